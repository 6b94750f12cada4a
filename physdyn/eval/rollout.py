"""Roll-outs: the model predicts a whole trajectory from the state right after the push.

As in the paper's reference test code: the shape feature is computed once, from the
body-frame point cloud rotated into the world orientation of step 0; at each step the current velocities
are fed with the recurrent state carried over; the predicted changes are added to v, w and p and the
world-frame rotation is composed on the left, R_{t+1} = Exp(dtheta_t) R_t (physdyn's targets are
world-frame: ``physdyn.data.windows``). Quaternions are re-normalised every step.

Shapes: B sequences, S = ``steps`` predicted transitions, T = S + 1 recorded steps (step 0 included).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from physdyn.data.windows import DELTA_KEYS, relative_rotation, world_oriented_points
from physdyn.eval.metrics import TOPPLE_THRESHOLD
from physdyn.geometry.rotations import quat_multiply, quat_to_matrix, rotvec_to_quat, tilt_angle, world_delta_rotvec

STATE_KEYS = ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity")


@dataclass
class RolloutResult:
    """A predicted trajectory per sequence, SI units, world frame (docs/conventions.md).

    com_position (B, T, 3), orientation_xyzw (B, T, 4) unit quaternions, linear_velocity (B, T, 3),
    angular_velocity (B, T, 3): the state at steps 0..S.
    topple_probability (B, T) or None: the probability that the object has toppled by step t (the model's
    output at step t-1, which predicts the label of step t; 0 at step 0, where nothing has toppled yet).
    delta_* (B, S, 3): the predicted change from step t to t+1 (``delta_rotation`` world axis-angle); None
    from ``rollout(..., with_changes=False)``, whose caller reads the states only.
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


def _numpy(x: Any) -> np.ndarray:
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
    d = {k: _numpy(deltas[k]) for k in DELTA_KEYS}
    B, S = d["delta_position"].shape[:2]
    out = {
        "com_position": np.empty((B, S + 1, 3)),
        "orientation_xyzw": np.empty((B, S + 1, 4)),
        "linear_velocity": np.empty((B, S + 1, 3)),
        "angular_velocity": np.empty((B, S + 1, 3)),
    }
    q = _numpy(q0).reshape(B, 4)
    out["orientation_xyzw"][:, 0] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    for key, start, delta in (("com_position", p0, "delta_position"), ("linear_velocity", v0, "delta_linear_velocity"),
                              ("angular_velocity", w0, "delta_angular_velocity")):
        out[key][:, 0] = _numpy(start).reshape(B, 3)
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


def _warm_start(warm_start_velocities: Any, B: int) -> tuple[np.ndarray, np.ndarray]:
    if warm_start_velocities is None:
        return np.zeros((B, 0, 3)), np.zeros((B, 0, 3))
    lin, ang = (_numpy(x) for x in warm_start_velocities)
    if lin.shape != ang.shape or lin.ndim != 3 or lin.shape[0] != B or lin.shape[2] != 3:
        raise ValueError(
            f"warm_start_velocities must be (linear, angular), each (B={B}, K, 3); got {lin.shape} and {ang.shape}"
        )
    return lin, ang


def rollout(
    model: Any,
    points_body: np.ndarray,
    orientation0_xyzw: np.ndarray,
    com_position0: np.ndarray,
    lin_vel0: np.ndarray,
    ang_vel0: np.ndarray,
    steps: int,
    warm_start_velocities: tuple[np.ndarray, np.ndarray] | None = None,
    stepwise: bool = False,
    topple_points_body: np.ndarray | None = None,
    spin_inertia: np.ndarray | None = None,
    body_inertia: np.ndarray | None = None,
    lengths: np.ndarray | None = None,
    with_changes: bool = True,
    hull_counts: np.ndarray | None = None,
) -> RolloutResult:
    """Roll a predictor out for ``steps`` transitions from the state at step 0, B sequences at once.

    model: a ``DynamicsNetwork`` (or anything with its ``encode_points`` and ``step``).
    points_body: (B, N, 3) body-frame cloud (pass the number of points the model was trained on);
    orientation0_xyzw (B, 4), com_position0 (B, 3), lin_vel0 (B, 3), ang_vel0 (B, 3): step 0, world frame.
    warm_start_velocities: optional (linear, angular), each (B, K, 3): the TRUE velocities at steps 1..K,
    fed instead of the model's own (the paper's "additional velocity steps"; K = 1 for the real-world
    model). Step 0 always receives the given true velocities. During the warm start the reported
    velocities are these observations; position and orientation are always the model's integrated ones.
    A model with ``rollout_changes`` (``DynamicsNetwork``) runs the loop in torch; ``stepwise=True`` forces
    the reference loop through ``step`` (the same numbers to float32 precision; tests compare them).
    A model with a ``topple_classifier`` (``physdyn fit-topple``) reports its per-step probabilities
    instead of the head's, from ``topple_points_body`` (B, N', 3) (default: ``points_body``; one fitted on thinned
    clouds, ``fit-topple --num-points``, thins them itself).
    spin_inertia: optional (B,) I_zz / m of each body about the world vertical at step 0, for models whose
    contact prior takes the body's (``model.contact_inertia=body``; ``physdyn.geometry.mass.vertical_inertia``)
    and for an outcome correction (``physdyn fit-outcome``; without it or ``body_inertia``, estimated from
    the cloud).
    A model with an ``outcome_correction`` has the resting pose of each push that comes to rest without
    toppling corrected, the correction spread over its trajectory (``physdyn.models.outcome_correction``; one
    fitted with ``--pointnet`` reads ``points_body`` thinned as its topple PointNet's, one thinning for both,
    ``thinned_clouds``);
    ``lengths`` (B,): each sequence's own number of states (steps + 1) where a batch is padded to its longest,
    so that each is judged at its own end, as alone (``Predictor.predict_many`` passes them; without them
    every sequence is judged at the batch's horizon, as a request of that length: ``physdyn test`` on a store
    of mixed lengths, and fit-outcome's roll-outs, which run each push past its end to rest).
    body_inertia: optional (B, 3, 3) I / m of each body in world axes at step 0, for a topple classifier
    that simulates the cloud's hull (``fit-topple --physics``; ``physdyn.geometry.mass.world_inertia_per_mass``)
    and for ``model.sim_seconds``; without it those roll-outs take the hull's inertia.
    ``hull_counts`` (B,): how many of each ``points_body`` cloud's first points are its mesh's hull vertices
    (``PreparedBody.hull_count``), so a PointNet that thins them needs no qhull (``thin_hull_surface``; a
    store's clouds come without).
    ``with_changes=False``: the result's ``delta_*`` are None, for a caller that reads the states only
    (``Predictor``): an outcome correction then does not work out the corrected steps' changes again.
    A model with ``model.sim_seconds`` > 0 takes its first k steps (those seconds at its rate) from PyBullet run on the hull of
    ``topple_points_body`` (default ``points_body``) and continues from the simulated state, its recurrent
    state warmed up on the simulated velocities and orientations (``simulated_start``); a caller's warm
    start replaces it.
    """
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    given_spin_inertia = spin_inertia if body_inertia is None else _numpy(body_inertia).reshape(-1, 3, 3)[:, 2, 2]
    spin_inertia = _if_taken(model, spin_inertia)
    q0 = _numpy(orientation0_xyzw)
    B = q0.shape[0]
    warm_v, warm_w = _warm_start(warm_start_velocities, B)
    K = warm_v.shape[1]
    simulated = None
    if not K and steps and sim_steps(model):
        simulated = simulated_start(model, topple_points_body if topple_points_body is not None else points_body, q0,
                                    com_position0, lin_vel0, ang_vel0, min(sim_steps(model), steps), body_inertia)
        warm_v, warm_w = simulated["linear_velocity"][:, 1:], simulated["angular_velocity"][:, 1:]
        K = warm_v.shape[1]
    warm_turn = None if simulated is None else relative_rotation(q0, simulated["orientation_xyzw"][:, 1:])
    points = _oriented(_numpy(points_body), q0).astype(np.float32)
    if hasattr(model, "rollout_changes") and not stepwise:
        kwargs = {} if spin_inertia is None else {"spin_inertia": spin_inertia}
        if getattr(model, "topple_classifier", None) is not None:
            kwargs["topple"] = False  # the classifier's probabilities replace the head's
        if warm_turn is not None:
            kwargs["warm_turn"] = warm_turn
        out = model.rollout_changes(points, lin_vel0, ang_vel0, steps, warm_v if K else None, warm_w if K else None, **kwargs)
        changes, fed = _numpy(out["changes"]), _numpy(out["fed"])
        deltas = {k: changes[..., 3 * i : 3 * i + 3] for i, k in enumerate(DELTA_KEYS)}
        fed_v, fed_w = fed[..., :3], fed[..., 3:]
        tp = out["topple_probability"]
        topple = [] if tp is None else list(_numpy(tp).transpose(1, 0))
        v = _numpy(lin_vel0).reshape(B, 3) if not steps else fed_v[:, -1] + deltas["delta_linear_velocity"][:, -1]
        w = _numpy(ang_vel0).reshape(B, 3) if not steps else fed_w[:, -1] + deltas["delta_angular_velocity"][:, -1]
    else:
        deltas, fed_v, fed_w, topple, v, w = _stepwise(model, points, lin_vel0, ang_vel0, steps, warm_v, warm_w, spin_inertia,
                                                       warm_turn)
    if simulated is not None:  # the simulated steps' changes, then the networks' from the simulated state
        deltas = {k: np.concatenate([simulated[k], deltas[k][:, K:]], axis=1) for k in DELTA_KEYS}
        if steps <= K:  # the last state is a simulated one
            v, w = simulated["linear_velocity"][:, -1], simulated["angular_velocity"][:, -1]
    states = integrate(com_position0, q0, lin_vel0, ang_vel0, deltas)
    if K and steps:
        # the velocity track restarts from each observation: report what was fed, then the last update
        states["linear_velocity"] = np.concatenate([fed_v, v[:, None]], axis=1)
        states["angular_velocity"] = np.concatenate([fed_w, w[:, None]], axis=1)
    probability = None
    if topple or (steps == 0 and getattr(model, "predicts_topple", False)):
        probability = np.concatenate([np.zeros((B, 1)), np.stack(topple, axis=1) if topple else np.zeros((B, 0))], axis=1)
    classifier = getattr(model, "topple_classifier", None)
    turned_thinned: dict[int, np.ndarray] = {}  # size -> points_body thinned to it and turned to step 0
    if classifier is not None:
        if getattr(classifier, "thinned_from", 0):  # a PointNet fitted on thinned clouds thins what it is given
            given = _numpy(points_body if topple_points_body is None else topple_points_body)
            cloud = _oriented(classifier.body_clouds(given, hull_counts if topple_points_body is None else None), q0)
            if topple_points_body is None:  # the model's own clouds, thinned and turned: a PointNet correction may read them too
                turned_thinned[classifier.num_points] = cloud
        else:
            cloud = points if topple_points_body is None else _oriented(_numpy(topple_points_body), q0)
        probability = classifier.predict(cloud, _numpy(lin_vel0).reshape(B, 3), _numpy(ang_vel0).reshape(B, 3), steps,
                                         None if body_inertia is None else _numpy(body_inertia).reshape(B, 3, 3))
    if simulated is not None and probability is not None:
        # a push the simulated start has already toppled (the 45 degree rule) has toppled: the returned
        # poses show it, so the probabilities say it from that step on
        from physdyn.sim.trajectory import TOPPLE_ANGLE  # PyBullet (sim/): only for models that simulate

        tilted = tilt_angle(q0[:, None], simulated["orientation_xyzw"]) > TOPPLE_ANGLE  # (B, K + 1)
        over = np.maximum.accumulate(tilted, axis=1)
        probability = probability.copy()
        probability[:, : K + 1] = np.where(over, 1.0, probability[:, : K + 1])
        probability[:, K + 1 :] = np.where(over[:, -1:], 1.0, probability[:, K + 1 :])
    # one verdict per push, at its own end: the correction moves only pushes that did not topple, and
    # ``Predictor.predict_many`` reports it (a correction turns about the vertical: the tilt stays)
    toppled = toppled_by_own_end(probability, q0, states["orientation_xyzw"], lengths)
    correction = getattr(model, "outcome_correction", None)
    if correction is not None:  # fit-outcome: where the push ends, learned
        from physdyn.models.outcome_correction import correct_rollout  # torch: only for models that have one

        # a PointNet correction (fit-outcome --pointnet) reads the cloud, thinned as the classifier's: one thinning
        # (``thinned_clouds``) and, where the classifier read points_body, one turning
        clouds = None
        if getattr(correction, "num_points", 0):
            body = correction.body_clouds(_numpy(points_body), hull_counts)  # checks the size it reads
            thinned = correction.thinned_from and correction.num_points in turned_thinned
            clouds = turned_thinned[correction.num_points] if thinned else _oriented(body, q0)
        if with_changes:
            states = {**states, **{k: np.array(v) for k, v in deltas.items()}}
        correct_rollout(model, states, _numpy(lin_vel0).reshape(B, 3), _numpy(ang_vel0).reshape(B, 3), given_spin_inertia,
                        points, toppled, lengths, clouds)
        if with_changes:
            deltas = {k: states.pop(k) for k in DELTA_KEYS}
    if not with_changes:
        deltas = dict.fromkeys(DELTA_KEYS)
    return RolloutResult(**states, topple_probability=probability, **deltas, fed_linear_velocity=fed_v,
                         fed_angular_velocity=fed_w, toppled=toppled)


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


def sim_steps(model: Any) -> int:
    """The steps ``model.sim_seconds`` of a ``DynamicsNetwork`` spans at its rate, at least one when it is set
    (0 for anything else)."""
    seconds = float(getattr(getattr(getattr(model, "config", None), "model", None), "sim_seconds", 0.0) or 0.0)
    return max(1, int(round(seconds / float(model.prior_dt)))) if seconds > 0 else 0


def simulated_start(model: Any, points_body: np.ndarray, q0: np.ndarray, p0: np.ndarray, v0: np.ndarray, w0: np.ndarray,
                    steps: int, body_inertia: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The first ``steps`` steps of each push from PyBullet on its cloud's hull (``physdyn.sim.cloud_body``) at
    the model's rate and friction: ``linear_velocity`` and ``angular_velocity`` (B, steps + 1, 3),
    ``orientation_xyzw`` (B, steps + 1, 4) and the changes ``delta_*`` (B, steps, 3) between the simulated
    states (``delta_rotation`` world axis-angle).
    points_body (B, N, 3) body frame; body_inertia optional (B, 3, 3) I / m in world axes at step 0."""
    from physdyn.config import PhysicsConfig  # the config loader (omegaconf): not for the numpy baselines' path
    from physdyn.sim.cloud_body import shared_simulator  # PyBullet: only for models that simulate

    q0 = _numpy(q0).reshape(-1, 4)
    inertia = None
    if body_inertia is not None:  # world axes at step 0 -> body axes, as the body is built in its own frame
        R = quat_to_matrix(q0)
        inertia = np.swapaxes(R, 1, 2) @ _numpy(body_inertia).reshape(-1, 3, 3) @ R
    rate = 1.0 / float(model.prior_dt)
    # the conventions' physics step (1/960 s), not the topple features' 1/240 s: at 1/240 s the contact
    # chatter of the first steps cost Table 1's velocity error 23 % against 17 % (docs/research/simulated-start.md)
    with shared_simulator(PhysicsConfig().time_step) as simulator:
        sim = simulator.trajectories(_numpy(points_body), q0, _numpy(p0).reshape(-1, 3), _numpy(v0).reshape(-1, 3),
                                     _numpy(w0).reshape(-1, 3), float(model.prior_friction), steps, rate, inertia)
    return {"linear_velocity": sim["linear_velocity"], "angular_velocity": sim["angular_velocity"],
            "orientation_xyzw": sim["orientation_xyzw"],
            **state_changes(sim["com_position"], sim["orientation_xyzw"], sim["linear_velocity"], sim["angular_velocity"])}


def _if_taken(model: Any, spin_inertia: np.ndarray | None) -> np.ndarray | None:
    """The bodies' spin inertia for a model that takes it (``DynamicsNetwork``), None for one that does not:
    callers pass it always, and a predictor with only ``encode_points(points)`` and ``step`` still works."""
    return spin_inertia if hasattr(model, "with_spin_inertia") else None


def _oriented(points_body: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """``world_oriented_points`` once per distinct cloud and orientation: a batch of requests often pushes
    a few objects, each in one pose, many times (the same numbers)."""
    keys = [P.tobytes() + q.tobytes() for P, q in zip(points_body, q0)]
    first: dict[bytes, int] = {}
    index = np.array([first.setdefault(k, len(first)) for k in keys])
    if len(first) == len(keys):
        return world_oriented_points(points_body, q0)
    rows = np.unique(index, return_index=True)[1]  # the first request of each distinct one, in order
    return world_oriented_points(points_body[rows], q0[rows])[index]


def _stepwise(model: Any, points: np.ndarray, lin_vel0: Any, ang_vel0: Any, steps: int, warm_v: np.ndarray,
              warm_w: np.ndarray, spin_inertia: np.ndarray | None = None, warm_turn: np.ndarray | None = None):
    """The reference roll-out loop, one ``model.step`` per step with numpy state between steps: the path of
    any object with ``encode_points`` and ``step``, and the check on ``rollout_changes``."""
    B, K = points.shape[0], warm_v.shape[1]
    feature = model.encode_points(points) if spin_inertia is None else model.encode_points(points, spin_inertia)
    v, w = _numpy(lin_vel0).reshape(B, 3).copy(), _numpy(ang_vel0).reshape(B, 3).copy()
    fed_v, fed_w = np.empty((B, steps, 3)), np.empty((B, steps, 3))
    deltas = {k: np.empty((B, steps, 3)) for k in DELTA_KEYS}
    topple = []
    state = None
    # Models fed their orientation since step 0 (model.orientation_input) get the integrated one, composed
    # as ``integrate`` composes it: R_{t+1} = Exp(dtheta_t) R_t, so R_t R_0^T is the product of the steps.
    turn = np.tile([0.0, 0.0, 0.0, 1.0], (B, 1)) if getattr(model, "uses_orientation", False) else None
    for t in range(steps):
        if 1 <= t <= K:
            v, w = warm_v[:, t - 1].copy(), warm_w[:, t - 1].copy()
            if warm_turn is not None and turn is not None:
                turn = warm_turn[:, t - 1].copy()
        fed_v[:, t], fed_w[:, t] = v, w
        pred = model.step(feature, v, w, state) if turn is None else model.step(feature, v, w, state, turn)
        state = pred.state
        for k in DELTA_KEYS:
            deltas[k][:, t] = _numpy(getattr(pred, k))
        if turn is not None:
            turn = quat_multiply(rotvec_to_quat(deltas["delta_rotation"][:, t]), turn)
            turn /= np.linalg.norm(turn, axis=-1, keepdims=True)
        if pred.topple_probability is not None:
            topple.append(_numpy(pred.topple_probability))
        v = v + deltas["delta_linear_velocity"][:, t]
        w = w + deltas["delta_angular_velocity"][:, t]
    return deltas, fed_v, fed_w, topple, v, w


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
    spin_inertia = _if_taken(model, spin_inertia)
    q0 = _numpy(orientation0_xyzw)
    points = world_oriented_points(_numpy(points_body), q0).astype(np.float32)
    turn = None
    if getattr(model, "uses_orientation", False):
        if orientation_xyzw is None:
            raise ValueError("this model is fed its orientation since step 0: pass the true orientation_xyzw")
        turn = relative_rotation(q0, _numpy(orientation_xyzw)).astype(np.float32)
    args = (points, np.asarray(linear_velocity, np.float32), np.asarray(angular_velocity, np.float32))
    kwargs = {} if spin_inertia is None else {"spin_inertia": spin_inertia}
    pred = model.predict_window(*args, **kwargs) if turn is None else model.predict_window(*args, orientation=turn, **kwargs)
    out: dict[str, np.ndarray | None] = {k: _numpy(getattr(pred, k)) for k in DELTA_KEYS}
    out["topple_probability"] = None if pred.topple_probability is None else _numpy(pred.topple_probability)
    return out
