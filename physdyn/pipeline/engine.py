"""A predictor's pipeline and the one roll-out engine that runs its stages in order.

motion (every step's change from step 0) -> integration (the states) -> topple (per-step probabilities) ->
the verdict at each push's own end -> end correction. The engine knows the three kinds of stage by their
interfaces (``physdyn.pipeline.stages``), not which ones exist.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from physdyn.data.windows import DELTA_KEYS
from physdyn.errors import PredictionError
from physdyn.pipeline.spread import DistributionStage, SampledPushes
from physdyn.pipeline.stages import DEFAULT_NUM_POINTS, CloudSpec, CorrectionStage, MotionStage, PreparedBatch, ToppleStage
from physdyn.pipeline.trajectory import RolloutResult, integrate, toppled_by_own_end


@dataclass
class Pipeline:
    """One stage of each kind; ``name`` says what a prediction's ``checkpoint`` key says (a preset or a path).
    ``distribution``: how a distribution forecast makes its samples (``physdyn.pipeline.spread``)."""

    motion: MotionStage
    topple: ToppleStage
    correction: CorrectionStage
    name: str = "model"
    distribution: DistributionStage = field(default_factory=SampledPushes)

    @property
    def network(self) -> Any:
        """The motion stage's ``DynamicsNetwork`` (None where it has none)."""
        return self.motion.network

    @property
    def rate_hz(self) -> float:
        return float(self.motion.rate_hz)

    @property
    def num_points(self) -> int:
        """The size of the cloud the motion reads (``PreparedBatch.points_body``)."""
        return int(self.motion.cloud.count)

    @property
    def points_method(self) -> str:
        return str(self.motion.cloud.method)

    @property
    def simulates(self) -> bool:
        """Whether a prediction runs PyBullet (a simulated start, a classifier's roll-out)."""
        return any(stage.simulates for stage in (self.motion, self.topple, self.correction))

    def stage_cloud(self) -> CloudSpec | None:
        """The cloud the topple stage is given, or the hull a simulating motion reads, where it is not the
        motion's own (``PreparedBatch.stage_points_body``); None where no stage needs another."""
        spec = self.topple.cloud
        if spec is None and self.motion.reads_stage_cloud:
            spec = CloudSpec(DEFAULT_NUM_POINTS, "surface")
        return None if spec is None or spec == self.motion.cloud else spec

    def without_simulator(self) -> "Pipeline":
        """The same stages with nothing simulated at inference (each stage's ``without_simulator``): no
        simulated start, and a topple classifier that simulates gives way to the network's head. The weights
        are shared; this pipeline itself where it simulates nothing."""
        if not self.simulates:
            return self
        return replace(self, motion=self.motion.without_simulator(), topple=self.topple.without_simulator(),
                       correction=self.correction.without_simulator(), name=f"{self.name} without simulator")

    def to(self, device: str) -> "Pipeline":
        """The networks on ``device``."""
        if hasattr(self.network, "to"):
            self.network.to(device)
        return self


def run_stages(pipeline: Pipeline, batch: PreparedBatch) -> RolloutResult:
    """Roll ``batch`` out through ``pipeline``'s stages: the states of steps 0..S, per-step topple
    probabilities, each push's verdict at its own end, the corrected resting poses."""
    if batch.friction is not None and not pipeline.motion.takes_friction:
        raise PredictionError(f"the model '{pipeline.name}' predicts at the friction it was trained at (its motion "
                              f"'{pipeline.motion.registered_name}' takes none); drop the friction, or predict with "
                              "fast or contact_prior, whose contact prior takes it")
    motion = pipeline.motion.run(batch, with_topple=pipeline.topple.reads_head)
    states = integrate(batch.p0, batch.q0, batch.v0, batch.w0, motion.deltas)
    if motion.warm_steps and batch.steps:
        # the velocity track restarts from each observation: report what was fed, then the last update
        states["linear_velocity"] = np.concatenate([motion.fed_linear_velocity, motion.last_linear_velocity[:, None]], axis=1)
        states["angular_velocity"] = np.concatenate([motion.fed_angular_velocity, motion.last_angular_velocity[:, None]], axis=1)
    probability = pipeline.topple.run(batch, motion)
    if motion.toppled_steps is not None and probability is not None:
        # a step a simulation showed toppled has toppled, whatever the topple stage says: certain from then on
        over, K = motion.toppled_steps, motion.toppled_steps.shape[1] - 1
        probability = probability.copy()
        probability[:, : K + 1] = np.where(over, 1.0, probability[:, : K + 1])
        probability[:, K + 1 :] = np.where(over[:, -1:], 1.0, probability[:, K + 1 :])
    # one verdict per push, at its own end: the correction moves only pushes that did not topple
    toppled = toppled_by_own_end(probability, batch.q0, states["orientation_xyzw"], batch.lengths)
    if batch.with_changes:
        states.update({k: np.array(v) for k, v in motion.deltas.items()})
    pipeline.correction.apply(batch, states, toppled)
    deltas = {k: states.pop(k) for k in DELTA_KEYS} if batch.with_changes else dict.fromkeys(DELTA_KEYS)
    return RolloutResult(**states, topple_probability=probability, **deltas, fed_linear_velocity=motion.fed_linear_velocity,
                         fed_angular_velocity=motion.fed_angular_velocity, toppled=toppled)
