"""End-correction stages: where a push that did not topple comes to rest.

- ``none``: the roll-out as it is;
- ``mlp``: small networks read the push and the roll-out's resting state and move the resting pose
  (``physdyn.models.outcome_correction``; `physdyn fit-outcome`);
- ``pointnet``: the same with small PointNets that also read the step-0 cloud (`physdyn fit-outcome --pointnet`).

The correction is spread over the trajectory in proportion to the roll-out's own progress, and applies only
where a push rests at its own last step and has not toppled. Its weights are a checkpoint's
``outcome_correction`` entry.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from physdyn.pipeline.stages import CloudSpec, CorrectionStage, PreparedBatch
from physdyn.registry import CORRECTION_STAGES

CHECKPOINT_KEY = "outcome_correction"  # where a checkpoint holds a correction's weights (`physdyn fit-outcome`)


@CORRECTION_STAGES.register("none")
class NoCorrection(CorrectionStage):
    """The roll-out as it is."""

    def apply(self, batch: PreparedBatch, states: dict[str, np.ndarray], toppled: np.ndarray) -> None:
        return None


@CORRECTION_STAGES.register("mlp")
class MLPCorrection(CorrectionStage):
    """``OutcomeCorrection`` of MLPs; ``rate_hz`` the roll-out's (its progress is spread at that step)."""

    def __init__(self, correction: Any, rate_hz: float):
        self.correction = correction
        self.dt = 1.0 / float(rate_hz)

    @classmethod
    def build(cls, config: Any, source: Any) -> "MLPCorrection":
        return cls.from_entry(source.part(CHECKPOINT_KEY, "correction"), source.rate_hz)

    @classmethod
    def from_entry(cls, entry: dict[str, Any], rate_hz: float) -> "MLPCorrection":
        from physdyn.models.outcome_correction import OutcomeCorrection  # torch: only for pipelines that have one

        return cls(OutcomeCorrection.from_dict(entry), rate_hz)

    def clouds(self, batch: PreparedBatch) -> np.ndarray | None:
        """What the networks read of the clouds: none for MLPs."""
        return None

    def apply(self, batch: PreparedBatch, states: dict[str, np.ndarray], toppled: np.ndarray) -> None:
        from physdyn.models.outcome_correction import correct_rollout

        correct_rollout(self.correction, self.dt, states, batch.v0, batch.w0, batch.given_spin_inertia(),
                        batch.model_cloud(), toppled, (batch.lengths, self.clouds(batch)))


@CORRECTION_STAGES.register("pointnet")
class PointNetCorrection(MLPCorrection):
    """``OutcomeCorrection`` of PointNets: it reads the motion's own cloud (``hull_surface``, of the size it was
    fitted on), thinned as fitted (``thinned_to``) by the batch's body cache, so that a topple PointNet that
    thins alike and this read one thinning, turned to the step-0 frame once."""

    strict_cloud = True

    def __init__(self, correction: Any, rate_hz: float):
        super().__init__(correction, rate_hz)
        # thinned, it reads hull_surface clouds (the hull's vertices first); else whatever the motion reads
        self.cloud = CloudSpec(int(correction.given_points), "hull_surface" if correction.thinned_from else "")

    def clouds(self, batch: PreparedBatch) -> np.ndarray:
        self.correction.check_given(batch.points_body)
        return batch.step0(batch.thinned(batch.points_body, self.correction.thinned_to))


def stage_name(d: dict[str, Any] | None) -> str:
    """The correction stage that reads a checkpoint's ``outcome_correction`` entry (``none`` where it has none)."""
    if not d:
        return "none"
    return "pointnet" if int(d.get("num_points", 0)) else "mlp"
