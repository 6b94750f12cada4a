"""Roll-outs: a predictor predicts whole trajectories from the state right after the push.

``rollout`` runs a pipeline of stages (``physdyn.pipeline``) on B pushes given as arrays (a store's, a
study's); ``Predictor.predict_many`` does the same for users' meshes. A bare network (``DynamicsNetwork``, or
anything with its ``encode_points`` and ``step``) is rolled out as the pipeline of its checkpoint's preset
without a topple classifier or a correction (``as_pipeline``). ``teacher_forced`` gives single-step predictions.

Shapes: B sequences, S = ``steps`` predicted transitions, T = S + 1 recorded steps (step 0 included).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from physdyn.data.windows import DELTA_KEYS, relative_rotation, world_oriented_points
from physdyn.errors import PhysdynError
from physdyn.models.dynamics_network import DynamicsNetwork
from physdyn.pipeline.correction import NoCorrection
from physdyn.pipeline.engine import Pipeline, run_stages
from physdyn.pipeline.motion import NetworkMotion, SimulatedStartMotion
from physdyn.pipeline.stages import BodyCache, PreparedBatch
from physdyn.pipeline.topple import HeadTopple
from physdyn.pipeline.trajectory import (STATE_KEYS, RolloutResult, as_float64, integrate, state_changes,
                                         toppled_by_own_end)

__all__ = ["DELTA_KEYS", "STATE_KEYS", "RolloutOptions", "RolloutResult", "as_pipeline", "integrate", "rollout",
           "sim_steps", "state_changes", "teacher_forced", "toppled_by_own_end"]


@dataclass
class RolloutOptions:
    """What a roll-out may be given beyond the step-0 state, all optional.

    warm_start_velocities: (linear, angular), each (B, K, 3): the TRUE velocities at steps 1..K, fed instead
    of the model's own (the paper's "additional velocity steps"; K = 1 for the real-world model). During the
    warm start the reported velocities are these observations; position and orientation are always the
    model's integrated ones. A caller's warm start replaces a simulated start.
    topple_points_body: (B, N', 3) the body-frame cloud the topple stage and a simulated start read where it
    is not the motion's (a classifier's size; default: ``points_body``).
    spin_inertia: (B,) I_zz / m of each body about the world vertical at step 0, for a contact prior that
    takes the body's (``model.contact_inertia=body``; ``physdyn.geometry.mass.vertical_inertia``) and for an
    end correction (without it or ``body_inertia``, estimated from the cloud).
    body_inertia: (B, 3, 3) I / m of each body in world axes at step 0, for a topple classifier that simulates
    the cloud's hull and for a simulated start (``physdyn.geometry.mass.world_inertia_per_mass``); without it
    those roll-outs take the hull's inertia.
    lengths: (B,) each sequence's own number of states where a batch is padded to its longest, so that each is
    judged at its own end, as alone (without them every sequence is judged at the batch's horizon).
    hull_counts: (B,) how many of each ``points_body`` cloud's first points are its mesh's hull vertices
    (``PreparedBody.hull_count``), so a PointNet that thins them needs no qhull.
    with_changes: False: the result's ``delta_*`` are None, for a caller that reads the states only.
    friction: (B,) each push's effective Coulomb coefficient with the ground, for a motion that takes friction
    (``MotionStage.takes_friction``: the contact prior); None: the model's own.
    reference_loop: a bare network rolled out through its ``step`` one step at a time, numpy between steps
    (the same numbers to float32 precision; the check on the torch loop).
    """

    warm_start_velocities: tuple[np.ndarray, np.ndarray] | None = None
    topple_points_body: np.ndarray | None = None
    spin_inertia: np.ndarray | None = None
    body_inertia: np.ndarray | None = None
    lengths: np.ndarray | None = None
    hull_counts: np.ndarray | None = None
    with_changes: bool = True
    reference_loop: bool = False
    friction: np.ndarray | None = None


def rollout(model: Any, points_body: np.ndarray, orientation0_xyzw: np.ndarray, com_position0: np.ndarray,
            lin_vel0: np.ndarray, ang_vel0: np.ndarray, steps: int, options: RolloutOptions | None = None) -> RolloutResult:
    """Roll ``model`` (a ``Pipeline``, or a bare network: ``as_pipeline``) out for ``steps`` transitions from
    the state at step 0, B sequences at once.

    points_body: (B, N, 3) body-frame cloud (of the size the model was trained on); orientation0_xyzw (B, 4),
    com_position0 (B, 3), lin_vel0 (B, 3), ang_vel0 (B, 3): step 0, world frame. ``options``: ``RolloutOptions``.
    """
    options = options or RolloutOptions()
    return run_stages(as_pipeline(model, options.reference_loop),
                      prepared_batch(points_body, (orientation0_xyzw, com_position0, lin_vel0, ang_vel0), steps, options))


def prepared_batch(points_body: np.ndarray, start: tuple, steps: int, options: RolloutOptions,
                   cache: BodyCache | None = None) -> PreparedBatch:
    """A ``PreparedBatch`` from arrays: ``start`` = (q0 (B, 4), p0, v0, w0 (B, 3)); checks the horizon and the
    warm start."""
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    q0, p0, v0, w0 = (as_float64(x) for x in start)
    B = q0.shape[0]
    warm_v, warm_w = _warm_start(options.warm_start_velocities, B)
    return PreparedBatch(as_float64(points_body), q0, p0.reshape(B, 3), v0.reshape(B, 3), w0.reshape(B, 3), int(steps),
                         warm_v, warm_w, stage_points_body=options.topple_points_body, spin_inertia=options.spin_inertia,
                         body_inertia=options.body_inertia, lengths=options.lengths, hull_counts=options.hull_counts,
                         with_changes=options.with_changes, cache=cache or BodyCache(),
                         friction=None if options.friction is None else as_float64(options.friction).reshape(B))


def as_pipeline(model: Any, reference_loop: bool = False) -> Pipeline:
    """``model`` if it is a ``Pipeline``; a bare network as one: its own motion (after a simulated start where
    its ``model.sim_seconds`` says so), its head's topple output, no correction."""
    if isinstance(model, Pipeline):
        return model
    if isinstance(model, DynamicsNetwork) and sim_steps(model):
        motion: NetworkMotion = SimulatedStartMotion(model, model.config.model.sim_seconds)
        motion.config = NetworkMotion.Config(reference_loop)
    else:
        motion = NetworkMotion(model, NetworkMotion.Config(reference_loop))
    return Pipeline(motion, HeadTopple(), NoCorrection())


def _warm_start(warm_start_velocities: Any, B: int) -> tuple[np.ndarray, np.ndarray]:
    if warm_start_velocities is None:
        return np.zeros((B, 0, 3)), np.zeros((B, 0, 3))
    lin, ang = (as_float64(x) for x in warm_start_velocities)
    if lin.shape != ang.shape or lin.ndim != 3 or lin.shape[0] != B or lin.shape[2] != 3:
        raise ValueError(
            f"warm_start_velocities must be (linear, angular), each (B={B}, K, 3); got {lin.shape} and {ang.shape}"
        )
    return lin, ang


def sim_steps(model: Any) -> int:
    """The steps a pipeline's simulated start spans at its rate (a bare ``DynamicsNetwork``: its
    ``model.sim_seconds``), at least one where it has one; 0 for anything else."""
    if isinstance(model, DynamicsNetwork):
        seconds = float(model.config.model.sim_seconds or 0.0)
        return max(1, int(round(seconds / float(model.prior_dt)))) if seconds > 0 else 0
    motion = model.motion if isinstance(model, Pipeline) else None
    return motion.sim_steps if isinstance(motion, SimulatedStartMotion) else 0


def teacher_forced(
    model: Any, points_body: np.ndarray, orientation0_xyzw: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray,
    orientation_xyzw: np.ndarray | None = None, spin_inertia: np.ndarray | None = None,
) -> dict[str, np.ndarray | None]:
    """Single-step (teacher-forced) predictions: the TRUE velocities fed at every step.

    points_body (B, N, 3) body frame; orientation0_xyzw (B, 4) at step 0; linear_velocity,
    angular_velocity (B, S, 3) true, world frame; orientation_xyzw (B, S, 4) the true orientations, needed by
    models fed their orientation since step 0; spin_inertia (B,) as for ``rollout``. Returns ``delta_*`` (B, S, 3) float64 and
    ``topple_probability`` (B, S) (the predicted label of step t+1) or None.
    """
    spin_inertia = spin_inertia if isinstance(model, DynamicsNetwork) else None  # a stand-in takes none
    q0 = as_float64(orientation0_xyzw)
    points = world_oriented_points(as_float64(points_body), q0).astype(np.float32)
    turn = None
    if isinstance(model, DynamicsNetwork) and model.uses_orientation:
        if orientation_xyzw is None:
            raise ValueError("this model is fed its orientation since step 0: pass the true orientation_xyzw")
        turn = relative_rotation(q0, as_float64(orientation_xyzw)).astype(np.float32)
    args = (points, np.asarray(linear_velocity, np.float32), np.asarray(angular_velocity, np.float32))
    kwargs = {} if spin_inertia is None else {"spin_inertia": spin_inertia}
    pred = model.predict_window(*args, **kwargs) if turn is None else model.predict_window(*args, orientation=turn, **kwargs)
    out: dict[str, np.ndarray | None] = {k: as_float64(getattr(pred, k)) for k in DELTA_KEYS}
    out["topple_probability"] = None if pred.topple_probability is None else as_float64(pred.topple_probability)
    return out


def store_friction(pipeline: Pipeline, friction: np.ndarray, sims: np.ndarray) -> np.ndarray | None:
    """(B,) the friction of each simulation of ``sims`` (``friction``: a store's, (M,)), for a motion that takes
    friction on a store simulated at other frictions than the model's own; None otherwise (the model's own
    throughout, and the roll-out takes its default path)."""
    own = getattr(pipeline.network, "prior_friction", None)
    mu = np.asarray(friction, dtype=np.float64)[sims]
    # a store that does not know its friction (imported trials: NaN) is rolled out at the model's own
    if not pipeline.motion.takes_friction or own is None or np.isnan(mu).any() or np.allclose(mu, own, rtol=0, atol=1e-9):
        return None
    return mu


def check_store_clouds(pipeline: Pipeline, store: Any) -> None:
    """One line and no roll-out where a stage of ``pipeline`` reads clouds ``store`` does not hold: a PointNet
    topple classifier reads its kind of cloud, given whole (thinned by it), and so does a PointNet correction."""
    topple, correction = pipeline.topple, pipeline.correction
    wants = topple.cloud.method if topple.strict_cloud else None
    if wants is not None:
        _check_clouds(store, "topple classifier", wants, topple.cloud.count)
    if correction.strict_cloud:
        _check_clouds(store, "outcome correction", correction.cloud.method or store.points_method, correction.cloud.count)
    if wants is not None and pipeline.points_method != wants:  # one store cannot feed both: the model would get the wrong kind
        raise PhysdynError(f"the model reads {pipeline.points_method} clouds and its topple classifier {wants} ones; a "
                           "store holds one kind, so `physdyn test` cannot feed both: measure it through `predict` "
                           f"(benchmarks/frontier.py), or give the classifier a model trained on {wants} clouds")


def _check_clouds(store: Any, reader: str, method: str, size: int) -> None:
    if store.points_method != method or store.points.shape[1] != size:
        raise PhysdynError(f"the checkpoint's {reader} reads {method} clouds of {size} points and {store.url} holds "
                           f"{store.points_method} ones of {store.points.shape[1]}; test it on a store made with "
                           f"points_method: {method}, num_points: {size}")
