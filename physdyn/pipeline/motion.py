"""Motion stages: every step's change of state from the state at step 0.

- ``network``: a ``DynamicsNetwork`` rolled out on its own velocities (the shape encoded once from the cloud
  in the step-0 frame; at each step the current velocities fed with the recurrent state carried over), in
  torch or, for one object, on numpy (``DynamicsNetwork.rollout_changes``);
- ``contact_prior``: the contact prior alone, no network (a ``DynamicsNetwork`` whose changes are its prior's:
  ``model.predictor: none`` and a zero residual; ``changes_are_the_prior``), with the body's own spin inertia;
- ``simulated_start``: the first ``sim_seconds`` from PyBullet on the hull of the stage cloud, then the
  network from the simulated state, its recurrent state warmed up on the simulated velocities and
  orientations (``bundled``; docs/research/simulated-start.md). A caller's warm start replaces it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from physdyn.data.windows import DELTA_KEYS, relative_rotation
from physdyn.errors import ConfigError, PredictionError
from physdyn.geometry.rotations import quat_multiply, quat_to_matrix, rotvec_to_quat, tilt_angle
from physdyn.models.dynamics_network import DynamicsNetwork
from physdyn.models.heads.base import NUM_CHANGES
from physdyn.models.prior_rollout import prior_rollout
from physdyn.pipeline.stages import CloudSpec, Motion, MotionStage, PreparedBatch
from physdyn.pipeline.trajectory import as_float64, state_changes
from physdyn.registry import MOTION_STAGES


@MOTION_STAGES.register("network")
class NetworkMotion(MotionStage):
    """A network's roll-out (``network``: a ``DynamicsNetwork``, or any object with its ``encode_points`` and
    ``step``, rolled out step by step)."""

    @dataclass
    class Config:
        reference_loop: bool = False  # one ``network.step`` per step with numpy between steps: the check on the torch loop

    def __init__(self, network: Any, config: "NetworkMotion.Config | None" = None):
        self.network = network
        self.config = config or NetworkMotion.Config()
        info = network.data_info if isinstance(network, DynamicsNetwork) else {}
        self.rate_hz = float(info.get("rate_hz") or 15.0)
        self.cloud = CloudSpec(int(getattr(network, "num_points", None) or info.get("num_points") or 1024),
                               str(info.get("points_method") or "surface"))
        self.predicts_topple = bool(getattr(network, "predicts_topple", False))

    @classmethod
    def build(cls, config: Any, source: Any) -> "NetworkMotion":
        return cls(source.network(), config)

    def run(self, batch: PreparedBatch, with_topple: bool) -> Motion:
        return self.changes(batch, (batch.warm_linear, batch.warm_angular), None, with_topple)

    def changes(self, batch: PreparedBatch, warm: tuple[np.ndarray, np.ndarray], warm_turn: np.ndarray | None,
                with_topple: bool) -> Motion:
        """The network's changes with the velocities ``warm`` (each (B, K, 3)) fed at steps 1..K and, for a
        network fed its orientation, ``warm_turn`` (B, K, 4) the rotations since step 0 at those steps."""
        model, steps = self.network, batch.steps
        warm_v, warm_w = warm
        K = warm_v.shape[1]
        points = batch.model_cloud()
        spin = batch.spin_inertia if isinstance(model, DynamicsNetwork) else None  # a stand-in takes none
        if isinstance(model, DynamicsNetwork) and not self.config.reference_loop:
            kwargs: dict[str, Any] = {} if spin is None else {"spin_inertia": spin}
            if not with_topple:
                kwargs["topple"] = False
            if warm_turn is not None:
                kwargs["warm_turn"] = warm_turn
            out = model.rollout_changes(points, batch.v0, batch.w0, steps, warm_v if K else None, warm_w if K else None, **kwargs)
            return self._motion(batch, out["changes"], out["fed"], out["topple_probability"], K)
        deltas, fed_v, fed_w, topple, v, w = reference_loop(model, points, batch, (warm_v, warm_w), spin, warm_turn)
        if topple is None and steps == 0 and self.predicts_topple:
            topple = np.zeros((batch.size, 0))
        return Motion(deltas, fed_v, fed_w, v, w, K, topple)

    def _motion(self, batch: PreparedBatch, changes: Any, fed: Any, topple: Any, K: int) -> Motion:
        """A ``Motion`` from ``rollout_changes``' arrays: changes (B, S, 12), fed (B, S, 6), topple (B, S) or None."""
        changes, fed = as_float64(changes), as_float64(fed)
        deltas = {k: changes[..., 3 * i : 3 * i + 3] for i, k in enumerate(DELTA_KEYS)}
        fed_v, fed_w = fed[..., :3], fed[..., 3:]
        topple = None if topple is None else as_float64(topple)
        v = batch.v0 if not batch.steps else fed_v[:, -1] + deltas["delta_linear_velocity"][:, -1]
        w = batch.w0 if not batch.steps else fed_w[:, -1] + deltas["delta_angular_velocity"][:, -1]
        if topple is None and batch.steps == 0 and self.predicts_topple:
            topple = np.zeros((batch.size, 0))
        return Motion(deltas, fed_v, fed_w, v, w, K, topple)


@MOTION_STAGES.register("contact_prior")
class ContactPriorMotion(NetworkMotion):
    """The contact prior alone. Built from weights (``fast``), it is theirs: their rate, friction and
    normalisation; built without (the ``contact_prior`` preset), from ``configs/experiment/contact_prior.yaml``
    at the rate, cloud and physics the preset gives."""

    @dataclass
    class Config:
        rate_hz: float = 15.0  # without weights: the steps' rate
        num_points: int = 256  # without weights: the hull_surface cloud whose footprint it reads

    takes_friction = True

    def __init__(self, network: DynamicsNetwork):
        if not network.changes_are_the_prior():
            raise ConfigError("motion 'contact_prior': the weights hold a network whose changes are not its prior's; "
                              "name motion 'network' for it")
        super().__init__(network)

    def run(self, batch: PreparedBatch, with_topple: bool) -> Motion:
        if batch.friction is None:
            return super().run(batch, with_topple)
        if batch.warm_linear.shape[1]:
            raise PredictionError("a warm start and a friction of its own for each push do not go together; drop one")
        # friction is an input of the prior, not a weight: each push slides at its own (the numpy roll-out)
        model = self.network
        spin = batch.spin_inertia
        code = model.encode_points(batch.model_cloud(), None if spin is None else torch.as_tensor(spin))
        geometry = model.split_code(code)[1].double().cpu().numpy()
        out = prior_rollout(geometry, batch.v0, batch.w0, batch.steps, model.prior_dt, batch.friction,
                            model.prior_gravity, model.config.model.contact_substeps)
        topple = None
        if with_topple and model.predicts_topple:  # the head's bias, as the torch roll-out gives it
            topple = np.full((batch.size, batch.steps), float(torch.sigmoid(model.head.linear.bias[NUM_CHANGES])))
        return self._motion(batch, out["changes"], out["fed"], topple, 0)

    @classmethod
    def build(cls, config: Any, source: Any) -> "ContactPriorMotion":
        if source.checkpoint is not None:
            return cls(source.network())
        return cls(contact_prior_network(source.physics, config.rate_hz, config.num_points))


def contact_prior_network(physics: Any, rate_hz: float, num_points: int) -> DynamicsNetwork:
    """A ``DynamicsNetwork`` that is the contact prior alone (``configs/experiment/contact_prior.yaml``), at the
    friction and gravity of ``physics`` (None: the conventions')."""
    from physdyn.config import PRESETS, ExperimentConfig, PhysicsConfig, load_config
    from physdyn.data.normalization import Normalization
    from physdyn.models.experiment_checks import check_experiment_config

    physics = physics or PhysicsConfig()
    # the shipped preset, checked as training checks it but for the trainer's keys (those need Lightning's)
    cfg = check_experiment_config(load_config(ExperimentConfig, PRESETS / "experiment" / "contact_prior.yaml"))
    info = {"rate_hz": float(rate_hz), "num_points": int(num_points), "points_method": "hull_surface",
            "friction": physics.lateral_friction_object * physics.lateral_friction_ground, "gravity": abs(physics.gravity)}
    model = DynamicsNetwork(cfg, Normalization(mode="std_inputs", input_mean=(0.0,) * 6, input_std=(1.0,) * 6), info)
    return model.eval()


@MOTION_STAGES.register("simulated_start")
class SimulatedStartMotion(NetworkMotion):
    """``sim_seconds`` of PyBullet, then the network. It reads the stage cloud (``reads_stage_cloud``) for
    the hull it simulates, and the bodies' inertia where given."""

    simulates = True
    reads_stage_cloud = True

    @dataclass
    class Config:
        sim_seconds: float | None = None  # None: the weights' model.sim_seconds

    def __init__(self, network: DynamicsNetwork, sim_seconds: float):
        super().__init__(network)
        self.sim_seconds = float(sim_seconds)
        if not self.sim_seconds > 0:
            raise ConfigError(f"motion 'simulated_start': sim_seconds must be positive, got {sim_seconds}; "
                              "name motion 'network' for none")

    @classmethod
    def build(cls, config: Any, source: Any) -> "SimulatedStartMotion":
        network = source.network()
        seconds = network.config.model.sim_seconds if config.sim_seconds is None else config.sim_seconds
        return cls(network, seconds)

    @property
    def sim_steps(self) -> int:
        """The steps ``sim_seconds`` spans at the network's rate, at least one."""
        return max(1, int(round(self.sim_seconds / float(self.network.prior_dt))))

    def without_simulator(self) -> NetworkMotion:
        return NetworkMotion(self.network)

    def run(self, batch: PreparedBatch, with_topple: bool) -> Motion:
        if batch.warm_linear.shape[1] or not batch.steps:
            return super().run(batch, with_topple)
        q0 = batch.q0
        simulated = simulated_start(self.network, batch.given_points_body, batch, min(self.sim_steps, batch.steps))
        K = simulated["linear_velocity"].shape[1] - 1
        warm = (simulated["linear_velocity"][:, 1:], simulated["angular_velocity"][:, 1:])
        motion = self.changes(batch, warm, relative_rotation(q0, simulated["orientation_xyzw"][:, 1:]), with_topple)
        # the simulated steps' changes, then the networks' from the simulated state
        deltas = {k: np.concatenate([simulated[k], motion.deltas[k][:, K:]], axis=1) for k in DELTA_KEYS}
        v, w = motion.last_linear_velocity, motion.last_angular_velocity
        if batch.steps <= K:  # the last state is a simulated one
            v, w = simulated["linear_velocity"][:, -1], simulated["angular_velocity"][:, -1]
        from physdyn.sim.trajectory import TOPPLE_ANGLE  # the conventions' topple rule

        # a push the simulated start has toppled (the 45 degree rule) has toppled: the poses show it
        tilted = tilt_angle(q0[:, None], simulated["orientation_xyzw"]) > TOPPLE_ANGLE  # (B, K + 1)
        return replace(motion, deltas=deltas, last_linear_velocity=v, last_angular_velocity=w,
                       toppled_steps=np.maximum.accumulate(tilted, axis=1))


def simulated_start(model: DynamicsNetwork, points_body: np.ndarray, batch: PreparedBatch, steps: int) -> dict[str, np.ndarray]:
    """The first ``steps`` steps of each push of ``batch`` from PyBullet on its cloud's hull
    (``physdyn.sim.cloud_body``; points_body (B, N, 3) body frame) at ``model``'s rate and friction, with the
    batch's ``body_inertia`` where given: ``linear_velocity`` and ``angular_velocity`` (B, steps + 1, 3),
    ``orientation_xyzw`` (B, steps + 1, 4) and the changes ``delta_*`` (B, steps, 3) between the simulated
    states (``delta_rotation`` world axis-angle)."""
    from physdyn.config import PhysicsConfig  # the config loader (omegaconf)
    from physdyn.sim.cloud_body import shared_simulator  # PyBullet: only for stages that simulate

    q0 = batch.q0
    inertia = None
    if batch.body_inertia is not None:  # world axes at step 0 -> body axes, as the body is built in its own frame
        R = quat_to_matrix(q0)
        inertia = np.swapaxes(R, 1, 2) @ as_float64(batch.body_inertia).reshape(-1, 3, 3) @ R
    rate = 1.0 / float(model.prior_dt)
    # the conventions' physics step (1/960 s), not the topple features' 1/240 s: at 1/240 s the contact
    # chatter of the first steps cost Table 1's velocity error 23 % against 17 % (docs/research/simulated-start.md)
    with shared_simulator(PhysicsConfig().time_step) as simulator:
        sim = simulator.trajectories(as_float64(points_body), q0, batch.p0, batch.v0, batch.w0, float(model.prior_friction),
                                     steps, rate, inertia)
    return {"linear_velocity": sim["linear_velocity"], "angular_velocity": sim["angular_velocity"],
            "orientation_xyzw": sim["orientation_xyzw"],
            **state_changes(sim["com_position"], sim["orientation_xyzw"], sim["linear_velocity"], sim["angular_velocity"])}


def reference_loop(model: Any, points: np.ndarray, batch: PreparedBatch, warm: tuple[np.ndarray, np.ndarray],
                   spin_inertia: np.ndarray | None = None, warm_turn: np.ndarray | None = None):
    """The reference roll-out loop, one ``model.step`` per step with numpy state between steps: the path of
    any object with ``encode_points`` and ``step``, and the check on ``rollout_changes``. points (B, N, 3)
    float32 in the step-0 frame. Returns (deltas, fed v, fed w, topple (B, S) or None, last v, last w)."""
    (warm_v, warm_w), steps = warm, batch.steps
    B, K = points.shape[0], warm_v.shape[1]
    feature = model.encode_points(points) if spin_inertia is None else model.encode_points(points, spin_inertia)
    v, w = batch.v0.copy(), batch.w0.copy()
    fed_v, fed_w = np.empty((B, steps, 3)), np.empty((B, steps, 3))
    deltas = {k: np.empty((B, steps, 3)) for k in DELTA_KEYS}
    topple = []
    state = None
    # Models fed their orientation since step 0 (model.orientation_input) get the integrated one, composed
    # as ``integrate`` composes it: R_{t+1} = Exp(dtheta_t) R_t, so R_t R_0^T is the product of the steps.
    orientation = isinstance(model, DynamicsNetwork) and model.uses_orientation
    turn = np.tile([0.0, 0.0, 0.0, 1.0], (B, 1)) if orientation else None
    for t in range(steps):
        if 1 <= t <= K:
            v, w = warm_v[:, t - 1].copy(), warm_w[:, t - 1].copy()
            if warm_turn is not None and turn is not None:
                turn = warm_turn[:, t - 1].copy()
        fed_v[:, t], fed_w[:, t] = v, w
        pred = model.step(feature, v, w, state) if turn is None else model.step(feature, v, w, state, turn)
        state = pred.state
        for k in DELTA_KEYS:
            deltas[k][:, t] = as_float64(getattr(pred, k))
        if turn is not None:
            turn = quat_multiply(rotvec_to_quat(deltas["delta_rotation"][:, t]), turn)
            turn /= np.linalg.norm(turn, axis=-1, keepdims=True)
        if pred.topple_probability is not None:
            topple.append(as_float64(pred.topple_probability))
        v = v + deltas["delta_linear_velocity"][:, t]
        w = w + deltas["delta_angular_velocity"][:, t]
    return deltas, fed_v, fed_w, np.stack(topple, axis=1) if topple else None, v, w
