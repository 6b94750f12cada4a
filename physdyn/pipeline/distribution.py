"""A distribution of outcomes from one push known only roughly: sampled pushes and the summary of their roll-outs.

``sample_requests`` draws N perturbed copies of each push (the uncertainty of docs/conventions.md, "Uncertainty
of a push"; ``physdyn.sim.perturb``), seeded, so a forecast is reproducible; ``summarise`` turns N sampled
trajectories into what a user reads: the probability of having toppled by each step, the mean and quantiles of
the final position and of the turn, and the 50 % and 90 % regions of the final position
(``physdyn.eval.scores.position_region``). ``Predictor.predict_distribution`` is both in one call.

Shapes: R pushes, N samples, T steps (step 0 included). World frame, z up, SI units, quaternions (x, y, z, w).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from physdyn.config.uncertainty import UncertaintyConfig, resolve_uncertainty
from physdyn.errors import PredictionError
from physdyn.eval.scores import COVERAGE_LEVELS, fit_positions, position_region
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, tilt_angle
from physdyn.sim.perturb import perturb_pushes
from physdyn.sim.trajectory import TOPPLE_ANGLE

QUANTILE_LEVELS = (5, 25, 50, 75, 95)  # per cent
MAX_SAMPLES = 4096  # a forecast's samples; far more only allocates (the regions settle within tens)
MIN_REGION_SAMPLES = 3  # a 2-D prediction region needs a covariance with N - 2 > 0 (``prediction_radius2``)


def check_samples(samples: Any) -> int:
    """``samples`` as a count from 1 to ``MAX_SAMPLES``; a one-line ``PredictionError`` naming the fix otherwise."""
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or not 1 <= int(samples) <= MAX_SAMPLES:
        raise PredictionError(f"samples must be a whole number from 1 to {MAX_SAMPLES}, got {samples!r}; e.g. --samples 32")
    return int(samples)


def sample_requests(lin_vel: Any, ang_vel: Any, friction: Any, uncertainty: Any, samples: int,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """N = ``samples`` perturbed copies of each of R pushes, drawn from ``uncertainty`` (a preset name, a
    mapping or an ``UncertaintyConfig``: ``resolve_uncertainty``) with ``np.random.default_rng(seed)``.

    lin_vel, ang_vel: (R, 3) or (3,) m/s and rad/s; friction: (R,) effective Coulomb coefficients, or None
    where the forecast does not vary friction. Returns lin (R, N, 3), ang (R, N, 3), friction (R, N) or None.
    With zero uncertainty every sample equals its push exactly. The draws are ``perturb_pushes``'s, so the
    first N samples of a larger forecast with the same seed are the same pushes.
    """
    config = uncertainty if isinstance(uncertainty, UncertaintyConfig) else resolve_uncertainty(uncertainty)
    lin = np.asarray(lin_vel, dtype=np.float64).reshape(-1, 3)
    ang = np.asarray(ang_vel, dtype=np.float64).reshape(-1, 3)
    mu = np.ones(len(lin)) if friction is None else np.asarray(friction, dtype=np.float64).reshape(-1)
    if len(ang) != len(lin) or len(mu) != len(lin):
        raise ValueError(f"lin_vel, ang_vel and friction must hold one row per push, got {len(lin)}, {len(ang)} and {len(mu)}")
    rng = np.random.default_rng(int(seed))
    lin_s, ang_s, mu_s = perturb_pushes(lin, ang, mu, config, rng, check_samples(samples))
    return lin_s, ang_s, None if friction is None else mu_s


def topple_by_step(rolled: Any, q0: np.ndarray) -> np.ndarray:
    """(B, T) each roll-out's probability of having toppled by step t: the running maximum of its topple output
    where the model has one, else whether it has tilted past 45 degrees. rolled: a ``RolloutResult``; q0 (B, 4)."""
    if rolled.topple_probability is not None:
        by_step = np.asarray(rolled.topple_probability, dtype=np.float64)
    else:
        by_step = (tilt_angle(q0[:, None], rolled.orientation_xyzw) > TOPPLE_ANGLE).astype(np.float64)
    return np.maximum.accumulate(by_step, axis=1)


def turn_deg(orientation_xyzw: np.ndarray) -> np.ndarray:
    """(..., T, 4) -> (...,) the angle (degrees) of the rotation from step 0 to the last step."""
    q = np.asarray(orientation_xyzw, dtype=np.float64)
    relative = quat_multiply(q[..., -1, :], quat_conjugate(q[..., 0, :]))
    # the angle of a unit quaternion, 2 atan2(|xyz|, |w|): in [0, 180] degrees, the sign of q either way
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(relative[..., :3], axis=-1), np.abs(relative[..., 3])))


def _quantiles(values: np.ndarray) -> dict[int, Any]:
    """(N, ...) -> {level: (...)} at ``QUANTILE_LEVELS`` per cent (numpy's linear interpolation)."""
    q = np.percentile(values, QUANTILE_LEVELS, axis=0)
    return {level: (float(v) if np.ndim(v) == 0 else np.asarray(v)) for level, v in zip(QUANTILE_LEVELS, q)}


def region(displacement_xy: np.ndarray, level: float, fitted: tuple | None = None) -> dict[str, Any] | None:
    """The central ``level`` region of N final displacements (N, 2) m as ``centre`` (2,) m, ``semi_axes``
    (2,) m (major first), ``angle_deg`` (the major axis from +x, counter-clockwise) and ``covariance`` (2, 2)
    m^2; None for fewer than ``MIN_REGION_SAMPLES`` samples. ``fitted``: the samples' (mean, covariance, N)
    where already taken (``physdyn.eval.scores.fit_positions``)."""
    if len(displacement_xy) < MIN_REGION_SAMPLES:
        return None
    ellipse = position_region(displacement_xy, level, fitted)
    return {"centre": np.asarray(ellipse.centre), "semi_axes": ellipse.semi_axes, "angle_deg": ellipse.angle_deg,
            "covariance": np.asarray(ellipse.covariance), "level": float(level)}


def summarise(com_position: Any, orientation_xyzw: Any, toppled_by_step: Any) -> dict[str, Any]:
    """The summary figures of N sampled trajectories.

    com_position (N, T, 3) m, orientation_xyzw (N, T, 4); toppled_by_step (N, T): whether each sample has
    toppled by step t (bool), or each sample's probability of it (floats in [0, 1]). Returns:
    ``topple_probability`` (T,): the mean over samples of each one's running maximum, so it never decreases;
    ``final_position_mean`` (3,) and ``final_position_quantiles`` {5, 25, 50, 75, 95: (3,)} of the last
    step's centre of mass, m, per axis; ``turn_deg_mean`` and ``turn_deg_quantiles`` {level: float} of the
    rotation from step 0 to the end, degrees; ``region_50`` and ``region_90``: the central 50 % and 90 %
    regions of the final horizontal displacement from step 0 (``region``; None under 3 samples).
    """
    p = np.asarray(com_position, dtype=np.float64)
    q = np.asarray(orientation_xyzw, dtype=np.float64)
    toppled = np.asarray(toppled_by_step, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 3 or q.shape != p.shape[:2] + (4,) or toppled.shape != p.shape[:2]:
        raise ValueError(f"com_position (N, T, 3), orientation_xyzw (N, T, 4) and toppled_by_step (N, T) expected, "
                         f"got {p.shape}, {q.shape} and {toppled.shape}")
    if len(p) == 0:
        raise ValueError("summarise needs at least one sample")
    final = p[:, -1]
    turn = turn_deg(q)
    displacement = final[:, :2] - p[:, 0, :2]
    quantiles = _quantiles(np.concatenate([final, turn[:, None]], axis=1))  # one sort for all four
    out: dict[str, Any] = {
        "topple_probability": np.maximum.accumulate(np.clip(toppled, 0.0, 1.0), axis=1).mean(axis=0),
        "final_position_mean": final.mean(axis=0),
        "final_position_quantiles": {level: value[:3] for level, value in quantiles.items()},
        "turn_deg_mean": float(turn.mean()),
        "turn_deg_quantiles": {level: float(value[3]) for level, value in quantiles.items()},
    }
    fitted = fit_positions(displacement) if len(displacement) >= MIN_REGION_SAMPLES else None
    for level in COVERAGE_LEVELS:
        out[f"region_{round(100 * level)}"] = region(displacement, level, fitted)
    return out


def describe(result: dict[str, Any]) -> str:
    """One paragraph a person reads: the topple probability, where the centre of mass ends (mean and 5-95 %),
    how far the object turns, from a ``Predictor.predict_distribution`` dict."""
    lo, hi = result["final_position_quantiles"][5], result["final_position_quantiles"][95]
    mean = result["final_position_mean"]
    turn = result["turn_deg_quantiles"]
    region = result.get("region_90")
    spread = "" if region is None else (f"; 90 % of final positions within an ellipse of semi-axes "
                                        f"{100 * region['semi_axes'][0]:.1f} x {100 * region['semi_axes'][1]:.1f} cm")
    return (f"distribution ({result['checkpoint']}), {result['samples']} samples, t = {result['time'][-1]:.2f} s: "
            f"topple probability {result['topple_probability'][-1]:.2f}; centre of mass ends at ({mean[0]:.3f}, "
            f"{mean[1]:.3f}, {mean[2]:.3f}) m on average, x {lo[0]:.3f} to {hi[0]:.3f} m and y {lo[1]:.3f} to "
            f"{hi[1]:.3f} m (5-95 %){spread}; turned {result['turn_deg_mean']:.1f} deg on average "
            f"({turn[5]:.1f} to {turn[95]:.1f} deg, 5-95 %).")
