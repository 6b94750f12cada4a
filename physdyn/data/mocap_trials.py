"""One motion-capture trial read, checked and converted to the conventions (docs/real-world.md; supplement,
"Real-world Data Experiments"); ``mocap_import`` writes a folder of them into a store.

Each trial is a CSV with header ``time,x,y,z,qx,qy,qz,qw``: the pose of the tracked rigid body in the
world frame (z up, metres, seconds, unit quaternion) at a constant rate. The tracked body frame is taken
to be the *mesh frame* of the given shape, so a mesh vertex x is at ``R @ x + position`` in the tracker's
world. Per trial (``import_trial``):

1. read and check: header, numbers, constant rate (reports the rate; a gap skips the trial), unit and
   continuous quaternions;
2. down-sample (120 Hz -> 30 Hz in the paper) by averaging windows of ``factor`` samples — positions by
   their mean, quaternions by Markley's average — and keeping every ``factor``-th window;
3. velocities (world frame) by central differences: linear from positions, angular from the relative
   rotation ``Log(R_{k+1} R_{k-1}^T)``;
4. trim so step 0 is the frame of maximum linear speed (the object has just left the hand), and end it
   once the object has rested for ``rest_duration`` (as the simulator ends its trajectories);
5. the floor: the median over the resting end of the lowest hull vertex's height is the floor offset,
   subtracted from z so the floor is z = 0; then com_position = pose applied to com_mesh.

A trial that fails a check raises ``TrialError`` with the reason; ``import_mocap`` reports it (file and reason)
and imports the rest.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from physdyn.errors import PhysdynError
from physdyn.geometry.rotations import canonical_quat, continuous_quat, quat_to_matrix, world_delta_rotvec
from physdyn.sim.synthetic_trials import CSV_HEADER, TrackedShape
from physdyn.sim.trajectory import topple_labels

COLUMNS = tuple(CSV_HEADER.split(","))


class TrialError(PhysdynError):
    """One trial cannot be imported; the message is the reason (the file is named by the caller)."""


@dataclass
class ImportSettings:
    """How trials are turned into a store. Speeds in m/s and rad/s, times in s."""

    rate_hz: float = 30.0  # output rate; the input rate must be a whole multiple of it
    gap_factor: float = 1.5  # a time step longer than this x the nominal one is a gap
    unit_tolerance: float = 0.01  # | |q| - 1 | above this is a non-unit quaternion
    max_rotation_step_deg: float = 30.0  # a larger jump between two samples is a tracking flip
    fix_sign_flips: bool = False  # re-align q -> -q sign jumps instead of skipping the trial
    min_peak_speed: float = 0.05  # below this the object never moved
    min_frames: int = 5  # output frames from the trim point on
    rest_linear_speed: float = 0.03  # above the simulator's 0.01: tracking noise in differenced velocities
    rest_angular_speed: float = 0.3
    rest_duration: float = 0.5
    num_points: int = 1024
    oversample: int = 3
    test_fraction: float = 10 / 66  # the paper: 10 of 66 trials
    val_fraction: float = 0.1  # of the training trials, at least one
    seed: int = 0
    friction: float = float("nan")  # unknown unless the user measured it
    category: str = "real"


@dataclass
class RawTrial:
    """A trial as read: time (N,) s, position (N, 3) m, orientation_xyzw (N, 4), tracker's world frame."""

    time: np.ndarray
    position: np.ndarray
    orientation_xyzw: np.ndarray


@dataclass
class ImportedTrial:
    """One trial in the conventions' frame at the output rate, step 0 = the trim point.

    com_position (T, 3), orientation_xyzw (T, 4) of the mesh frame, linear_velocity (T, 3) m/s,
    angular_velocity (T, 3) rad/s (world axes), topple_label (T,) bool, topple_step (-1 if none);
    time (T,) in the trial's own clock (centre of each averaging window); input_rate_hz, floor_offset (m,
    subtracted from z), peak_speed (m/s), notes (things worth telling the user).
    """

    name: str
    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    topple_label: np.ndarray
    topple_step: int
    time: np.ndarray
    input_rate_hz: float
    floor_offset: float
    peak_speed: float
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.com_position)


# --------------------------------------------------------------------------------------------------
# Reading and checking
# --------------------------------------------------------------------------------------------------
def read_trial_csv(path: str | Path) -> RawTrial:
    """Parse one trial; raises TrialError for a malformed header, a bad row or a NaN / infinite value."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise TrialError(f"cannot read the file ({type(exc).__name__}: {exc})") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise TrialError("empty file")
    header = tuple(c.strip().lower() for c in rows[0])
    if header != COLUMNS:
        raise TrialError(f"malformed header '{','.join(rows[0])}'; expected '{CSV_HEADER}'")
    data = np.empty((len(rows) - 1, len(COLUMNS)))
    for i, row in enumerate(rows[1:]):
        line = i + 2
        if len(row) != len(COLUMNS):
            raise TrialError(f"line {line} has {len(row)} fields, expected {len(COLUMNS)} ({CSV_HEADER})")
        try:
            data[i] = [float(c) for c in row]
        except ValueError:
            raise TrialError(f"line {line} holds a value that is not a number: '{','.join(row)}'") from None
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise TrialError(f"NaN or infinite value in column '{COLUMNS[col]}' at line {row + 2} "
                         f"({int(bad.any(axis=1).sum())} row(s) affected; the tracker lost the body?)")
    return RawTrial(time=data[:, 0], position=data[:, 1:4], orientation_xyzw=data[:, 4:8])


def check_rate(time: np.ndarray, gap_factor: float = 1.5) -> float:
    """The sampling rate (Hz, from the median step); raises TrialError for time running backwards or a gap."""
    if len(time) < 2:
        raise TrialError(f"too short: {len(time)} sample(s)")
    dt = np.diff(time)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise TrialError(f"time does not increase at line {i + 3} ({time[i]:.6f} s then {time[i + 1]:.6f} s)")
    nominal = float(np.median(dt))
    gaps = np.flatnonzero(dt > gap_factor * nominal)
    if len(gaps):
        i = int(gaps[0])
        missing = int(round(dt[i] / nominal)) - 1
        raise TrialError(f"gap of {dt[i] * 1e3:.1f} ms (~{missing} missing sample(s)) after t = {time[i]:.4f} s "
                         f"(line {i + 2}) at {1 / nominal:.1f} Hz; {len(gaps)} gap(s) in all")
    return 1.0 / nominal


def check_quaternions(q_xyzw: np.ndarray, settings: ImportSettings) -> np.ndarray:
    """Unit-norm, sign-continuous quaternions (N, 4); raises TrialError for non-unit ones, a sign jump
    q -> -q (unless ``fix_sign_flips``) or an orientation jump too large for one sample (a tracking flip)."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1.0) > settings.unit_tolerance
    if off.any():
        i = int(np.argmax(off))
        raise TrialError(f"non-unit quaternion (norm {norm[i]:.4f}) at line {i + 2}; {int(off.sum())} row(s) are off by "
                         f"more than {settings.unit_tolerance:g}: check the column order is qx,qy,qz,qw")
    q = q / norm[:, None]
    dots = np.sum(q[1:] * q[:-1], axis=1)
    angle = np.degrees(2.0 * np.arccos(np.clip(np.abs(dots), 0.0, 1.0)))
    jumps = np.flatnonzero(angle > settings.max_rotation_step_deg)
    if len(jumps):
        i = int(jumps[0])
        raise TrialError(f"orientation jumps by {angle[i]:.1f} deg between lines {i + 2} and {i + 3} "
                         f"(a tracking flip or a swapped marker)")
    flips = np.flatnonzero(dots < 0)
    if len(flips):
        if not settings.fix_sign_flips:
            raise TrialError(f"quaternion sign flips (q -> -q) at line {int(flips[0]) + 3} ({len(flips)} flip(s)); "
                             f"export continuous quaternions, or pass --fix-sign-flips to re-align them")
        q = continuous_quat(q)
    return q


# --------------------------------------------------------------------------------------------------
# Pure signal processing
# --------------------------------------------------------------------------------------------------
def average_quaternions(q_xyzw: np.ndarray) -> np.ndarray:
    """Markley's average of each row's quaternions: (..., W, 4) -> (..., 4) unit, sign as the first one.

    Each window is sign-aligned to its first quaternion, then the average is the principal eigenvector of
    the sum of outer products q q^T (F. L. Markley et al., "Averaging Quaternions", 2007).
    """
    q = np.asarray(q_xyzw, dtype=np.float64)
    ref = q[..., :1, :]
    q = np.where(np.sum(q * ref, axis=-1, keepdims=True) < 0, -q, q)
    M = np.einsum("...wi,...wj->...ij", q, q)
    _, vectors = np.linalg.eigh(M)
    mean = vectors[..., :, -1]
    return np.where(np.sum(mean * ref[..., 0, :], axis=-1, keepdims=True) < 0, -mean, mean)


def downsample(time: np.ndarray, position: np.ndarray, orientation_xyzw: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Average sliding windows of ``factor`` samples and keep every ``factor``-th: (N, ...) -> (N // factor, ...).
    Output times are the windows' mean times."""
    n = len(time) // factor
    cut = n * factor
    t = time[:cut].reshape(n, factor).mean(axis=1)
    p = position[:cut].reshape(n, factor, 3).mean(axis=1)
    q = average_quaternions(orientation_xyzw[:cut].reshape(n, factor, 4))
    return t, p, q


def central_velocities(time: np.ndarray, position: np.ndarray, orientation_xyzw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame velocities (T, 3), (T, 3) by central differences (one-sided at the ends); angular from the
    relative rotation Log(R_{k+1} R_{k-1}^T) over the time between them."""
    lo = np.concatenate([[0], np.arange(len(time) - 2), [len(time) - 2]])
    hi = np.concatenate([[1], np.arange(2, len(time)), [len(time) - 1]])
    dt = (time[hi] - time[lo])[:, None]
    v = (position[hi] - position[lo]) / dt
    w = world_delta_rotvec(orientation_xyzw[lo], orientation_xyzw[hi]) / dt
    return v, w


def rest_start(speed: np.ndarray, spin: np.ndarray, settings: ImportSettings, rate_hz: float) -> int | None:
    """First frame from which the object stays below the rest thresholds for ``rest_duration``, or None."""
    still = (speed < settings.rest_linear_speed) & (spin < settings.rest_angular_speed)
    need = max(1, int(math.ceil(settings.rest_duration * rate_hz - 1e-9)))
    run = 0
    for k, s in enumerate(still):
        run = run + 1 if s else 0
        if run >= need:
            return k - need + 1
    return None


# --------------------------------------------------------------------------------------------------
# One trial
# --------------------------------------------------------------------------------------------------
def import_trial(path: str | Path, shape: TrackedShape, settings: ImportSettings = ImportSettings()) -> ImportedTrial:
    """Read, check and convert one trial (module docstring); raises TrialError with the reason."""
    path = Path(path)
    raw = read_trial_csv(path)
    input_rate = check_rate(raw.time, settings.gap_factor)
    factor = int(round(input_rate / settings.rate_hz))
    if factor < 1 or abs(input_rate / factor - settings.rate_hz) > 0.01 * settings.rate_hz:
        raise TrialError(f"recorded at {input_rate:.2f} Hz, not a whole multiple of the output rate "
                         f"{settings.rate_hz:g} Hz; pass --rate with a divisor of {input_rate:.0f} Hz")
    if len(raw.time) < factor * max(3, settings.min_frames):
        raise TrialError(f"too short: {len(raw.time)} samples ({raw.time[-1] - raw.time[0]:.3f} s at {input_rate:.0f} Hz); "
                         f"need at least {factor * max(3, settings.min_frames)}")
    q = check_quaternions(raw.orientation_xyzw, settings)
    t, origin, q = downsample(raw.time, raw.position, q, factor)
    rate = input_rate / factor
    # The tracked body frame is the mesh frame: the centre of mass is the pose applied to com_mesh.
    com = origin + np.einsum("tij,j->ti", quat_to_matrix(q), shape.com_mesh)
    v, w = central_velocities(t, com, q)
    speed = np.linalg.norm(v, axis=1)
    peak = int(np.argmax(speed))
    if speed[peak] < settings.min_peak_speed:
        raise TrialError(f"never moves: peak speed {speed[peak]:.3f} m/s is below {settings.min_peak_speed:g} m/s")
    notes = []
    rest = rest_start(speed[peak:], np.linalg.norm(w[peak:], axis=1), settings, rate)
    need = max(1, int(math.ceil(settings.rest_duration * rate - 1e-9)))
    if rest is None:
        end = len(t)
        resting = slice(max(peak, end - need), end)
        notes.append(f"never at rest (|v| < {settings.rest_linear_speed:g} m/s, |w| < {settings.rest_angular_speed:g} rad/s "
                     f"for {settings.rest_duration:g} s); floor estimated from the last {end - resting.start} frame(s)")
    else:
        end = peak + rest + need
        resting = slice(peak + rest, end)
    if end - peak < settings.min_frames:
        raise TrialError(f"too short after trimming: {end - peak} frame(s) from the peak speed at t = {t[peak]:.3f} s; "
                         f"need at least {settings.min_frames} (--min-frames)")
    floor = float(np.median(shape.lowest_vertex_z(com[resting], q[resting])))
    com = com - np.array([0.0, 0.0, floor])
    keep = slice(peak, end)
    orientation = canonical_quat(q[keep])
    labels, topple_step = topple_labels(orientation)
    return ImportedTrial(
        name=path.name, com_position=com[keep], orientation_xyzw=orientation, linear_velocity=v[keep],
        angular_velocity=w[keep], topple_label=labels, topple_step=topple_step, time=t[keep],
        input_rate_hz=input_rate, floor_offset=floor, peak_speed=float(speed[peak]), notes=notes,
    )
