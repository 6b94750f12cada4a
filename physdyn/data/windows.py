"""Training windows: T consecutive steps of one simulation, with per-step targets.

Step t of a window carries the inputs at step t (world-frame ``v_t``, ``w_t``) and the change to step t+1:
``dv = v_{t+1} - v_t``, ``dw = w_{t+1} - w_t``, ``dp = p_{t+1} - p_t`` and the world-frame rotation
``dtheta = Log(R_{t+1} R_t^T)`` (so ``R_{t+1} = Exp(dtheta) R_t``), plus the topple label of step t+1.
A window running past the end of its simulation repeats the last (resting) frame: zero changes, last
topple label. The point cloud is the shape's body-frame cloud rotated into the world orientation of the
window's first step (``R @ p``: the body frame is the mesh frame moved to the centre of mass).

Everything per frame is computed once (``FrameTargets``), so a batch of windows is a few fancy-index
gathers — no per-item Python loops and no store reads during training.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from physdyn.geometry.mass import vertical_inertia, world_inertia_per_mass
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_matrix, rotvec_to_quat, world_delta_rotvec

if TYPE_CHECKING:  # annotations only: reading a store (zarr) is not needed to predict
    from physdyn.data.store import StoreData

# The per-step changes a model predicts, in the order of its 12 outputs [dv, dw, dp, dtheta].
DELTA_KEYS = ("delta_linear_velocity", "delta_angular_velocity", "delta_position", "delta_rotation")

WINDOW_KEYS = (
    "points", "linear_velocity", "angular_velocity", "delta_linear_velocity", "delta_angular_velocity",
    "delta_position", "delta_rotation", "topple_label", "valid", "com_position0", "orientation0_xyzw",
    "sim", "start", "relative_orientation_xyzw", "spin_inertia",
)


@dataclass
class FrameTargets:
    """Per-frame change to the next frame of the same simulation (zero on each simulation's last frame).

    delta_linear_velocity, delta_angular_velocity, delta_position, delta_rotation: (F, 3) float64
    next_topple_label: (F,) bool, the label of frame f+1 (of f itself on a simulation's last frame)
    """

    delta_linear_velocity: np.ndarray
    delta_angular_velocity: np.ndarray
    delta_position: np.ndarray
    delta_rotation: np.ndarray
    next_topple_label: np.ndarray


def frame_targets(store: StoreData, frames: np.ndarray | None = None) -> FrameTargets:
    """The targets of every frame, or of ``frames`` only (any shape of frame indices; the arrays then have
    that shape in front): evaluation needs the test frames, not the whole store."""
    F = len(store.com_position)
    cur = np.arange(F) if frames is None else np.asarray(frames, dtype=np.int64).reshape(-1)
    is_last = np.zeros(F, dtype=bool)
    is_last[store.start[1:] - 1] = True  # each simulation's last frame has no next frame: it maps to itself
    nxt = np.where(is_last[cur], cur, cur + 1)
    q = store.orientation_xyzw
    lead = cur.shape if frames is None else np.shape(frames)
    shaped = lambda a: a.reshape(lead + a.shape[1:])  # noqa: E731
    return FrameTargets(
        delta_linear_velocity=shaped(store.linear_velocity[nxt] - store.linear_velocity[cur]),
        delta_angular_velocity=shaped(store.angular_velocity[nxt] - store.angular_velocity[cur]),
        delta_position=shaped(store.com_position[nxt] - store.com_position[cur]),
        delta_rotation=shaped(np.where((nxt == cur)[:, None], 0.0, world_delta_rotvec(q[cur], q[nxt]))),
        next_topple_label=shaped(store.topple_label[nxt].astype(bool)),
    )


def relative_rotation(q_first: np.ndarray, q: np.ndarray) -> np.ndarray:
    """q_first (B, 4), q (B, T, 4) xyzw -> (B, T, 4) world-frame rotation from the first pose to each pose:
    R_t R_first^T, the object's turn since the point cloud was oriented."""
    return quat_multiply(q, np.broadcast_to(quat_conjugate(q_first)[:, None, :], q.shape))


def world_oriented_points(points_body: np.ndarray, orientation_xyzw: np.ndarray) -> np.ndarray:
    """points_body: (..., N, 3) body frame; orientation_xyzw: (..., 4) of the mesh frame -> (..., N, 3) R @ p."""
    R = quat_to_matrix(orientation_xyzw)
    # A product, not einsum: einsum's summation order changes with the batch's size (a cloud turned alone and
    # in a batch of 512 differed in the last bit), and it took twice as long on a batch of 512 clouds.
    return np.matmul(points_body, np.swapaxes(R, -1, -2))


def store_spin_inertia(store: StoreData, sims: np.ndarray, orientation_xyzw: np.ndarray) -> np.ndarray:
    """(B,) I_zz / m about the world vertical of each sim's shape in the given (B, 4) orientations."""
    shapes = store.shape_id[np.asarray(sims, dtype=np.int64)]
    axes = quat_to_matrix(store.inertia_orientation_xyzw[shapes])
    return vertical_inertia(store.inertia_diag[shapes], axes, store.mass[shapes], orientation_xyzw)


def store_world_inertia(store: StoreData, sims: np.ndarray, orientation_xyzw: np.ndarray) -> np.ndarray:
    """(B, 3, 3) I / m of each sim's shape in world axes at the given (B, 4) orientations."""
    shapes = store.shape_id[np.asarray(sims, dtype=np.int64)]
    axes = quat_to_matrix(store.inertia_orientation_xyzw[shapes])
    return world_inertia_per_mass(store.inertia_diag[shapes], axes, store.mass[shapes], orientation_xyzw)


def turned_about_vertical(batch: dict[str, np.ndarray], yaw: np.ndarray) -> dict[str, np.ndarray]:
    """A batch of ``WindowSource.gather`` turned about the world vertical by ``yaw`` (B,) radians: the same
    windows pushed in other directions. Points, velocities and changes (rotation vectors included) turn as
    vectors; the pose at the first step turns with the world, rotations since it are conjugated."""

    turn = rotvec_to_quat(np.asarray(yaw, np.float64)[:, None] * np.array([0.0, 0.0, 1.0]))
    R = quat_to_matrix(turn)
    out = dict(batch)
    for key in ("points", "linear_velocity", "angular_velocity", "delta_linear_velocity", "delta_angular_velocity",
                "delta_position", "delta_rotation"):
        out[key] = np.einsum("bij,b...j->b...i", R, batch[key]).astype(batch[key].dtype)
    out["com_position0"] = np.einsum("bij,bj->bi", R, batch["com_position0"])
    out["orientation0_xyzw"] = quat_multiply(turn, batch["orientation0_xyzw"])
    rel = batch["relative_orientation_xyzw"]
    turn_t = np.broadcast_to(turn[:, None, :], rel.shape)
    out["relative_orientation_xyzw"] = quat_multiply(quat_multiply(turn_t, rel), quat_conjugate(turn_t)).astype(rel.dtype)
    return out


def subsample_indices(num_available: int, num_points: int | None, rng: np.random.Generator, batch: int) -> np.ndarray | None:
    """(batch, num_points) random point indices without replacement, or None to keep every point."""
    if num_points is None or num_points >= num_available:
        return None
    return np.argsort(rng.random((batch, num_available)), axis=1)[:, :num_points]


class WindowSource:
    """Gathers batches of windows from an in-memory store.

    ``window``: steps per window (T). Arrays returned by ``gather`` (B = len(sims)):
    points (B, N, 3) float32 world-oriented body frame; linear_velocity, angular_velocity and the four
    ``delta_*`` (B, T, 3) float32; topple_label (B, T) float32 (label of step t+1); valid (B, T) bool
    (False where step t+1 is padding); com_position0 (B, 3), orientation0_xyzw (B, 4) float64 (pose at
    the window's first step); sim, start (B,) int64; relative_orientation_xyzw (B, T, 4) float32, the
    world-frame rotation from the window's first step to step t (``relative_rotation``); spin_inertia (B,)
    float32, the body's I_zz / m about the world vertical at the window's first step (``store_spin_inertia``).
    """

    def __init__(self, store: StoreData, window: int, num_points: int | None = None):
        if window < 1:
            raise ValueError(f"window must be at least 1 step, got {window}")
        self.store = store
        self.window = int(window)
        self.num_points = num_points
        self.targets = frame_targets(store)
        self.lengths = store.lengths()

    def max_start(self, sims: np.ndarray) -> np.ndarray:
        """Largest start per simulation that keeps a window of real transitions (0 for short simulations)."""
        return np.maximum(self.lengths[sims] - 1 - self.window, 0)

    def random_starts(self, sims: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return (rng.random(len(sims)) * (self.max_start(sims) + 1)).astype(np.int64)

    def gather(self, sims: np.ndarray, starts: np.ndarray, point_index: np.ndarray | None = None) -> dict[str, np.ndarray]:
        s = self.store
        sims = np.asarray(sims, dtype=np.int64)
        starts = np.asarray(starts, dtype=np.int64)
        steps = starts[:, None] + np.arange(self.window)[None, :]  # (B, T)
        length = self.lengths[sims][:, None]
        frames = s.start[sims][:, None] + np.minimum(steps, length - 1)
        first = s.start[sims] + np.minimum(starts, length[:, 0] - 1)
        shape_points = s.points[s.shape_id[sims]]  # (B, N, 3)
        if point_index is not None:
            shape_points = np.take_along_axis(shape_points, point_index[..., None], axis=1)
        t = self.targets
        f32 = np.float32
        return {
            "points": world_oriented_points(shape_points, s.orientation_xyzw[first]).astype(f32),
            "linear_velocity": s.linear_velocity[frames].astype(f32),
            "angular_velocity": s.angular_velocity[frames].astype(f32),
            "delta_linear_velocity": t.delta_linear_velocity[frames].astype(f32),
            "delta_angular_velocity": t.delta_angular_velocity[frames].astype(f32),
            "delta_position": t.delta_position[frames].astype(f32),
            "delta_rotation": t.delta_rotation[frames].astype(f32),
            "topple_label": t.next_topple_label[frames].astype(f32),
            "valid": steps < length - 1,
            "com_position0": s.com_position[first],
            "orientation0_xyzw": s.orientation_xyzw[first],
            "sim": sims,
            "start": starts,
            "relative_orientation_xyzw": relative_rotation(s.orientation_xyzw[first], s.orientation_xyzw[frames]).astype(f32),
            "spin_inertia": store_spin_inertia(s, sims, s.orientation_xyzw[first]).astype(f32),
        }
