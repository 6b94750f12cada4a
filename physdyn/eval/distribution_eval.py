"""Proper scores of a model's distribution forecast on an ensemble store (one simulated with an ``ensemble:``
block: docs/dataset-format.md, "Ensembles"). Definitions: docs/evaluation.md, "Distribution scores".

For every selected push, the pipeline's distribution stage (``physdyn.pipeline.spread``) makes N outcomes from
its recorded step-0 state on the store's body and cloud of its shape (``physdyn.eval.evaluate.store_rollouts``),
for the members' horizon: N pushes drawn around the recorded velocities and rolled out in batches
(``sampled_pushes``), or one roll-out and N outcomes drawn around it (``calibrated``). The members start from
that same orientation, so the samples' final orientations are compared with theirs as they are; positions are
compared as horizontal displacements from step 0 (a member starts above the origin). A push's topple
probability is the forecast's, as ``Predictor.predict_distribution`` gives it (the mean over samples of each
one's probability of having toppled by the end), against each member's topple label. The deterministic
forecast, one roll-out of the unperturbed push, is scored the same way beside it.

Sampled pushes vary the friction too where the motion takes it (the contact prior: ``fast``, ``contact_prior``);
other models predict at the friction they were trained at, while the members' friction varies: that spread is
then part of the reference the forecast is scored against. Either forecast starts from the push's recorded
friction where the motion takes it.

Shapes: P pushes, N samples, K members, T steps of a member (step 0 included).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from physdyn.config.uncertainty import UncertaintyConfig, resolve_uncertainty
from physdyn.data.store import StoreData, load_store
from physdyn.eval.evaluate import EvaluationError, select_sequences, store_rollouts
from physdyn.eval.rollout import as_pipeline
from physdyn.eval.scores import COVERAGE_LEVELS, DistributionScores, score_pushes
from physdyn.pipeline.distribution import MIN_REGION_SAMPLES, check_samples, sample_requests, topple_by_step
from physdyn.pipeline.spread import SampledPushes

DEFAULT_SAMPLES = 32  # `physdyn test`'s N on an ensemble store
ROWS_PER_BATCH = 1024  # roll-outs at a time (P x N rows in all)
SCORE_KEYS = ("position_es_cm", "position_floor_cm", "orientation_es_deg", "orientation_floor_deg", "brier",
              "brier_floor", "ece", *(f"coverage_{round(100 * level)}" for level in COVERAGE_LEVELS))


def has_ensemble(store: StoreData) -> bool:
    """Whether ``store`` holds members for its pushes (``ensemble/com_position``)."""
    return "ensemble/com_position" in store.extra


def store_uncertainty(store: StoreData) -> UncertaintyConfig:
    """The uncertainty the store's members were perturbed with (its ``ensemble`` attribute)."""
    return resolve_uncertainty(dict(store.attrs["ensemble"]["uncertainty"]), "the store's ensemble.uncertainty")


def member_outcomes(store: StoreData, sims: np.ndarray) -> dict[str, np.ndarray]:
    """The members' outcomes of ``sims`` (P,): ``displacement_xy`` (P, K, 2) m, the final horizontal
    displacement from step 0; ``orientation_xyzw`` (P, K, 4) the final orientation; ``toppled`` (P, K) bool,
    toppled by the member's end."""
    position = store.extra["ensemble/com_position"][sims]
    return {"displacement_xy": position[:, :, -1, :2] - position[:, :, 0, :2],
            "orientation_xyzw": store.extra["ensemble/orientation_xyzw"][sims][:, :, -1],
            "toppled": store.extra["ensemble/topple_label"][sims].any(axis=-1)}


def sampled_outcomes(predictor: Any, store: StoreData, sims: np.ndarray, uncertainty: UncertaintyConfig, samples: int,
                     seed: int = 0) -> dict[str, np.ndarray]:
    """N = ``samples`` roll-outs of each push of ``sims`` (P,), for the members' horizon: ``com_position``
    (P, N, T, 3), ``orientation_xyzw`` (P, N, T, 4), ``toppled`` (P, N) bool by each roll-out's own end,
    ``topple_by_step`` (P, N, T) each roll-out's probability of having toppled by step t (its topple output's
    running maximum, or the 45 degree rule), and the sampled step-0 velocities ``lin_vel0``, ``ang_vel0`` (P, N, 3).
    A motion that takes friction (the contact prior) rolls each sample out at a friction drawn around the
    push's recorded one."""
    P, N = len(sims), int(samples)
    steps = store.extra["ensemble/com_position"].shape[2] - 1
    first = store.start[sims]
    # a motion that takes friction has each sample's drawn too, around the push's own, as `predict` does
    pipeline = as_pipeline(predictor)
    mu = np.asarray(store.friction, dtype=np.float64)[sims]
    takes = pipeline.motion.takes_friction and getattr(pipeline.network, "prior_friction", None) is not None
    if not takes or np.isnan(mu).any():
        mu = None
    lin, ang, mus = sample_requests(store.linear_velocity[first], store.angular_velocity[first], mu, uncertainty, N, seed)
    rows = np.repeat(sims, N)  # push-major: the N samples of a push are consecutive rows
    q0 = np.repeat(store.orientation_xyzw[first], N, axis=0)
    start = (q0, np.repeat(store.com_position[first], N, axis=0), lin.reshape(P * N, 3), ang.reshape(P * N, 3))
    rolled = store_rollouts(predictor, store, rows, start, steps, batch_size=ROWS_PER_BATCH, seed=seed,
                            friction=None if mus is None else mus.reshape(P * N))
    T = steps + 1
    by_step = topple_by_step(rolled, q0)
    return {"com_position": rolled.com_position.reshape(P, N, T, 3),
            "orientation_xyzw": rolled.orientation_xyzw.reshape(P, N, T, 4),
            "toppled": np.asarray(rolled.toppled, dtype=bool).reshape(P, N),
            "topple_by_step": by_step.reshape(P, N, T), "lin_vel0": lin, "ang_vel0": ang}


def forecast_outcomes(predictor: Any, store: StoreData, sims: np.ndarray, uncertainty: UncertaintyConfig, samples: int,
                      seed: int = 0) -> dict[str, np.ndarray]:
    """The pipeline's distribution forecast (its distribution stage: ``physdyn.pipeline.spread``) of each push of
    ``sims``: ``com_position``, ``orientation_xyzw``, ``toppled`` and ``topple_by_step`` as ``sampled_outcomes``
    gives them (with sampled pushes, also their velocities), and ``topple_probability`` (P,) the forecast's
    probability of having toppled by the end (as ``Predictor.predict_distribution`` gives it)."""
    stage = getattr(predictor, "distribution", None) or SampledPushes()
    if stage.rolls_out_samples or uncertainty.is_zero:
        out = sampled_outcomes(predictor, store, sims, uncertainty, samples, seed)
    else:
        one = sampled_outcomes(predictor, store, sims, resolve_uncertainty("none"), 1, seed)
        first = store.start[sims]
        nominal = {key: one[key][:, 0] for key in ("com_position", "orientation_xyzw", "topple_by_step")}
        out = stage.spread(nominal, store.linear_velocity[first], store.angular_velocity[first], uncertainty, samples,
                           np.random.default_rng(int(seed)))
        out["topple_by_step"] = np.repeat(one["topple_by_step"], int(samples), axis=1)
    out["topple_probability"] = out["topple_by_step"][:, :, -1].mean(axis=1)
    return out


def score_forecast(forecast: dict[str, np.ndarray], members: dict[str, np.ndarray]) -> DistributionScores:
    """``score_pushes`` of a forecast (``forecast_outcomes``) against the members (``member_outcomes``): the
    final horizontal displacement, the final orientation, and the forecast's topple probability. Coverage
    needs ``MIN_REGION_SAMPLES`` samples a push and is left out below that."""
    position = forecast["com_position"]
    displacement = position[:, :, -1, :2] - position[:, :, 0, :2]
    enough = position.shape[1] >= MIN_REGION_SAMPLES
    return score_pushes(displacement, members["displacement_xy"], forecast["orientation_xyzw"][:, :, -1],
                        members["orientation_xyzw"], forecast["topple_probability"], members["toppled"],
                        levels=COVERAGE_LEVELS if enough else ())


def _summary(scores: DistributionScores) -> dict[str, float | None]:
    means = scores.mean
    return {key: means.get(key) for key in SCORE_KEYS}


def _diagram(scores: DistributionScores) -> dict[str, np.ndarray]:
    r = scores.reliability
    return {"bin_edges": r.bin_edges, "mean_predicted": r.mean_predicted, "observed_frequency": r.observed_frequency,
            "count": r.count}


def evaluate_distribution(predictor: Any, store: StoreData | str, split: str = "test",
                          categories: Sequence[str] | None = None, samples: int = DEFAULT_SAMPLES,
                          uncertainty: Any = None, seed: int = 0, keep_samples: bool = False) -> dict[str, Any] | None:
    """The distribution scores of ``predictor`` (a ``Pipeline``, a bare network or a checkpoint's pipeline) on
    a split of an ensemble store; None for a store without an ensemble.

    samples: N pushes drawn per push; uncertainty: what they are drawn from (a preset name, a mapping, an
    ``UncertaintyConfig``; None: the store's own ensemble uncertainty); seed: the draws' seed. Returns a
    JSON-ready dict: ``forecast`` and ``deterministic`` (each the mean over pushes of ``SCORE_KEYS``;
    coverage None under 3 samples), ``reliability`` (per forecast: the diagram's ``bin_edges``,
    ``mean_predicted``, ``observed_frequency``, ``count``), ``per_push`` (lists: ``sim``,
    ``member_topple_fraction``, ``<forecast>.topple_probability`` and ``<forecast>.<score>``), and what was
    run: ``store``, ``split``, ``pushes``, ``members``, ``seconds``, ``samples``, ``seed``, ``distribution`` (the
    stage), ``uncertainty``, ``uncertainty_source`` ("store" or "given"), ``friction_varied`` (whether the
    forecast spreads the friction too). ``keep_samples`` adds
    ``trajectories``: {"sims", "forecast", "deterministic" (``sampled_outcomes``), "members"
    (``member_outcomes``)} - numpy, not JSON.
    """
    store = load_store(store) if isinstance(store, str) else store
    if not has_ensemble(store):
        return None
    K, T = store.extra["ensemble/topple_label"].shape[1:]
    if K < 2:  # a floor is half the members' mean pairwise distance
        raise EvaluationError(f"{store.url} holds {K} ensemble member a push and the scores' floors need two or more; "
                              "simulate it with ensemble.members >= 2, or pass --no-distribution")
    count = check_samples(samples)
    config = store_uncertainty(store) if uncertainty is None else resolve_uncertainty(uncertainty, "uncertainty")
    sims = select_sequences(store, split, categories)
    members = member_outcomes(store, sims)
    forecasts = {"forecast": forecast_outcomes(predictor, store, sims, config, count, seed),
                 "deterministic": forecast_outcomes(predictor, store, sims, resolve_uncertainty("none"), 1, seed)}
    scores = {name: score_forecast(f, members) for name, f in forecasts.items()}
    per_push: dict[str, list] = {"sim": sims.tolist(), "member_topple_fraction": members["toppled"].mean(axis=1).tolist()}
    for name, s in scores.items():
        per_push[f"{name}.topple_probability"] = forecasts[name]["topple_probability"].tolist()
        per_push.update({f"{name}.{key}": value.tolist() for key, value in s.per_push.items()})
    pipeline = as_pipeline(predictor)
    stage = getattr(pipeline, "distribution", None) or SampledPushes()
    # the friction's spread is in a calibrated spread's laws, and drawn by sampled pushes of a motion that takes it
    varied = not stage.rolls_out_samples or pipeline.motion.takes_friction
    out = {"store": store.url, "split": split, "pushes": int(len(sims)), "members": int(K),
           "seconds": (T - 1) / store.rate_hz, "samples": count, "seed": int(seed), "distribution": stage.registered_name,
           "uncertainty": dataclasses.asdict(config), "uncertainty_source": "store" if uncertainty is None else "given",
           "friction_varied": bool(varied), **{name: _summary(s) for name, s in scores.items()},
           "reliability": {name: _diagram(s) for name, s in scores.items()}, "per_push": per_push}
    if keep_samples:
        out["trajectories"] = {"sims": sims, **forecasts, "members": members}
    return out
