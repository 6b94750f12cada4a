"""A roll-out's trajectory: the per-step changes integrated into states, and the verdict on toppling.

The pose is integrated as the paper's reference test code does: the predicted changes are added to v, w and
p, and the world-frame rotation is composed on the left, R_{t+1} = Exp(dtheta_t) R_t (physdyn's targets are
world-frame: ``physdyn.data.windows``). Quaternions are re-normalised every step.

Shapes: B sequences, S predicted transitions, T = S + 1 recorded steps (step 0 included).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from physdyn.data.windows import DELTA_KEYS
from physdyn.eval.metrics import TOPPLE_THRESHOLD  # a leaf of pure numpy: the one threshold for reports and roll-outs
from physdyn.geometry.rotations import rotvec_to_quat, tilt_angle, world_delta_rotvec

STATE_KEYS = ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity")


@dataclass
class RolloutResult:
    """A predicted trajectory per sequence, SI units, world frame (docs/conventions.md).

    com_position (B, T, 3), orientation_xyzw (B, T, 4) unit quaternions, linear_velocity (B, T, 3),
    angular_velocity (B, T, 3): the state at steps 0..S.
    topple_probability (B, T) or None: the probability that the object has toppled by step t (the model's
    output at step t-1, which predicts the label of step t; 0 at step 0, where nothing has toppled yet).
    delta_* (B, S, 3): the predicted change from step t to t+1 (``delta_rotation`` world axis-angle); None
    for a request with ``with_changes=False``, whose caller reads the states only.
    fed_linear_velocity, fed_angular_velocity (B, S, 3): the velocities the predictor received at step t
    (its own roll-out, or the truth during a warm start).
    """

    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    topple_probability: np.ndarray | None
    delta_linear_velocity: np.ndarray | None
    delta_angular_velocity: np.ndarray | None
    delta_position: np.ndarray | None
    delta_rotation: np.ndarray | None
    fed_linear_velocity: np.ndarray
    fed_angular_velocity: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)
    toppled: np.ndarray | None = None  # (B,) by each roll-out's own end (``toppled_by_own_end``); None from baselines

    @property
    def num_steps(self) -> int:
        """S, the number of predicted transitions."""
        return self.com_position.shape[1] - 1

    def deltas(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in DELTA_KEYS}

    def sequence(self, b: int) -> dict[str, np.ndarray | None]:
        """One sequence's arrays with the names of a prediction file (conventions: `physdyn predict`)."""
        out: dict[str, np.ndarray | None] = {k: getattr(self, k)[b] for k in STATE_KEYS}
        out["topple_probability"] = None if self.topple_probability is None else self.topple_probability[b]
        return out


def as_float64(x: Any) -> np.ndarray:
    """An array or tensor as a float64 numpy array (on the CPU)."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def state_changes(com_position: np.ndarray, orientation_xyzw: np.ndarray, linear_velocity: np.ndarray,
                  angular_velocity: np.ndarray) -> dict[str, np.ndarray]:
    """States (B, T, ...) -> their changes ``delta_*`` (B, T-1, 3), the inverse of ``integrate``
    (``delta_rotation`` world axis-angle: R_{t+1} = Exp(d_t) R_t)."""
    q = np.asarray(orientation_xyzw, np.float64)
    return {"delta_linear_velocity": np.diff(linear_velocity, axis=1),
            "delta_angular_velocity": np.diff(angular_velocity, axis=1),
            "delta_position": np.diff(com_position, axis=1),
            "delta_rotation": world_delta_rotvec(q[:, :-1], q[:, 1:])}


def integrate(p0: np.ndarray, q0: np.ndarray, v0: np.ndarray, w0: np.ndarray, deltas: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Accumulate per-step changes into states (a pure function; ``rollout`` uses it for the pose).

    p0 (B, 3), q0 (B, 4) xyzw, v0 (B, 3), w0 (B, 3): the state at step 0; deltas: ``delta_*`` (B, S, 3)
    as in ``DELTA_KEYS``. Returns ``com_position`` (B, S+1, 3), ``orientation_xyzw`` (B, S+1, 4),
    ``linear_velocity`` and ``angular_velocity`` (B, S+1, 3), float64:
    p_{t+1} = p_t + dp_t, v_{t+1} = v_t + dv_t, w_{t+1} = w_t + dw_t, R_{t+1} = Exp(dtheta_t) R_t.
    """
    d = {k: as_float64(deltas[k]) for k in DELTA_KEYS}
    B, S = d["delta_position"].shape[:2]
    out = {
        "com_position": np.empty((B, S + 1, 3)),
        "orientation_xyzw": np.empty((B, S + 1, 4)),
        "linear_velocity": np.empty((B, S + 1, 3)),
        "angular_velocity": np.empty((B, S + 1, 3)),
    }
    q = as_float64(q0).reshape(B, 4)
    out["orientation_xyzw"][:, 0] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    for key, start, delta in (("com_position", p0, "delta_position"), ("linear_velocity", v0, "delta_linear_velocity"),
                              ("angular_velocity", w0, "delta_angular_velocity")):
        out[key][:, 0] = as_float64(start).reshape(B, 3)
        # a running sum adds in order, so a step-by-step roll-out gives bitwise the same numbers
        np.cumsum(np.concatenate([out[key][:, :1], d[delta]], axis=1), axis=1, out=out[key])
    # One quaternion product per step on component arrays (B,): quat_multiply's stacking per call cost more
    # than the arithmetic in a one-object roll-out.
    sx, sy, sz, sw = np.moveaxis(rotvec_to_quat(d["delta_rotation"]), -1, 0)  # each (B, S)
    if B == 1:  # one object: the same arithmetic on Python numbers, ten times cheaper than on (1,) arrays
        out["orientation_xyzw"][0] = _compose_one(out["orientation_xyzw"][0, 0].tolist(), sx[0].tolist(), sy[0].tolist(),
                                                  sz[0].tolist(), sw[0].tolist())
        return out
    bx, by, bz, bw = out["orientation_xyzw"][:, 0].T.copy()
    for t in range(S):
        ax, ay, az, aw = sx[:, t], sy[:, t], sz[:, t], sw[:, t]
        bx, by, bz, bw = (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                          aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)
        n = np.sqrt(bx * bx + by * by + bz * bz + bw * bw)
        bx, by, bz, bw = bx / n, by / n, bz / n, bw / n
        out["orientation_xyzw"][:, t + 1] = np.stack([bx, by, bz, bw], axis=-1)
    return out


def _compose_one(first: list, sx: list, sy: list, sz: list, sw: list) -> list:
    """``integrate``'s quaternion loop for one object, operation for operation: (S + 1) rows of xyzw."""
    bx, by, bz, bw = first
    rows = [first]
    for ax, ay, az, aw in zip(sx, sy, sz, sw):
        bx, by, bz, bw = (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                          aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)
        n = math.sqrt(bx * bx + by * by + bz * bz + bw * bw)
        bx, by, bz, bw = bx / n, by / n, bz / n, bw / n
        rows.append([bx, by, bz, bw])
    return rows


def toppled_by_own_end(probability: np.ndarray | None, q0: np.ndarray, orientations: np.ndarray,
                       lengths: np.ndarray | None = None) -> np.ndarray:
    """(B,) whether each roll-out has toppled by its own last state (``lengths`` (B,) states, default all T):
    its per-step probabilities (B, T) reaching ``TOPPLE_THRESHOLD``, or, for a model with no topple output,
    the conventions' rule on its own poses (B, T, 4): tilted past 45 degrees from step 0."""
    T = orientations.shape[1]
    live = np.ones((len(q0), T), dtype=bool) if lengths is None else np.arange(T)[None] < np.asarray(lengths)[:, None]
    if probability is not None:
        return ((np.asarray(probability) >= TOPPLE_THRESHOLD) & live).any(axis=1)
    from physdyn.sim.trajectory import TOPPLE_ANGLE  # the conventions' topple rule

    return ((tilt_angle(np.asarray(q0)[:, None], orientations) > TOPPLE_ANGLE) & live).any(axis=1)


