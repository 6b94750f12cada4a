"""The reference code's evaluation metrics, as pure numpy functions.

Shapes: B sequences, S steps (transitions). Predicted and true changes are dicts of (B, S, 3) arrays keyed
``delta_linear_velocity``, ``delta_angular_velocity``, ``delta_position``, ``delta_rotation`` (world
axis-angle). ``valid`` (B, S) bool marks the real steps of each sequence (False on padding past its end).

Per-step errors (``step_errors``), each (B, S):
- ``linear_velocity`` ||dv^ - dv|| (m/s), ``angular_velocity`` ||dw^ - dw|| (rad/s), ``position``
  ||dp^ - dp|| (m): Euclidean;
- ``angle_deg`` | ||dtheta^|| - ||dtheta|| | in degrees;
- ``axis`` 1 - cos(angle between the axes of dtheta^ and dtheta), NaN where the true step angle is under 1
  degree (the axis is meaningless there) or the predicted rotation is exactly zero.
A sequence's error is the mean over its valid steps (NaNs skipped), the reported error the mean over
sequences (``sequence_means``, ``mean_over_sequences``). Used with the true velocities fed at every step
this is the single-step error; with a roll-out's own predictions, the roll-out error.

Relative errors (``relative_errors``), for the supplement's Table 1, two documented forms:
- ``kind="sequence"`` (the headline): per sequence, the summed error over the summed magnitude of the true
  change, sum_t ||x^_t - x_t|| / sum_t ||x_t|| (for ``angle``: sum_t | ||dtheta^_t|| - ||dtheta_t|| | /
  sum_t ||dtheta_t||), then averaged over sequences. A sequence whose true change is zero throughout is
  skipped (NaN). Resting steps add their error to the numerator but cannot blow up a ratio.
- ``kind="step"``: the paper's relative loss per step, ||x^ - x|| / (||x|| + ||x^||)
  (for ``angle`` with the scalars ||dtheta||), averaged over steps whose denominator exceeds ``eps`` (the
  reference's 0/0 on resting steps is skipped, not counted), then over sequences. Bounded in [0, 1].

Accumulated errors (``final_errors``): at each sequence's last real step, the Euclidean distance between
predicted and true centre-of-mass positions (m) and the geodesic angle between predicted and true
orientations (deg).

Topple classification (``topple_classification``): a sequence is predicted to topple when any valid
step's probability is >= 0.5. Rates are normalised per true class: tp_rate = TP / P, fn_rate = FN / P,
tn_rate = TN / N, fp_rate = FP / N (NaN for an empty class); accuracy = (TP + TN) / (P + N);
f1 = 2 TP / (2 TP + FP + FN) (NaN when there is neither a toppling sequence nor a predicted one).
"""

from __future__ import annotations

import warnings
from typing import Mapping

import numpy as np

from physdyn.geometry.rotations import quat_conjugate, quat_multiply

AXIS_MIN_ANGLE_DEG = 1.0
TOPPLE_THRESHOLD = 0.5
ERROR_KEYS = ("linear_velocity", "angular_velocity", "position", "angle_deg", "axis")
RELATIVE_KEYS = ("linear_velocity", "angular_velocity", "position", "angle")
_DELTA_OF = {
    "linear_velocity": "delta_linear_velocity",
    "angular_velocity": "delta_angular_velocity",
    "position": "delta_position",
}


def _nanmean(x: np.ndarray, axis=None) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN slice is a legitimate NaN here
        return np.nanmean(x, axis=axis)


def _valid(valid: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    return np.ones(shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)


def step_errors(pred: Mapping[str, np.ndarray], true: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-step errors of predicted vs true changes, each (B, S) (definitions: module docstring)."""
    out = {}
    for name, key in _DELTA_OF.items():
        out[name] = np.linalg.norm(np.asarray(pred[key], np.float64) - np.asarray(true[key], np.float64), axis=-1)
    r_hat = np.asarray(pred["delta_rotation"], np.float64)
    r = np.asarray(true["delta_rotation"], np.float64)
    a_hat, a = np.linalg.norm(r_hat, axis=-1), np.linalg.norm(r, axis=-1)
    out["angle_deg"] = np.degrees(np.abs(a_hat - a))
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.sum(r_hat * r, axis=-1) / (a_hat * a)
    axis = 1.0 - np.clip(cos, -1.0, 1.0)
    out["axis"] = np.where((np.degrees(a) >= AXIS_MIN_ANGLE_DEG) & (a_hat > 0), axis, np.nan)
    return out


def sequence_means(errors: Mapping[str, np.ndarray], valid: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Mean of each (B, S) error over the valid, non-NaN steps of each sequence -> (B,) (NaN if none)."""
    out = {}
    for key, err in errors.items():
        err = np.asarray(err, np.float64)
        out[key] = _nanmean(np.where(_valid(valid, err.shape), err, np.nan), axis=1)
    return out


def mean_over_sequences(per_sequence: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Mean over sequences of (B,) values, NaNs skipped -> floats (NaN for no sequence)."""
    return {k: float(_nanmean(np.asarray(v, np.float64))) if np.size(v) else float("nan") for k, v in per_sequence.items()}


def _magnitudes(pred: Mapping[str, np.ndarray], true: Mapping[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per quantity: (error, |true|, |pred|), each (B, S), for the relative forms."""
    out = {}
    for name, key in _DELTA_OF.items():
        x_hat, x = np.asarray(pred[key], np.float64), np.asarray(true[key], np.float64)
        out[name] = (np.linalg.norm(x_hat - x, axis=-1), np.linalg.norm(x, axis=-1), np.linalg.norm(x_hat, axis=-1))
    a_hat = np.linalg.norm(np.asarray(pred["delta_rotation"], np.float64), axis=-1)
    a = np.linalg.norm(np.asarray(true["delta_rotation"], np.float64), axis=-1)
    out["angle"] = (np.abs(a_hat - a), a, a_hat)
    return out


def relative_errors(
    pred: Mapping[str, np.ndarray], true: Mapping[str, np.ndarray], valid: np.ndarray | None = None,
    kind: str = "sequence", eps: float = 1e-9,
) -> dict[str, np.ndarray]:
    """Relative errors per sequence -> (B,) fractions for ``RELATIVE_KEYS`` (definitions: module docstring)."""
    if kind not in ("sequence", "step"):
        raise ValueError(f"kind must be 'sequence' or 'step', got {kind!r}")
    out = {}
    for name, (err, mag, mag_hat) in _magnitudes(pred, true).items():
        ok = _valid(valid, err.shape)
        if kind == "sequence":
            num = np.sum(np.where(ok, err, 0.0), axis=1)
            den = np.sum(np.where(ok, mag, 0.0), axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                out[name] = np.where(den > eps, num / den, np.nan)
        else:
            den = mag + mag_hat
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.where(ok & (den > eps), err / den, np.nan)
            out[name] = _nanmean(ratio, axis=1)
    return out


def rotation_angle_deg(q_a_xyzw: np.ndarray, q_b_xyzw: np.ndarray) -> np.ndarray:
    """Geodesic angle (deg) between two orientations, (..., 4) -> (...); q and -q are the same rotation."""
    rel = quat_multiply(q_a_xyzw, quat_conjugate(q_b_xyzw))
    rel = rel / np.linalg.norm(rel, axis=-1, keepdims=True)
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(rel[..., :3], axis=-1), np.abs(rel[..., 3])))


def final_errors(
    pred_position: np.ndarray, pred_orientation_xyzw: np.ndarray, true_position: np.ndarray,
    true_orientation_xyzw: np.ndarray, last: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Accumulated errors at each sequence's last real step.

    Positions (B, T, 3), orientations (B, T, 4); last (B,) index of the last real step (default T - 1).
    Returns ``position_m`` (B,) Euclidean distance and ``rotation_deg`` (B,) geodesic angle.
    """
    B, T = np.shape(pred_position)[:2]
    idx = np.full(B, T - 1) if last is None else np.asarray(last, dtype=np.int64)
    rows = np.arange(B)
    p_err = np.linalg.norm(np.asarray(pred_position)[rows, idx] - np.asarray(true_position)[rows, idx], axis=-1)
    r_err = rotation_angle_deg(np.asarray(pred_orientation_xyzw)[rows, idx], np.asarray(true_orientation_xyzw)[rows, idx])
    return {"position_m": p_err, "rotation_deg": r_err}


def position_error_curve(pred_position: np.ndarray, true_position: np.ndarray) -> np.ndarray:
    """Accumulated position error at every step: (B, T, 3) x 2 -> (B, T) metres."""
    return np.linalg.norm(np.asarray(pred_position, np.float64) - np.asarray(true_position, np.float64), axis=-1)


def error_curve(errors: np.ndarray, valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean error at each step index over the sequences still running there, for error-vs-time plots.

    errors (B, S); valid (B, S). Returns (mean (S,), count (S,)): NaN mean where no sequence counts.
    """
    errors = np.asarray(errors, np.float64)
    ok = _valid(valid, errors.shape) & ~np.isnan(errors)
    count = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, np.sum(np.where(ok, errors, 0.0), axis=0) / count, np.nan)
    return mean, count


def error_quantiles(errors: np.ndarray, valid: np.ndarray | None = None,
                    quantiles: tuple[float, ...] = (0.25, 0.5, 0.75)) -> np.ndarray:
    """Quantiles of the error at each step index over the sequences still running there: (Q, S), NaN where
    no sequence counts. Medians and quartiles, unlike means, are not dragged by a few long failures."""
    errors = np.asarray(errors, np.float64)
    ok = _valid(valid, errors.shape) & ~np.isnan(errors)
    masked = np.where(ok, errors, np.nan)
    out = np.full((len(quantiles), errors.shape[1]), np.nan)
    some = ok.any(axis=0)
    if some.any():
        out[:, some] = np.nanquantile(masked[:, some], quantiles, axis=0)
    return out


def predicted_topple(probability: np.ndarray, valid: np.ndarray | None = None, threshold: float = TOPPLE_THRESHOLD) -> np.ndarray:
    """(B, T) per-step probabilities -> (B,) bool: any valid step at or above the threshold."""
    p = np.asarray(probability, np.float64)
    return np.any((p >= threshold) & _valid(valid, p.shape), axis=1)


def topple_classification(predicted: np.ndarray, toppled: np.ndarray) -> dict[str, float]:
    """Per-sequence predicted vs true toppling, (B,) bool each -> rates, accuracy, F1 and counts."""
    pred = np.asarray(predicted, dtype=bool)
    true = np.asarray(toppled, dtype=bool)
    tp, fn = int(np.sum(pred & true)), int(np.sum(~pred & true))
    fp, tn = int(np.sum(pred & ~true)), int(np.sum(~pred & ~true))
    pos, neg = tp + fn, tn + fp

    def ratio(a: int, b: int) -> float:
        return a / b if b else float("nan")

    return {
        "tp_rate": ratio(tp, pos), "fn_rate": ratio(fn, pos), "tn_rate": ratio(tn, neg), "fp_rate": ratio(fp, neg),
        "accuracy": ratio(tp + tn, pos + neg), "f1": ratio(2 * tp, 2 * tp + fp + fn),
        "tp": tp, "fp": fp, "fn": fn, "tn": tn,
    }
