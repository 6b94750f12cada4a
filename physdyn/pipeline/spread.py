"""A predictor's distribution stage: how a forecast makes N outcomes of one push known only roughly.

Two are built in (a preset's ``distribution: {name: ...}``; plugins add more through the entry-point group
``physdyn.distribution_stages``):

- ``sampled_pushes``: N pushes drawn from the uncertainty (``physdyn.pipeline.distribution.sample_requests``),
  each rolled out by the pipeline. Its spread is the push's alone: where the model is wrong, every sample is
  wrong the same way.
- ``calibrated``: one roll-out of the push as given, and N outcomes drawn around its end. The final position
  moves along and across the travel and the final heading turns, each by a Gaussian whose standard deviation
  has two parts: the push's (what the uncertainty spreads the outcome by, scaled from the default
  uncertainty's) and the model's own error; each part is a power law of the roll-out's travel and turn,
  fitted by maximum likelihood to ensemble stores (``physdyn fit-spread``,
  ``physdyn.pipeline.spread_fit``). Each sample's topple verdict is drawn from the roll-out's topple
  probability, and a sample drawn as toppled ends by a wider law of its own. Each sample's path reaches its end as the roll-out's reaches its own: an
  offset is added in proportion to the distance travelled so far, a turn in proportion to the turn so far.
  The topple probability is the roll-out's own.

With zero uncertainty every forecast is the prediction itself, N times. Shapes: P pushes, N samples, T steps.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from physdyn.config.uncertainty import UNCERTAINTY_PRESETS, UncertaintyConfig
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, turn_about_vertical
from physdyn.pipeline.stages import Stage
from physdyn.registry import DISTRIBUTION_STAGES

COMPONENTS = ("along", "across", "turn")  # the final position along and across the travel (m), the heading (rad)
# a power law's inputs: a constant, log(travel + 1 cm) and log(|turn| + 0.05 rad) of the roll-out (the push's
# speed added nothing on held-out shapes: a slide's travel already goes as its square)
FEATURE_FLOORS = (0.01, 0.05)
NUM_FEATURES = 1 + len(FEATURE_FLOORS)


class DistributionStage(Stage):
    """``rolls_out_samples``: the caller rolls out N sampled pushes (``sampled_pushes``); otherwise the stage is
    a ``SpreadStage``: the caller rolls out the push as given and ``spread`` draws the N outcomes around it."""

    rolls_out_samples: ClassVar[bool] = True


class SpreadStage(DistributionStage):
    """A distribution stage that draws N outcomes around the one roll-out of the push as given."""

    rolls_out_samples = False

    @abstractmethod
    def spread(self, nominal: dict[str, np.ndarray], lin_vel: np.ndarray, ang_vel: np.ndarray,
               uncertainty: UncertaintyConfig, samples: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """nominal: ``com_position`` (P, T, 3), ``orientation_xyzw`` (P, T, 4), ``topple_by_step`` (P, T) (each
        push's probability of having toppled by step t, never decreasing); lin_vel, ang_vel (P, 3) ->
        ``com_position`` (P, N, T, 3), ``orientation_xyzw`` (P, N, T, 4), ``toppled`` (P, N) bool."""


@DISTRIBUTION_STAGES.register("sampled_pushes")
class SampledPushes(DistributionStage):
    """N pushes drawn from the uncertainty, each rolled out by the pipeline (the caller's batches)."""

    rolls_out_samples = True


@DISTRIBUTION_STAGES.register("calibrated")
class CalibratedSpread(SpreadStage):
    """One roll-out and a fitted spread around its end (the module docstring)."""

    @dataclass
    class Config:
        # log standard deviations as power laws, one row per component (along m, across m, turn rad), each
        # [constant, travel, turn] (FEATURE_FLOORS): the push's part at the default uncertainty, and the
        # model's own error (`physdyn fit-spread` writes both)
        push: list = field(default_factory=lambda: [[-9.0, 0.0, 0.0]] * 3)
        model: list = field(default_factory=lambda: [[-9.0, 0.0, 0.0]] * 3)
        # where a sample drawn as toppled ends, along and across (push and model together): toppling moves a
        # body off the path it slid along
        toppled: list = field(default_factory=lambda: [[-9.0, 0.0, 0.0]] * 2)
        # the roll-outs' travel (m) and |turn| (rad) the laws were fitted over: a power law holds there, and
        # beyond it the spread is the nearest edge's (a spin in place would otherwise read as a tiny travel)
        travel_range: list = field(default_factory=lambda: [0.0, 1e9])
        turn_range: list = field(default_factory=lambda: [0.0, 1e9])
        fitted_on: str = ""  # what the coefficients were fitted on, for the model card

    def __init__(self, config: "CalibratedSpread.Config | None" = None):
        self.config = config or self.Config()
        self.push = _coefficients(self.config.push, "push")
        self.model = _coefficients(self.config.model, "model")
        self.toppled = _coefficients(self.config.toppled, "toppled", 2)
        ranges = [_range(self.config.travel_range, "travel_range"), _range(self.config.turn_range, "turn_range")]
        self.feature_low = np.log(np.array([r[0] for r in ranges]) + FEATURE_FLOORS)
        self.feature_high = np.log(np.array([r[1] for r in ranges]) + FEATURE_FLOORS)

    def within_range(self, features: np.ndarray) -> np.ndarray:
        """(P, NUM_FEATURES) with travel and turn clipped to the range the laws were fitted over."""
        out = np.array(features, dtype=np.float64)
        out[:, 1:] = np.clip(out[:, 1:], self.feature_low, self.feature_high)
        return out

    def sigmas(self, features: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """(P, NUM_FEATURES), the push part's scale (3,) (``push_scale``) -> (P, 3) standard deviations of an
        upright outcome's along (m), across (m) and turn (rad)."""
        f = self.within_range(features)
        push = np.exp(f @ self.push.T) * scale
        return np.sqrt(push ** 2 + np.exp(f @ self.model.T) ** 2)

    def toppled_sigmas(self, features: np.ndarray) -> np.ndarray:
        """(P, NUM_FEATURES) -> (P, 2) standard deviations of where a toppled outcome ends, along and across (m)."""
        return np.exp(self.within_range(features) @ self.toppled.T)

    def spread(self, nominal, lin_vel, ang_vel, uncertainty, samples, rng):
        p = np.asarray(nominal["com_position"], dtype=np.float64)
        q = np.asarray(nominal["orientation_xyzw"], dtype=np.float64)
        P, T = p.shape[:2]
        N = int(samples)
        # the verdicts from a stream of their own, so the first N samples of a larger forecast are the same
        verdicts = np.random.default_rng(rng.integers(2 ** 63))
        draws = rng.standard_normal((P, N, 3))
        verdict = verdicts.random((P, N)) < np.asarray(nominal["topple_by_step"])[:, -1:]
        if uncertainty.is_zero:
            draws[:] = 0.0
            verdict = np.repeat(np.asarray(nominal["topple_by_step"])[:, -1:] >= 0.5, N, axis=1)
        yaw = heading_turn(q)
        frame = outcome_frame(p, q, lin_vel, yaw)
        sigma = np.repeat(self.sigmas(frame["features"], push_scale(uncertainty))[:, None], N, axis=1)
        sigma[..., :2] = np.where(verdict[..., None], self.toppled_sigmas(frame["features"])[:, None], sigma[..., :2])
        offsets = draws * sigma
        along, across = frame["along"], np.stack([-frame["along"][:, 1], frame["along"][:, 0]], axis=1)
        shift = offsets[..., 0:1] * along[:, None] + offsets[..., 1:2] * across[:, None]  # (P, N, 2) world
        travel, turning = progress(p, yaw)
        com = np.repeat(p[:, None], N, axis=1)
        com[..., :2] += travel[:, None, :, None] * shift[:, :, None, :]
        orientation = turn_about_vertical(turning[:, None, :] * offsets[..., 2:3], q[:, None])
        return {"com_position": com, "orientation_xyzw": orientation, "toppled": verdict}


def _range(value: Any, key: str) -> tuple[float, float]:
    from physdyn.errors import ConfigError

    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        low, high = float("nan"), float("nan")
    if not 0.0 <= low <= high:
        raise ConfigError(f"distribution.params.{key}: [low, high] with 0 <= low <= high expected, got {value!r}; "
                          "`physdyn fit-spread` writes it")
    return low, high


def _coefficients(rows: Any, key: str, count: int = len(COMPONENTS)) -> np.ndarray:
    from physdyn.errors import ConfigError

    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (count, NUM_FEATURES) or not np.isfinite(a).all():
        raise ConfigError(f"distribution.params.{key}: {count} rows ({', '.join(COMPONENTS[:count])}) of "
                          f"{NUM_FEATURES} finite numbers expected; `physdyn fit-spread` writes them")
    return a


def push_scale(uncertainty: UncertaintyConfig) -> np.ndarray:
    """(3,) how much ``uncertainty`` spreads the outcome against the default uncertainty, per component: along
    the travel as the speed (a slide's length goes as its square) and the friction; across it as the
    direction; the turn as the spin."""
    d = UNCERTAINTY_PRESETS["default"]
    u = uncertainty
    along = math.hypot(2 * u.speed_rel, u.friction_rel) / math.hypot(2 * d.speed_rel, d.friction_rel)
    across = u.direction_deg / d.direction_deg
    turn = math.sqrt(((u.spin_rel / d.spin_rel) ** 2 + (u.spin_abs / d.spin_abs) ** 2) / 2)
    return np.array([along, across, turn])


def heading_turn(q: np.ndarray) -> np.ndarray:
    """(P, T, 4) -> (P, T) the turn about the vertical from step 0 at each step, rad, unwrapped over steps."""
    rel = quat_multiply(q, quat_conjugate(q[:, :1]))
    yaw = 2.0 * np.arctan2(rel[..., 2], rel[..., 3])
    return np.unwrap(yaw, axis=1)


def outcome_frame(p: np.ndarray, q: np.ndarray, lin_vel: np.ndarray, yaw: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Each push's travel frame and the spread's inputs: ``along`` (P, 2) the unit final horizontal
    displacement (the push's direction where it barely moves, else x), ``travel`` (P,) m, ``turn`` (P,) rad,
    ``features`` (P, NUM_FEATURES). ``yaw``: ``heading_turn(q)``, where already taken."""
    displacement = p[:, -1, :2] - p[:, 0, :2]
    travel = np.linalg.norm(displacement, axis=1)
    push = np.asarray(lin_vel, dtype=np.float64).reshape(-1, 3)[:, :2]
    direction = np.where((travel > 1e-3)[:, None], displacement, push)
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    along = np.where(norm > 1e-9, direction / np.maximum(norm, 1e-12), np.array([1.0, 0.0]))
    turn = (heading_turn(q) if yaw is None else yaw)[:, -1]
    floors = FEATURE_FLOORS
    features = np.stack([np.ones_like(travel), np.log(travel + floors[0]), np.log(np.abs(turn) + floors[1])], axis=1)
    return {"along": along, "travel": travel, "turn": turn, "features": features}


def progress(p: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, T) how far along its path each push is at each step, from 0 to 1: by the distance travelled, and
    by the heading turned (yaw: ``heading_turn``; by time where it does not move or turn)."""
    T = p.shape[1]
    by_time = np.broadcast_to(np.linspace(0.0, 1.0, T), p.shape[:2])

    def fraction(step_sizes: np.ndarray) -> np.ndarray:
        done = np.concatenate([np.zeros((len(step_sizes), 1)), np.cumsum(step_sizes, axis=1)], axis=1)
        total = done[:, -1:]
        return np.where(total > 1e-9, done / np.maximum(total, 1e-12), by_time)

    travel = fraction(np.linalg.norm(np.diff(p[..., :2], axis=1), axis=-1)) if T > 1 else np.zeros(p.shape[:2])
    turning = fraction(np.abs(np.diff(yaw, axis=1))) if T > 1 else np.zeros(p.shape[:2])
    return travel, turning
