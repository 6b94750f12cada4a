"""Topple stages: per step, the probability that the push has toppled the object by then.

- ``head``: the network head's per-step output (none for a network without one: the 45 degree rule on the
  predicted poses then decides);
- ``logistic``: a logistic regression over physics-shaped features of the step-0 cloud and velocities,
  optionally with a short PyBullet roll-out of the cloud's hull (``physdyn.models.topple_classifier``;
  `physdyn fit-topple`, ``--physics``);
- ``pointnet``: small PointNets over the step-0 cloud in the frame of the push's travel
  (``physdyn.models.topple_pointnet``; `physdyn fit-topple --pointnet`).

The classifiers decide the whole push at step 0 and spread the probability over the steps by the training
pushes' topple times. Their weights are a checkpoint's ``topple_classifier`` entry (``classifier_from_dict``).
"""

from __future__ import annotations

from abc import abstractmethod

from typing import Any

import numpy as np

from physdyn.pipeline.stages import DEFAULT_NUM_POINTS, CloudSpec, Motion, PreparedBatch, ToppleStage
from physdyn.registry import TOPPLE_STAGES

CHECKPOINT_KEY = "topple_classifier"  # where a checkpoint holds a classifier's weights (`physdyn fit-topple`)


@TOPPLE_STAGES.register("head")
class HeadTopple(ToppleStage):
    """The motion's network head: its probability at step t-1 predicts the label of step t."""

    reads_head = True

    def run(self, batch: PreparedBatch, motion: Motion) -> np.ndarray | None:
        if motion.topple_probability is None:
            return None
        return np.concatenate([np.zeros((batch.size, 1)), motion.topple_probability], axis=1)


class _FittedTopple(ToppleStage):
    """A classifier `physdyn fit-topple` wrote into the weights: built from their entry, given the step-0 cloud,
    the push and the bodies' inertia."""

    classifier: Any

    @classmethod
    def build(cls, config: Any, source: Any) -> ToppleStage:
        return cls.from_entry(source.part(CHECKPOINT_KEY, "topple"))

    @classmethod
    @abstractmethod
    def from_entry(cls, entry: dict[str, Any]) -> ToppleStage:
        """The stage of the classifier ``entry`` (the weights' ``CHECKPOINT_KEY`` entry) describes."""

    def _predict(self, batch: PreparedBatch, cloud: np.ndarray) -> np.ndarray:
        inertia = None if batch.body_inertia is None else np.asarray(batch.body_inertia).reshape(-1, 3, 3)
        return self.classifier.predict(cloud, batch.v0, batch.w0, batch.steps, inertia)

    def _given_cloud(self, batch: PreparedBatch) -> np.ndarray:
        """The stage's own cloud where the batch has one, else the motion's, turned to step 0."""
        return batch.model_cloud() if batch.stage_points_body is None else batch.step0(batch.stage_points_body)


@TOPPLE_STAGES.register("logistic")
class LogisticTopple(_FittedTopple):
    """``ToppleClassifier``: given its own cloud size (``classifier.num_points``; None: the default stage cloud),
    surface points; with ``physics`` it simulates each push's hull for a second."""

    def __init__(self, classifier: Any):
        self.classifier = classifier
        self.simulates = bool(classifier.physics)
        self.cloud = CloudSpec(int(classifier.num_points or DEFAULT_NUM_POINTS), "surface")
        self.given_count = classifier.num_points

    @classmethod
    def from_entry(cls, entry: dict[str, Any]) -> "LogisticTopple":
        from physdyn.models.topple_classifier import ToppleClassifier

        return cls(ToppleClassifier.from_dict(entry))

    def without_simulator(self) -> ToppleStage:
        return HeadTopple() if self.simulates else self

    def run(self, batch: PreparedBatch, motion: Motion) -> np.ndarray:
        return self._predict(batch, self._given_cloud(batch))


@TOPPLE_STAGES.register("pointnet")
class PointNetTopple(_FittedTopple):
    """``PointNetToppleClassifier``: given ``hull_surface`` clouds of the size it was fitted on, or of the size
    it thins from (``thinned_to``), thinned by the batch's body cache before they are turned."""

    strict_cloud = True

    def __init__(self, classifier: Any):
        self.classifier = classifier
        self.cloud = CloudSpec(int(classifier.thinned_from or classifier.num_points), classifier.points_method)
        self.given_count = self.cloud.count

    @classmethod
    def from_entry(cls, entry: dict[str, Any]) -> "PointNetTopple":
        from physdyn.models.topple_pointnet import PointNetToppleClassifier  # torch networks: only where used

        return cls(PointNetToppleClassifier.from_dict(entry))

    def run(self, batch: PreparedBatch, motion: Motion) -> np.ndarray:
        if self.classifier.thinned_to:
            cloud = batch.step0(batch.thinned(batch.given_points_body, self.classifier.thinned_to))
        else:
            cloud = self._given_cloud(batch)
        return self._predict(batch, cloud)


def classifier_from_dict(d: dict[str, Any]) -> Any:
    """The classifier a checkpoint's ``topple_classifier`` entry holds (``ToppleClassifier``, or
    ``PointNetToppleClassifier`` for kind "pointnet", `fit-topple --pointnet`), read by its stage."""
    return TOPPLE_STAGES.get(stage_name(d)).from_entry(d).classifier


def stage_name(d: dict[str, Any] | None) -> str:
    """The topple stage that reads a checkpoint's ``topple_classifier`` entry (``head`` where it has none)."""
    if not d:
        return "head"
    return "pointnet" if d.get("kind") == "pointnet" else "logistic"
