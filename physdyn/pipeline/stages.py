"""The three kinds of stage a predictor is made of, what each reads and what each returns.

A roll-out runs them in order (``physdyn.pipeline.engine``): the **motion** stage gives every step's change of
state from the state at step 0; the **topple** stage says, per step, how likely the push has toppled the
object; the **correction** stage moves where a push that did not topple comes to rest. Each reads a
``PreparedBatch``: B pushes, each with one body-frame cloud, its step-0 state and its body's inertia; a
stage that reads a cloud asks the batch for it in the **step-0 frame** (``PreparedBatch.step0``: body-frame
points turned to the body's world orientation at step 0, centre of mass at the origin), turned once per
batch, whichever stages read it.

A new stage is a subclass registered under a name (``@TOPPLE_STAGES.register("mine")``) and that name in a
predictor preset (configs/predictor/, ``topple: {name: mine}``); docs/architecture.md, "Stages and presets".

Shapes: B pushes, S = ``steps`` predicted transitions, K warm-start steps.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from physdyn.data.windows import world_oriented_points

DEFAULT_NUM_POINTS = 1024  # the cloud a stage reads that names no size of its own (a simulation's hull)
THINNED_KEPT = 256  # thinned clouds a ``BodyCache`` keeps, the latest


@dataclass(frozen=True)
class CloudSpec:
    """Which body-frame cloud of a mesh a stage is given: ``count`` points sampled by ``method``
    ("surface" or "hull_surface"; ``physdyn.predict.body.PreparedBody.points_body``)."""

    count: int
    method: str = "surface"


class BodyCache:
    """What a predictor keeps about the bodies it has seen: its prepared meshes (``meshes``, least recently used
    first, filled by ``Predictor._bodies``) and the thinned clouds its PointNets read (``thin``). ``forget``
    drops both, and the simulator's hull shapes, so the next request pays for its preparation as a new mesh
    does (benchmarks/frontier.py)."""

    def __init__(self) -> None:
        from collections import OrderedDict

        self.meshes: OrderedDict[tuple, Any] = OrderedDict()
        self.thinned: dict[tuple, np.ndarray] = {}  # (count, cloud bytes, hull count) -> thinned cloud

    def thin(self, points_body: np.ndarray, count: int, hull_counts: Any = None) -> np.ndarray:
        """``physdyn.models.topple_pointnet.thinned_clouds`` with this cache: each distinct cloud thinned once."""
        from physdyn.models.topple_pointnet import thinned_clouds

        return thinned_clouds(points_body, count, hull_counts, kept=self.thinned)

    def forget(self) -> None:
        from physdyn.sim.cloud_body import forget_clouds  # PyBullet's hull shapes, keyed by content

        self.meshes.clear()
        self.thinned.clear()
        forget_clouds()


@dataclass
class PreparedBatch:
    """B pushes ready for the stages, SI units, world frame.

    points_body (B, N, 3): each body's cloud in its own frame (centre of mass at the origin), the one the
    motion stage reads; stage_points_body (B, N', 3) or None: the cloud the other stages are given where it
    differs (a topple classifier's size, a simulation's hull: ``Pipeline.stage_cloud``).
    q0 (B, 4) xyzw, p0, v0, w0 (B, 3): the state at step 0. steps: S.
    warm_linear, warm_angular (B, K, 3): the true velocities of steps 1..K, fed instead of the model's own.
    spin_inertia (B,) or None: each body's I_zz / m about the vertical at step 0; body_inertia (B, 3, 3) or
    None: its I / m in world axes at step 0 (None: stages estimate them from the cloud).
    lengths (B,) or None: each push's own number of states where the batch is padded to its longest.
    hull_counts (B,) or None: how many of each ``points_body`` cloud's first points are its mesh's hull vertices.
    with_changes: whether the result carries the per-step changes (``delta_*``) or only the states.
    friction (B,) or None: each push's effective Coulomb coefficient with the ground (None: the model's own),
    for a motion stage that ``takes_friction``.
    """

    points_body: np.ndarray
    q0: np.ndarray
    p0: np.ndarray
    v0: np.ndarray
    w0: np.ndarray
    steps: int
    warm_linear: np.ndarray
    warm_angular: np.ndarray
    stage_points_body: np.ndarray | None = None
    spin_inertia: np.ndarray | None = None
    body_inertia: np.ndarray | None = None
    lengths: np.ndarray | None = None
    hull_counts: np.ndarray | None = None
    with_changes: bool = True
    cache: BodyCache = field(default_factory=BodyCache)
    friction: np.ndarray | None = None
    _turned: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)
    _thinned: dict[tuple[int, int], np.ndarray] = field(default_factory=dict, repr=False)
    _model_cloud: np.ndarray | None = field(default=None, repr=False)

    @property
    def size(self) -> int:
        return len(self.q0)

    @property
    def given_points_body(self) -> np.ndarray:
        """The body-frame cloud stages other than the motion are given: ``stage_points_body`` or ``points_body``."""
        return self.points_body if self.stage_points_body is None else self.stage_points_body

    def step0(self, points_body: np.ndarray) -> np.ndarray:
        """(B, N, 3) body frame -> the step-0 frame (float64), once per array and per batch."""
        key = id(points_body)
        if key not in self._turned:
            self._turned[key] = (points_body, _oriented(np.asarray(points_body, np.float64), self.q0))
        return self._turned[key][1]

    def model_cloud(self) -> np.ndarray:
        """(B, N, 3) float32: ``points_body`` in the step-0 frame, as the networks read it."""
        if self._model_cloud is None:
            self._model_cloud = self.step0(self.points_body).astype(np.float32)
        return self._model_cloud

    def thinned(self, points_body: np.ndarray, count: int) -> np.ndarray:
        """(B, count, 3) body frame: ``points_body`` thinned by ``thin_hull_surface`` (as given for count 0),
        once per batch, so two stages that thin alike read one array (and ``step0`` turns it once)."""
        key = (id(points_body), int(count))
        if key not in self._thinned:
            hulls = self.hull_counts if points_body is self.points_body else None
            self._thinned[key] = self.cache.thin(np.asarray(points_body), int(count), hulls)
        return self._thinned[key]

    def given_spin_inertia(self) -> np.ndarray | None:
        """(B,) I_zz / m: from ``body_inertia`` where given, else ``spin_inertia`` (None: neither)."""
        if self.body_inertia is not None:
            return np.asarray(self.body_inertia, np.float64).reshape(-1, 3, 3)[:, 2, 2]
        return self.spin_inertia


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


@dataclass
class Motion:
    """What a motion stage returns: per-step changes from the state at step 0.

    deltas: ``delta_*`` (B, S, 3) each (``physdyn.data.windows.DELTA_KEYS``; ``delta_rotation`` world
    axis-angle, R_{t+1} = Exp(d_t) R_t). fed_linear_velocity, fed_angular_velocity (B, S, 3): the velocities
    fed at each step; last_linear_velocity, last_angular_velocity (B, 3): those of step S. warm_steps: K, the
    steps whose velocities were observed or simulated rather than integrated (their velocity track is the fed
    one). topple_probability (B, S) or None: the network head's probability that step t+1 has toppled.
    toppled_steps (B, K + 1) bool or None: the steps a simulation has shown toppled (past 45 degrees).
    """

    deltas: dict[str, np.ndarray]
    fed_linear_velocity: np.ndarray
    fed_angular_velocity: np.ndarray
    last_linear_velocity: np.ndarray
    last_angular_velocity: np.ndarray
    warm_steps: int = 0
    topple_probability: np.ndarray | None = None
    toppled_steps: np.ndarray | None = None


class Stage(ABC):
    """What every stage says of itself. ``build`` makes one from its preset's typed ``Config`` (the class's
    ``Config`` dataclass, if any) and the ``StageSource`` of the preset's weights."""

    registered_name: ClassVar[str] = ""
    simulates: bool = False  # whether it runs PyBullet inside a prediction
    strict_cloud: ClassVar[bool] = False  # whether it reads only clouds of exactly its ``cloud`` (a store must hold them)

    @classmethod
    def build(cls, config: Any, source: Any) -> "Stage":
        return cls() if config is None else cls(config)  # type: ignore[call-arg]

    def without_simulator(self) -> "Stage":
        """This stage with nothing simulated (itself where it simulates nothing)."""
        return self


class MotionStage(Stage):
    """Per-step changes of state from step 0. ``cloud``: the cloud it reads (``PreparedBatch.points_body``);
    ``rate_hz``: its steps' rate; ``network``: its ``DynamicsNetwork``, if it has one."""

    cloud: CloudSpec
    rate_hz: float
    network: Any = None
    predicts_topple: bool = False  # whether ``run(..., with_topple=True)`` gives the head's probabilities
    reads_stage_cloud: bool = False  # whether it reads ``PreparedBatch.given_points_body`` too
    takes_friction: bool = False  # whether it reads ``PreparedBatch.friction`` (else it predicts at its own)

    @abstractmethod
    def run(self, batch: PreparedBatch, with_topple: bool) -> Motion:
        """The changes of ``batch``'s S steps; ``with_topple``: the head's probabilities are wanted."""


class ToppleStage(Stage):
    """Per-step topple probabilities. ``reads_head``: it reads the motion's ``topple_probability``;
    ``cloud``: the body-frame cloud it is given (None: none, or the motion's)."""

    reads_head: ClassVar[bool] = False
    cloud: CloudSpec | None = None
    given_count: int | None = None  # the size of the cloud it is given from a store (None: all its points)

    @abstractmethod
    def run(self, batch: PreparedBatch, motion: Motion) -> np.ndarray | None:
        """(B, S + 1) the probability that each push has toppled by step t (0 at step 0), or None: no
        topple output (the 45 degree rule on the poses then decides)."""


class CorrectionStage(Stage):
    """A change to the integrated trajectory, in place. ``cloud``: the body-frame cloud it reads (None: none;
    a method of "" reads the motion's, whatever its method)."""

    cloud: CloudSpec | None = None

    @abstractmethod
    def apply(self, batch: PreparedBatch, states: dict[str, np.ndarray], toppled: np.ndarray) -> None:
        """Change ``states`` in place: ``com_position`` (B, T, 3), ``orientation_xyzw`` (B, T, 4),
        ``linear_velocity``, ``angular_velocity`` (B, T, 3), and where present ``delta_*`` (B, S, 3) to
        match; ``toppled`` (B,): each push's verdict at its own end."""
