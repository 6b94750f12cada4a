"""Predictors that need no learning, with the output of ``rollout``, and loading any predictor by name.

- ``stay_put``: the object never moves (its velocities drop to zero after step 0).
- ``coulomb_slide``: the centre of mass slides along the horizontal part of v0, decelerating at mu g
  (mu: the store's effective Coulomb coefficient, ``sims/friction``) until it stops; no rotation. This is
  exact for a box pushed through its centre of mass, and the bar a learned model must clear.
Both predict that nothing topples (probability 0 at every step). Neither uses a warm start.
- ``cloud_sim``: "just running the simulator" on what a model sees: PyBullet (1/240 s) on the convex hull of
  the shape's point cloud, with the body's own mass properties (the store's), from the step-0 state
  (``physdyn.sim.cloud_body``). Its topple probability is 1 from the step its roll-out passes 45 degrees.
  Teacher-forced one-step errors start each step at rest in the true orientation with the true velocities
  (a rocking or airborne state is put on the ground). About 10 ms of CPU per push.

``resolve_predictor`` accepts a baseline's name, a ``Baseline``, a ``DynamicsNetwork`` or the path of any
``DynamicsModel`` checkpoint (e.g. the MLP baseline of ``configs/experiment/mlp_baseline.yaml``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any

import numpy as np

from physdyn.errors import CheckpointError, PhysdynError
from physdyn.pipeline.trajectory import RolloutResult, state_changes

GRAVITY = 9.81


def _result(p: np.ndarray, q: np.ndarray, v: np.ndarray, w: np.ndarray, rotates: bool = False) -> RolloutResult:
    """States (B, T, ...) -> a RolloutResult whose deltas are the state differences. The rotation's are
    those of ``state_changes`` for a baseline that turns, exactly zero for one that never does (its axis
    error is then undefined, "n/a" in reports, not the axis of a rounding residue)."""
    B, T = p.shape[:2]
    changes = state_changes(p, q, v, w)
    if not rotates:
        changes["delta_rotation"] = np.zeros((B, T - 1, 3))
    return RolloutResult(
        com_position=p, orientation_xyzw=q, linear_velocity=v, angular_velocity=w,
        topple_probability=np.zeros((B, T)), **changes,
        fed_linear_velocity=v[:, :-1].copy(), fed_angular_velocity=w[:, :-1].copy(),
    )


def _initial(com_position0, orientation0_xyzw, lin_vel0, ang_vel0):
    p0 = np.asarray(com_position0, np.float64).reshape(-1, 3)
    q0 = np.asarray(orientation0_xyzw, np.float64).reshape(-1, 4)
    return p0, q0 / np.linalg.norm(q0, axis=-1, keepdims=True), np.asarray(lin_vel0, np.float64).reshape(-1, 3), \
        np.asarray(ang_vel0, np.float64).reshape(-1, 3)


def stay_put(com_position0: np.ndarray, orientation0_xyzw: np.ndarray, lin_vel0: np.ndarray, ang_vel0: np.ndarray,
             steps: int) -> RolloutResult:
    """The object stays where it is: (B, 3), (B, 4), (B, 3), (B, 3) at step 0 -> T = steps + 1 steps."""
    p0, q0, v0, w0 = _initial(com_position0, orientation0_xyzw, lin_vel0, ang_vel0)
    T = steps + 1
    v = np.zeros((len(p0), T, 3))
    w = np.zeros((len(p0), T, 3))
    v[:, 0], w[:, 0] = v0, w0
    return _result(np.repeat(p0[:, None], T, axis=1), np.repeat(q0[:, None], T, axis=1), v, w)


def coulomb_slide(com_position0: np.ndarray, orientation0_xyzw: np.ndarray, lin_vel0: np.ndarray, ang_vel0: np.ndarray,
                  steps: int, friction: np.ndarray | float, rate_hz: float, gravity: float = GRAVITY) -> RolloutResult:
    """Sliding with Coulomb friction, in closed form at the recording times t_k = k / rate_hz.

    friction: (B,) or a scalar effective Coulomb coefficient mu. With u the horizontal part of v0,
    s0 = |u| and a = mu g: speed s(t) = max(s0 - a t, 0); distance d(t) = s0 t - a t^2 / 2 until the stop
    at t = s0 / a, then s0^2 / (2 a). Height and orientation stay; angular velocity is 0 after step 0.
    """
    p0, q0, v0, w0 = _initial(com_position0, orientation0_xyzw, lin_vel0, ang_vel0)
    B, T = len(p0), steps + 1
    mu = np.broadcast_to(np.asarray(friction, np.float64), (B,))
    bad = ~(mu > 0)  # NaN (unknown friction, e.g. imported trials) fails too, rather than rolling out NaNs
    if bad.any():
        raise ValueError(f"friction must be positive and known, got {mu[bad][:3]}")
    u = v0.copy()
    u[:, 2] = 0.0
    s0 = np.linalg.norm(u, axis=-1)
    direction = np.divide(u, s0[:, None], out=np.zeros_like(u), where=s0[:, None] > 0)
    a = mu * gravity
    t = np.arange(T)[None, :] / float(rate_hz)
    t_stop = s0 / a
    tc = np.minimum(t, t_stop[:, None])
    speed = s0[:, None] - a[:, None] * tc
    dist = s0[:, None] * tc - 0.5 * a[:, None] * tc**2
    p = p0[:, None] + dist[..., None] * direction[:, None]
    v = speed[..., None] * direction[:, None]
    v[:, 0] = v0
    w = np.zeros((B, T, 3))
    w[:, 0] = w0
    return _result(p, np.repeat(q0[:, None], T, axis=1), v, w)


class Baseline(ABC):
    """A named baseline for ``evaluate``: ``rollout(p0, q0, v0, w0, steps, friction, rate_hz)``."""

    name = "baseline"
    predicts_topple = True  # its zero probabilities are a prediction: "never topples"
    uses_shapes = False  # whether ``rollout`` needs ``points_body`` and ``inertia_per_mass`` (cloud_sim)

    @abstractmethod
    def rollout(self, com_position0, orientation0_xyzw, lin_vel0, ang_vel0, steps: int, friction, rate_hz: float) -> RolloutResult:
        """(B, 3) positions and velocities, (B, 4) orientations, (B,) friction -> steps + 1 states each."""


class StayPut(Baseline):
    name = "stay_put"

    def rollout(self, com_position0, orientation0_xyzw, lin_vel0, ang_vel0, steps, friction, rate_hz):
        return stay_put(com_position0, orientation0_xyzw, lin_vel0, ang_vel0, steps)


class CoulombSlide(Baseline):
    name = "coulomb_slide"

    def __init__(self, gravity: float = GRAVITY):
        self.gravity = gravity

    def rollout(self, com_position0, orientation0_xyzw, lin_vel0, ang_vel0, steps, friction, rate_hz):
        return coulomb_slide(com_position0, orientation0_xyzw, lin_vel0, ang_vel0, steps, friction, rate_hz, self.gravity)


class CloudSim(Baseline):
    name = "cloud_sim"
    uses_shapes = True

    def __init__(self, time_step: float | None = None):
        self.time_step = time_step  # None: physdyn.sim.cloud_body.CLOUD_TIME_STEP (1/240 s)

    def rollout(self, com_position0, orientation0_xyzw, lin_vel0, ang_vel0, steps, friction, rate_hz,
                points_body=None, inertia_per_mass=None):
        """As ``Baseline.rollout``, with points_body (B, N, 3) each shape's cloud in the body frame and
        inertia_per_mass (B, 3, 3) its I / m in body axes (None: the hull's)."""
        from physdyn.sim.cloud_body import CloudSimulator  # PyBullet: only when this baseline runs
        from physdyn.sim.trajectory import topple_labels

        if points_body is None:
            raise PhysdynError("the cloud_sim baseline needs each sequence's point cloud (points_body)")
        friction = np.broadcast_to(np.asarray(friction, np.float64), (len(np.asarray(com_position0).reshape(-1, 3)),))
        if np.isnan(friction).any():
            raise PhysdynError("the cloud_sim baseline needs the friction coefficient; the store records none "
                               "(sims/friction is NaN)")
        with CloudSimulator(**({} if self.time_step is None else {"time_step": self.time_step})) as sim:
            out = sim.trajectories(points_body, orientation0_xyzw, com_position0, lin_vel0, ang_vel0, friction,
                                   steps, rate_hz, inertia_per_mass)
        result = _result(out["com_position"], out["orientation_xyzw"], out["linear_velocity"], out["angular_velocity"],
                         rotates=True)
        result.topple_probability = np.stack([topple_labels(q)[0] for q in out["orientation_xyzw"]]).astype(np.float64)
        return result


BASELINES: dict[str, type[Baseline]] = {"stay_put": StayPut, "coulomb_slide": CoulombSlide, "cloud_sim": CloudSim}


def load_checkpoint(path: str | Path):
    """The ``DynamicsNetwork`` of a checkpoint of `physdyn fit` (plain torch: predicting and evaluating need not
    import Lightning); a one-line ``CheckpointError`` otherwise. Its topple classifier and end correction, if
    any, are stages of its pipeline (``physdyn.pipeline.presets.load_pipeline``), not of the network."""
    from physdyn.models.checkpoint_file import read_checkpoint  # torch: not for the numpy baselines
    from physdyn.pipeline.presets import network_from_checkpoint

    # a one-line error for a missing, unreadable, foreign or code-carrying file; "bundled" and "fast" name the
    # shipped models there
    return network_from_checkpoint(read_checkpoint(path), str(path))


def checkpoint_and_store(checkpoint: str | Path, data: str | None = None, stages: bool = False):
    """(the network of ``checkpoint``, or with ``stages`` its whole pipeline (with what `fit-topple` and
    `fit-outcome` added), the store to use: ``data`` or the one it was trained on)."""
    model = resolve_predictor(checkpoint) if stages else load_checkpoint(checkpoint)
    network = model.network if stages else model
    store = data or network.data_info.get("store")
    if not store:
        raise CheckpointError(f"{checkpoint} does not record its store; pass --data STORE")
    return model, store


def resolve_predictor(spec: Any):
    """A baseline name, a ``Baseline``, a ``DynamicsNetwork`` (or its ``DynamicsModel``), a ``Pipeline``, or a
    checkpoint path (its pipeline, with what `fit-topple` and `fit-outcome` added) -> the predictor."""
    if isinstance(spec, Baseline) or hasattr(spec, "encode_points") or hasattr(spec, "motion"):
        return spec
    if isinstance(spec, str) and spec in BASELINES:
        return BASELINES[spec]()
    if isinstance(spec, (str, Path)):
        from physdyn.pipeline.presets import load_pipeline  # torch: not for the numpy baselines

        return load_pipeline(spec)
    raise TypeError(f"cannot evaluate a {type(spec).__name__}; pass a DynamicsNetwork, a checkpoint path or one of {sorted(BASELINES)}")


def predictor_name(predictor: Any, fallback: str = "model") -> str:
    """A baseline's name, or the name in a network's config (a pipeline's: its network's)."""
    if isinstance(predictor, Baseline):
        return predictor.name
    network = getattr(predictor, "network", None) or predictor  # a Pipeline's network, or the network itself
    try:
        return str(network.config.name) or fallback
    except AttributeError:
        return fallback
