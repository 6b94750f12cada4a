"""Proper scores of outcome distributions: a forecast of N sampled outcomes of a push against K reference members
(perturbed re-simulations of the same push). Every score is lower-is-better except coverage.

Shapes: one push is ``samples (N, D)`` against ``members (K, D)``; any leading batch axes (``(P, N, D)`` against
``(P, K, D)`` for P pushes) give one score per push. ``score_pushes`` gathers every score over P pushes.

Energy score (Gneiting & Raftery 2007), for a metric ||.|| in which the outcomes are points of a Euclidean space:
    ES(x, y) = 1/N sum_i ||x_i - y|| - 1/(2 N (N-1)) sum_{i != j} ||x_i - x_j||
with the *fair* estimator's spread term (averaged over the N (N-1) ordered pairs i != j, not N^2: unbiased for
the forecast distribution's score, so a forecast is not rewarded for drawing few samples). With ``fair=False``
the plain estimator divides by N^2. One sample (N = 1) has no spread term: its score is that of a point mass,
1/N sum_i ||x_i - y||. The reported score averages ES(x, y_k) over the K members.
    Floor: a perfect forecast (samples drawn from the reference's own distribution) has expected score
    E||X - Y|| - 1/2 E||X - X'|| = 1/2 E||Y - Y'||, estimated by half the mean over the K (K-1) ordered pairs
    of distinct members of ||y_i - y_j|| (unbiased, like the fair estimator; needs K >= 2).
- Final position: Euclidean distance in cm (inputs in metres, all given axes: (N, 2) or (N, 3)).
- Final orientation: the chordal distance between rotations divided by sqrt 2, in "chordal degrees". For unit
  quaternions q1, q2 with rotation matrices R1, R2 and relative rotation angle theta,
      ||R1 - R2||_F^2 = 6 - 2 tr(R1^T R2) = 4 - 4 cos(theta) = 8 sin^2(theta/2) = 8 (1 - <q1, q2>^2),
  so ||R1 - R2||_F / sqrt 2 = 2 sin(theta/2) = 2 sqrt(1 - <q1, q2>^2) in [0, 2], and the reported distance is
      d_deg = (180/pi) ||R1 - R2||_F / sqrt 2 = (360/pi) sin(theta/2).
  The scale is linear, so the score is the energy score of the rotation matrices as points of R^9 (proper, and
  the floor uses the same distance); it equals theta in degrees to first order (within 1 % up to 28 deg) and
  reads 81.0 at theta = 90 deg, 114.6 at 180 deg. The angle back from a distance: theta = 2 asin(d_deg pi/360).
  Invariant to q -> -q (one rotation).

Brier score of a topple probability p against the members' 0/1 topple labels y_k: the mean over members of
(p - y_k)^2, which is (p - f)^2 + f (1 - f) for the members' topple fraction f, so the reference's own
uncertainty is part of it. Floor: a perfect forecast (p the true fraction) scores f (1 - f), estimated
unbiasedly as K/(K-1) f (1 - f): half the members' mean pairwise |y_i - y_j|, the energy score's floor in 1-D.

Reliability diagram over P pushes: the predicted probabilities fall in ``n_bins`` equal bins of [0, 1] (1.0 in
the last); per bin the mean predicted probability, the observed frequency (the mean over its pushes of the
members' topple fraction, i.e. the pooled members when every push has K of them) and the count of pushes.
Expected calibration error: the count-weighted mean over non-empty bins of |mean predicted - observed|.

Coverage of the central q region of the final position (horizontal plane: x, y, z being up): the fraction of
members inside the forecast's q prediction ellipse, {x : (x - m)^T S^-1 (x - m) <= r^2}, with m and S the
samples' mean and covariance (N - 1 divisor) and the Gaussian prediction radius (Hotelling)
    r^2 = 2 (N-1)(N+1) / (N (N-2)) F_{2, N-2}^{-1}(q) = (N^2 - 1)/N ((1 - q)^(-2/(N-2)) - 1),
which holds a new draw from the samples' Gaussian with probability exactly q at any N >= 3 (the plug-in
chi-square radius, -2 ln(1 - q), is its N -> infinity limit and covers less for few samples).
``position_region`` returns the ellipse (centre, semi-axes, axes, angle) for plotting.

The scores of the energy and Brier kinds come from ``scoringrules`` (pinned in pyproject.toml).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CM_PER_M = 100.0
CHORDAL_DEG_PER_UNIT = 180.0 / math.pi / math.sqrt(2.0)  # (180/pi) / sqrt 2, applied to ||R1 - R2||_F
COVERAGE_LEVELS = (0.5, 0.9)
# Added to the samples' covariance (m^2): a degenerate cloud (all samples equal, or on a line) then has a
# tiny region instead of a singular matrix.
COVARIANCE_FLOOR_M2 = 1e-12
# Memory of one scoringrules call, (pushes, N, N + K, D) float64 differences, is kept under this many bytes.
_CHUNK_BYTES = 32 * 2**20


def _scoringrules():
    # Imported on first use: scoringrules loads scipy.special (0.7 s), and this module must stay cheap to import.
    import scoringrules
    import scoringrules.core.energy

    return scoringrules


def _paired(samples, members, what: str) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.asarray(samples, dtype=np.float64), np.asarray(members, dtype=np.float64)
    if x.ndim < 2 or y.ndim != x.ndim or x.shape[:-2] != y.shape[:-2] or x.shape[-1] != y.shape[-1]:
        raise ValueError(f"{what}: samples (..., N, D) and members (..., K, D) with the same leading axes and D "
                         f"expected, got {x.shape} and {y.shape}")
    if x.shape[-2] < 1 or y.shape[-2] < 1:
        raise ValueError(f"{what}: at least one sample and one member needed, got {x.shape} and {y.shape}")
    return x, y


def energy_score(samples, members, *, fair: bool = True) -> np.ndarray:
    """Euclidean energy score, averaged over members. samples: (..., N, D); members: (..., K, D) -> (...,)."""
    x, y = _paired(samples, members, "energy_score")
    batch, (n, d), k = x.shape[:-2], x.shape[-2:], y.shape[-2]
    x, y = x.reshape(-1, n, d), y.reshape(-1, k, d)
    estimator = "fair" if fair and n > 1 else "nrg"  # one sample: the point mass's score, no spread term
    # The library's core function broadcasts members (B, K, D) against the samples (B, 1, N, D), so the
    # spread term is computed once per push; the public es_ensemble takes one observation a call and would
    # recompute it for every member (K times the work).
    energy = _scoringrules().core.energy
    chunk = max(1, _CHUNK_BYTES // (8 * n * (n + k) * d))
    out = np.empty(len(x))
    for start in range(0, len(x), chunk):
        xs, ys = x[start:start + chunk, None], y[start:start + chunk]
        out[start:start + chunk] = energy.es(ys, xs, estimator=estimator, backend="numpy").mean(axis=-1)
    return out.reshape(batch)


def energy_score_floor(members) -> np.ndarray:
    """A perfect forecast's expected energy score: half the mean over ordered pairs i != j of ||y_i - y_j||.
    members: (..., K, D), K >= 2 -> (...,)."""
    y = np.asarray(members, dtype=np.float64)
    if y.ndim < 2 or y.shape[-2] < 2:
        raise ValueError(f"the floor needs members (..., K, D) with K >= 2, got shape {y.shape}")
    k = y.shape[-2]
    pairwise = np.linalg.norm(y[..., :, None, :] - y[..., None, :, :], axis=-1)  # zero diagonal
    return pairwise.sum(axis=(-2, -1)) / (k * (k - 1)) / 2.0


def position_energy_score_cm(samples_m, members_m, *, fair: bool = True) -> np.ndarray:
    """Energy score of the final position in cm. samples_m: (..., N, 2 or 3) m; members_m: (..., K, same) m."""
    return CM_PER_M * energy_score(samples_m, members_m, fair=fair)


def position_energy_floor_cm(members_m) -> np.ndarray:
    """A perfect forecast's energy score of the final position, cm. members_m: (..., K, 2 or 3) m -> (...,)."""
    return CM_PER_M * energy_score_floor(members_m)


def _rotation_points(q_xyzw) -> np.ndarray:
    """(..., 4) quaternions -> (..., 9) points whose Euclidean distance is the chordal distance in degrees."""
    from physdyn.geometry.rotations import quat_to_matrix  # scipy.spatial at import: loaded only when needed

    q = np.asarray(q_xyzw, dtype=np.float64)
    if q.shape[-1:] != (4,) or not np.all(np.linalg.norm(q, axis=-1) > 0):
        raise ValueError(f"non-zero quaternions (..., 4), x y z w, expected, got shape {q.shape}")
    return CHORDAL_DEG_PER_UNIT * quat_to_matrix(q).reshape(q.shape[:-1] + (9,))


def chordal_distance_deg(q1_xyzw, q2_xyzw) -> np.ndarray:
    """(360/pi) sqrt(1 - <q1, q2>^2) = (180/pi) ||R1 - R2||_F / sqrt 2. q1, q2: (..., 4), broadcast -> (...)."""
    q1, q2 = np.asarray(q1_xyzw, dtype=np.float64), np.asarray(q2_xyzw, dtype=np.float64)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    q2 = q2 / np.linalg.norm(q2, axis=-1, keepdims=True)
    dot = np.sum(q1 * q2, axis=-1)
    return (360.0 / math.pi) * np.sqrt(np.clip(1.0 - dot * dot, 0.0, 1.0))


def orientation_energy_score_deg(samples_xyzw, members_xyzw, *, fair: bool = True) -> np.ndarray:
    """Energy score of the final orientation in chordal degrees. samples_xyzw: (..., N, 4); members_xyzw:
    (..., K, 4) -> (...,)."""
    return energy_score(_rotation_points(samples_xyzw), _rotation_points(members_xyzw), fair=fair)


def orientation_energy_floor_deg(members_xyzw) -> np.ndarray:
    """A perfect forecast's energy score of the final orientation, chordal degrees. members_xyzw: (..., K, 4)."""
    return energy_score_floor(_rotation_points(members_xyzw))


def _topple_inputs(topple_probability, member_topples) -> tuple[np.ndarray, np.ndarray]:
    p, y = np.asarray(topple_probability, dtype=np.float64), np.asarray(member_topples, dtype=np.float64)
    if y.ndim < 1 or p.shape != y.shape[:-1]:
        raise ValueError(f"topple_probability (...,) and member_topples (..., K) expected, got {p.shape} and {y.shape}")
    if not np.all((p >= 0) & (p <= 1)):
        raise ValueError(f"topple probabilities must lie in [0, 1], got min {np.min(p)} max {np.max(p)}")
    if not np.all((y == 0) | (y == 1)):
        raise ValueError("member_topples must be 0 or 1 (a member topples or not)")
    return p, y


def brier_score(topple_probability, member_topples) -> np.ndarray:
    """Mean over members of (p - y_k)^2. topple_probability: (...,) in [0, 1]; member_topples: (..., K) 0/1."""
    p, y = _topple_inputs(topple_probability, member_topples)
    return np.mean(_scoringrules().brier_score(y, p[..., None], backend="numpy"), axis=-1)


def brier_floor(member_topples) -> np.ndarray:
    """A perfect forecast's expected Brier score, K/(K-1) f (1 - f). member_topples: (..., K) 0/1, K >= 2."""
    y = np.asarray(member_topples, dtype=np.float64)
    if y.ndim < 1 or y.shape[-1] < 2:
        raise ValueError(f"the floor needs member_topples (..., K) with K >= 2, got shape {y.shape}")
    k, f = y.shape[-1], y.mean(axis=-1)
    return k / (k - 1) * f * (1.0 - f)


@dataclass(frozen=True, eq=False)
class ReliabilityDiagram:
    """Per bin of predicted probability: bin_edges (B+1,); mean_predicted, observed_frequency (B,), NaN where
    empty; count (B,) pushes."""

    bin_edges: np.ndarray
    mean_predicted: np.ndarray
    observed_frequency: np.ndarray
    count: np.ndarray

    @property
    def expected_calibration_error(self) -> float:
        """Count-weighted mean over non-empty bins of |mean predicted - observed frequency|."""
        full = self.count > 0
        gap = np.abs(self.mean_predicted[full] - self.observed_frequency[full])
        return float(np.sum(self.count[full] * gap) / np.sum(self.count))


def reliability_diagram(topple_probability, observed, n_bins: int = 10) -> ReliabilityDiagram:
    """topple_probability: (P,) in [0, 1]; observed: (P,) topple fractions in [0, 1] or (P, K) 0/1 labels."""
    p, obs = np.asarray(topple_probability, dtype=np.float64), np.asarray(observed, dtype=np.float64)
    if obs.ndim == 2:
        _topple_inputs(p, obs)
        obs = obs.mean(axis=-1)
    if p.ndim != 1 or obs.shape != p.shape or len(p) == 0:
        raise ValueError(f"topple_probability (P,) and observed (P,) or (P, K) expected, got {p.shape}, {obs.shape}")
    if not (np.all((p >= 0) & (p <= 1)) and np.all((obs >= 0) & (obs <= 1))):
        raise ValueError("probabilities and observed fractions must lie in [0, 1]")
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    which = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, n_bins - 1)  # 1.0 in the last bin
    count = np.bincount(which, minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):  # an empty bin is NaN by design
        mean_predicted = np.bincount(which, weights=p, minlength=n_bins) / count
        observed_frequency = np.bincount(which, weights=obs, minlength=n_bins) / count
    return ReliabilityDiagram(edges, mean_predicted, observed_frequency, count)


def expected_calibration_error(topple_probability, observed, n_bins: int = 10) -> float:
    """ECE of ``reliability_diagram(topple_probability, observed, n_bins)``."""
    return reliability_diagram(topple_probability, observed, n_bins).expected_calibration_error


def plot_reliability_diagram(diagram: ReliabilityDiagram, path, title: str | None = None) -> Path:
    """Draws the diagram (observed against predicted, the diagonal, pushes per bin below) to a PNG at path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # Agg: no display, no pyplot state
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.5, 5.5))
    FigureCanvasAgg(fig)
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    top.plot([0, 1], [0, 1], color="0.6", linestyle="--", label="calibrated")
    full = diagram.count > 0
    top.plot(diagram.mean_predicted[full], diagram.observed_frequency[full], "o-", label="forecast")
    top.set(ylabel="observed topple frequency", xlim=(0, 1), ylim=(0, 1),
            title=title or f"reliability (ECE {diagram.expected_calibration_error:.3f})")
    top.legend(loc="upper left")
    widths = np.diff(diagram.bin_edges)
    bottom.bar(diagram.bin_edges[:-1], diagram.count, width=widths, align="edge", edgecolor="white")
    bottom.set(xlabel="predicted topple probability", ylabel="pushes")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png", dpi=120)
    return path


def prediction_radius2(n_samples: int, level: float) -> float:
    """Squared Mahalanobis radius of the Gaussian q prediction ellipse in 2-D from N samples (module docstring)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"a region's level must lie in (0, 1), got {level}")
    if n_samples < 3:
        raise ValueError(f"a 2-D region needs at least 3 samples (a covariance with N - 2 > 0), got {n_samples}")
    n = float(n_samples)
    return (n * n - 1.0) / n * ((1.0 - level) ** (-2.0 / (n - 2.0)) - 1.0)


@dataclass(frozen=True, eq=False)
class Ellipse:
    """The central ``level`` region of a forecast's final position: centre (2,) m, covariance (2, 2) m^2,
    radius2 the squared Mahalanobis radius."""

    centre: np.ndarray
    covariance: np.ndarray
    radius2: float
    level: float

    def _principal(self) -> tuple[np.ndarray, np.ndarray]:
        values, vectors = np.linalg.eigh(self.covariance)
        return values[::-1], vectors[:, ::-1]  # major axis first

    @property
    def semi_axes(self) -> np.ndarray:
        """(2,) m, major first: sqrt(radius2 * eigenvalue)."""
        return np.sqrt(self.radius2 * np.clip(self._principal()[0], 0.0, None))

    @property
    def axes(self) -> np.ndarray:
        """(2, 2): column i is the unit direction of semi_axes[i]."""
        return self._principal()[1]

    @property
    def angle_deg(self) -> float:
        """The major axis's angle from +x, counter-clockwise, in [0, 180) (matplotlib's Ellipse angle)."""
        return float(np.degrees(np.arctan2(self.axes[1, 0], self.axes[0, 0])) % 180.0)

    def contains(self, points_m) -> np.ndarray:
        """points_m: (..., 2 or 3) m (x, y used) -> (...) bool."""
        d = np.asarray(points_m, dtype=np.float64)[..., :2] - self.centre
        return np.einsum("...i,ij,...j->...", d, np.linalg.inv(self.covariance), d) <= self.radius2

    def boundary(self, n_points: int = 64) -> np.ndarray:
        """(n_points, 2) m: the closed outline (first point repeated last)."""
        t = np.linspace(0.0, 2.0 * np.pi, n_points)
        unit = np.stack([np.cos(t), np.sin(t)], axis=-1) * self.semi_axes
        return self.centre + unit @ self.axes.T


def fit_positions(samples_m) -> tuple[np.ndarray, np.ndarray, int]:
    """samples_m: (..., N, 2 or 3) -> mean (..., 2), covariance (..., 2, 2) with the floor, N."""
    x = np.asarray(samples_m, dtype=np.float64)
    if x.ndim < 2 or x.shape[-1] not in (2, 3):
        raise ValueError(f"final positions (..., N, 2 or 3) expected, got shape {x.shape}")
    x = x[..., :2]
    n = x.shape[-2]
    mean = x.mean(axis=-2)
    d = x - mean[..., None, :]
    cov = np.einsum("...ni,...nj->...ij", d, d) / max(n - 1, 1) + COVARIANCE_FLOOR_M2 * np.eye(2)
    return mean, cov, n


def position_region(samples_m, level: float, fitted: tuple | None = None) -> Ellipse:
    """The central ``level`` prediction ellipse of one push's final positions. samples_m: (N, 2 or 3) m;
    fitted: their ``fit_positions``, where already taken (one fit for several levels)."""
    if np.ndim(samples_m) != 2:
        raise ValueError(f"one push's samples (N, 2 or 3) expected, got shape {np.shape(samples_m)}")
    mean, cov, n = fitted if fitted is not None else fit_positions(samples_m)
    return Ellipse(mean, cov, prediction_radius2(n, level), level)


def region_coverage(samples_m, members_m, level: float) -> np.ndarray:
    """Fraction of members inside the samples' ``level`` ellipse. samples_m: (..., N, 2 or 3) m; members_m:
    (..., K, 2 or 3) m -> (...,)."""
    mean, cov, n = fit_positions(samples_m)
    y = np.asarray(members_m, dtype=np.float64)
    if y.shape[:-2] != mean.shape[:-1] or y.shape[-1] not in (2, 3):
        raise ValueError(f"members (..., K, 2 or 3) with the samples' leading axes expected, got {y.shape}")
    d = y[..., :2] - mean[..., None, :]
    mahalanobis2 = np.einsum("...ki,...ij,...kj->...k", d, np.linalg.inv(cov), d)
    return np.mean(mahalanobis2 <= prediction_radius2(n, level), axis=-1)


@dataclass(frozen=True, eq=False)
class DistributionScores:
    """Scores of P pushes: per_push maps a score's name to a (P,) array (keys as in ``score_pushes``);
    reliability is the diagram over the P pushes' topple probabilities (None without them)."""

    per_push: dict
    reliability: ReliabilityDiagram | None = None

    @property
    def mean(self) -> dict:
        """Each score's mean over pushes, plus ``ece`` (the reliability diagram's) when there is one."""
        means = {key: float(np.mean(value)) for key, value in self.per_push.items()}
        if self.reliability is not None:
            means["ece"] = self.reliability.expected_calibration_error
        return means


def score_pushes(sample_positions_m, member_positions_m, sample_orientations_xyzw=None,
                 member_orientations_xyzw=None, topple_probability=None, member_topples=None,
                 levels: tuple = COVERAGE_LEVELS) -> DistributionScores:
    """Every score of P pushes. Positions: (P, N, 3) and (P, K, 3) m; orientations: (P, N, 4) and (P, K, 4);
    topple_probability (P,), member_topples (P, K) 0/1. Keys: position_es_cm, position_floor_cm,
    orientation_es_deg, orientation_floor_deg (with orientations), brier, brier_floor (with topples),
    coverage_50, coverage_90 (coverage_<100 level> for each of ``levels``)."""
    per_push = {"position_es_cm": position_energy_score_cm(sample_positions_m, member_positions_m),
                "position_floor_cm": position_energy_floor_cm(member_positions_m)}
    if (sample_orientations_xyzw is None) != (member_orientations_xyzw is None):
        raise ValueError("orientations need both the samples' and the members'")
    if sample_orientations_xyzw is not None:
        per_push["orientation_es_deg"] = orientation_energy_score_deg(sample_orientations_xyzw,
                                                                      member_orientations_xyzw)
        per_push["orientation_floor_deg"] = orientation_energy_floor_deg(member_orientations_xyzw)
    if (topple_probability is None) != (member_topples is None):
        raise ValueError("topple scores need both topple_probability and member_topples")
    reliability = None
    if topple_probability is not None:
        per_push["brier"] = brier_score(topple_probability, member_topples)
        per_push["brier_floor"] = brier_floor(member_topples)
        reliability = reliability_diagram(topple_probability, member_topples)
    for level in levels:
        per_push[f"coverage_{round(100 * level)}"] = region_coverage(sample_positions_m, member_positions_m, level)
    return DistributionScores(per_push, reliability)
