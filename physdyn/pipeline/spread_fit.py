"""Fit the ``calibrated`` distribution stage (``physdyn.pipeline.spread``) to ensemble stores: `physdyn fit-spread`.

For every push of the stores, the predictor rolls out the push as recorded, and the store's members (the push
re-simulated from perturbed pushes: docs/dataset-format.md, "Ensembles") say where it really ends. In the
roll-out's travel frame, each member's final position along and across the travel and its final heading are
compared with the roll-out's:

- the **push's part** is fitted to the members' spread about their own mean (how far the uncertainty alone
  spreads the outcome);
- the **model's part** to the members' distance from the roll-out, given the push's part (how far the model is
  off besides).

Each is a Gaussian whose log standard deviation is linear in the features of ``outcome_frame`` (a power law of
travel and turn), fitted by maximum likelihood to the upright members. Members that toppled get a law of
their own for where they end (the forecast draws a sample's spread by its topple verdict) and are left out of
the turn (their heading is not a turn about the vertical). Shapes: P pushes, K members.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import minimize

from physdyn.config.uncertainty import UNCERTAINTY_PRESETS
from physdyn.geometry.rotations import quat_conjugate, quat_multiply
from physdyn.pipeline.spread import COMPONENTS, FEATURE_FLOORS, NUM_FEATURES, CalibratedSpread, outcome_frame, push_scale

MIN_MEMBERS = 3  # upright members a push needs to take part
POWER_BOUND = 1.5  # the largest power of travel or turn a standard deviation may follow (the least: 0)


def outcome_residuals(predictor: Any, store: Any, sims: np.ndarray) -> dict[str, np.ndarray]:
    """The roll-out of each push of ``sims`` and its members' outcomes in its frame: ``features`` (P, F),
    ``residual`` (P, K, 3) member minus roll-out (along m, across m, turn rad, the turn wrapped), ``upright``
    (P, K) bool, ``scale`` (3,) the store's uncertainty against the default (``push_scale``)."""
    from physdyn.eval.distribution_eval import member_outcomes, sampled_outcomes, store_uncertainty

    rolled = sampled_outcomes(predictor, store, sims, UNCERTAINTY_PRESETS["none"], 1)
    first = store.start[sims]
    p, q = rolled["com_position"][:, 0], rolled["orientation_xyzw"][:, 0]
    frame = outcome_frame(p, q, store.linear_velocity[first])
    members = member_outcomes(store, sims)
    e = members["displacement_xy"] - (p[:, -1, :2] - p[:, 0, :2])[:, None]
    along = frame["along"][:, None]
    rel = quat_multiply(members["orientation_xyzw"], quat_conjugate(store.orientation_xyzw[first])[:, None])
    heading = 2.0 * np.arctan2(rel[..., 2], rel[..., 3])
    turn = np.angle(np.exp(1j * (heading - frame["turn"][:, None])))
    residual = np.stack([(e * along).sum(-1), e[..., 1] * along[..., 0] - e[..., 0] * along[..., 1], turn], axis=-1)
    return {"features": frame["features"], "residual": residual, "upright": ~members["toppled"],
            "scale": push_scale(store_uncertainty(store))}


def _fit_log_sigma(features: np.ndarray, values: np.ndarray, weight: np.ndarray, floor_var: np.ndarray) -> np.ndarray:
    """Coefficients c (F,) maximising the Gaussian likelihood of ``values`` (M,) with variance
    floor_var + exp(2 features @ c) (each sample weighted by ``weight``)."""
    def loss(c: np.ndarray) -> tuple[float, np.ndarray]:
        s2 = np.exp(2.0 * features @ c)
        var = floor_var + s2
        nll = weight * (np.log(var) + values ** 2 / var)
        grad_var = weight * (1.0 / var - values ** 2 / var ** 2)
        return float(nll.sum() / weight.sum()), (features.T @ (grad_var * 2.0 * s2)) / weight.sum()

    start = np.zeros(features.shape[1])
    start[0] = 0.5 * np.log(max(np.average(values ** 2, weights=weight), 1e-12))
    # travel and turn go together: unbounded, their powers can cancel into laws that fit the data and explode
    # where one is small and the other large; a spread that never shrinks as either grows, by a power of at
    # most POWER_BOUND, keeps a law a law
    bounds = [(None, None)] + [(0.0, POWER_BOUND)] * (features.shape[1] - 1)
    result = minimize(loss, start, jac=True, method="L-BFGS-B", bounds=bounds)
    return result.x


def _rows(data: list[dict[str, np.ndarray]], c: int, members: str) -> tuple[np.ndarray, ...]:
    """Component ``c``'s residuals of the ``members`` ("upright": of pushes with ``MIN_MEMBERS`` of them, whose
    own mean and spread mean something; "toppled": all): features (M, F), the deviation from those members' own
    mean scaled to the default uncertainty (M,), the residual (M,), the push part's scale (M,)."""
    feats, within, full, scale = [], [], [], []
    for d in data:
        ok = d["upright"] if members == "upright" else ~d["upright"]
        r = d["residual"][..., c]
        n = ok.sum(axis=1, keepdims=True)
        mean = np.where(ok, r, 0.0).sum(axis=1, keepdims=True) / n.clip(min=1)
        # deviations from the members' own mean, scaled back to the spread (n - 1 degrees of freedom)
        dev = (r - mean) * np.sqrt(n / np.maximum(n - 1, 1)) / d["scale"][c]
        rows = ((n >= MIN_MEMBERS) if members == "upright" else True) & ok
        feats.append(np.repeat(d["features"][:, None], r.shape[1], axis=1)[rows])
        within.append(dev[rows])
        full.append(r[rows])
        scale.append(np.full(rows.sum(), d["scale"][c]))
    return tuple(np.concatenate(a) for a in (feats, within, full, scale))


def fit_spread(data: list[dict[str, np.ndarray]], fitted_on: str = "") -> CalibratedSpread.Config:
    """The ``calibrated`` stage's coefficients from ``outcome_residuals`` of one or more stores: the push's and
    the model's parts of each component from the upright members, and where a toppled member ends (along and
    across: one law, the push's and the model's parts together) from the toppled ones."""
    from physdyn.errors import PhysdynError

    if any(not np.all(d["scale"] > 0) for d in data):
        raise PhysdynError("a store's ensemble was simulated at zero uncertainty in a speed, direction or spin, so "
                           "its members cannot say how the push spreads the outcome; simulate it with ensemble."
                           "uncertainty: default (configs/data/ensemble_calibrate.yaml)")
    push_rows, model_rows, toppled_rows = [], [], []
    for c in range(len(COMPONENTS)):
        X, y, e, scale = _rows(data, c, "upright")
        if len(y) < 10 * X.shape[1]:
            raise PhysdynError(f"the stores hold {len(y)} upright members of pushes with {MIN_MEMBERS} or more of them, "
                               f"too few to fit a spread; simulate more pushes, with ensemble.members of 8 or more "
                               "(configs/data/ensemble_calibrate.yaml)")
        ones = np.ones(len(y))
        push = _fit_log_sigma(X, y, ones, np.zeros(len(y)))
        model = _fit_log_sigma(X, e, ones, (np.exp(X @ push) * scale) ** 2)
        push_rows.append(push.round(4).tolist())
        model_rows.append(model.round(4).tolist())
        if COMPONENTS[c] != "turn":  # a toppled member's heading is not a turn about the vertical
            Xt, _, et, _ = _rows(data, c, "toppled")
            # too few toppled members: one law for the upright members' whole distance from the roll-out
            toppled = (_fit_log_sigma(Xt, et, np.ones(len(et)), np.zeros(len(et))) if len(et) > 10 * Xt.shape[1]
                       else _fit_log_sigma(X, e, ones, np.zeros(len(e))))
            toppled_rows.append(np.asarray(toppled).round(4).tolist())
    features = np.concatenate([d["features"] for d in data])
    ranges = {}
    if features.shape[1] == NUM_FEATURES:  # (a study may fit laws of other inputs: they are not clipped)
        travel, turn = (np.exp(features[:, k + 1]) - FEATURE_FLOORS[k] for k in range(2))
        # the central 96 %: a law holds where its data are, not on their few extremes
        ranges = {key: [round(float(max(np.percentile(v, 2), 0.0)), 4), round(float(np.percentile(v, 98)), 4)]
                  for key, v in (("travel_range", travel), ("turn_range", turn))}
    return CalibratedSpread.Config(push=push_rows, model=model_rows, toppled=toppled_rows, fitted_on=fitted_on, **ranges)


def spread_coverage(stage: CalibratedSpread, data: dict[str, np.ndarray], level: float = 0.9) -> np.ndarray:
    """(3,) the fraction of members within the stage's central ``level`` interval, per component, each member
    judged by the spread of its kind (upright or toppled; the turn of upright members only): a check of the
    fit on data of its own kind (a calibrated stage holds about ``level``)."""
    from scipy.stats import norm

    upright = data["upright"]
    sigma = np.repeat(stage.sigmas(data["features"], data["scale"])[:, None], upright.shape[1], axis=1)
    toppled = stage.toppled_sigmas(data["features"])
    sigma[..., :2] = np.where(upright[..., None], sigma[..., :2], toppled[:, None])
    inside = np.abs(data["residual"]) / sigma <= norm.ppf(0.5 + level / 2)
    counted = np.ones(inside.shape, dtype=bool)
    counted[..., COMPONENTS.index("turn")] = upright
    return (inside & counted).sum(axis=(0, 1)) / counted.sum(axis=(0, 1))
