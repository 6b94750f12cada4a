"""The frontier of distributions: outcome distributions for a push known only roughly, physdyn's against PyBullet
ensembles, scored against perturbed re-simulations at the conventions' step, every cost measured in one run.

    python benchmarks/distributions.py                       # both sets, 20 meshes x 3 pushes each (about 10 minutes)
    python benchmarks/distributions.py --quick               # a smoke check: 2 meshes x 2 pushes per set
    python benchmarks/distributions.py --sets wheel --meshes 40 --pushes 5 --out reports/distributions/wheel.md

Meshes and pushes: the frontier's external sets (benchmarks/frontier_sets.py: ``pybullet`` and ``wheel``, meshes
new to the model), ``--pushes`` simulated pushes per mesh; each push's step-0 state (orientation, post-push
velocities, friction) is what a user knows only roughly. Horizon: the truth's own length (to rest, or the
conventions' cap).

Reference: each push re-simulated ``--members`` times (32) at the conventions' 1/960 s, each member a push drawn
from the ``default`` uncertainty (docs/conventions.md, "Uncertainty of a push": ``physdyn.sim.perturb``), the
velocities set directly and the friction perturbed, as ``physdyn.sim.ensemble`` simulates an ensemble store's
members. Cached under ``--work``.

Forecasts, each drawn with its own seed (never the reference's pushes):
- PyBullet ensembles at 1/60, 1/120, 1/240 s and the frontier's step schedule, K = 1, 4, 16, 64 runs. K = 1 is
  the push as given (what a user runs once); K > 1 are K pushes drawn from the same uncertainty. The topple
  probability is the fraction of runs that topple.
- physdyn: ``Predictor.predict_distribution`` with N = 16, 32, 64 samples (the predictor ``--predictor``,
  default ``fast``, with its own distribution stage), and with N = 32 sampled pushes (the ``sampled_pushes``
  stage) where its own stage is another; its topple probability is the forecast's own (by the last step).
- physdyn's one prediction, as a point (N = 1), and with a fixed spread: 64 samples of its final position plus
  isotropic horizontal Gaussian noise of ``--spread-cm`` (3 cm, a constant chosen before any run: about the
  spread of a 3 % push's outcomes on the project's own shapes; the reference's median spread per set is printed
  beside it), every sample in its one final orientation, its topple probability the prediction's (the point's
  is its verdict, 0 or 1).

Costs: ms of CPU per push (one core: one torch thread, one BLAS thread), each push a mesh new to the forecast,
timed as benchmarks/frontier.py times regime (a): PyBullet builds the body (``prepare_body`` and its collision
shape) once per mesh and step, and a push's K runs cost that build plus K times the mean run at that step;
physdyn forgets every prepared mesh before each forecast, so each pays its mesh's preparation. The steps take
turns mesh by mesh and physdyn's forecasts of each mesh's pushes run after its turn.

Scores (``physdyn.eval.scores.score_pushes``, means over pushes): the energy score of the final horizontal
displacement from step 0 (cm) and of the final orientation (chordal degrees), fair estimator; the Brier score of
toppling by the horizon and the ECE over the set's pooled pushes; the coverage of the forecast's 50 % and 90 %
regions of the final position (3 samples or more). The floor row is a perfect forecast's expected score.
Verdicts: the forecast's targets (docs/distributions.md, "Where it stands against PyBullet ensembles") for
``predict_distribution``'s default sample count; the meshes that carry most of its mean position score.
"""

from __future__ import annotations

import os

for _threads in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_threads] = "1"  # before numpy and torch load: every cost here is one core's

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import hashlib  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

if __package__:  # imported as benchmarks.distributions by a study (python -m benchmarks.studies.NAME)
    from .frontier import (SCHEDULES, Progress, best_of, closing_line, load_predictors, pybullet_rows, schedule_name,
                           start_run, warm_up)
    from .frontier_report import fmt, fmt_ms
    from .frontier_sets import Requests, collect_set, requests_from_store, truth_store
else:  # python benchmarks/distributions.py: Python puts this folder on the path
    from frontier import (SCHEDULES, Progress, best_of, closing_line, load_predictors, pybullet_rows, schedule_name,
                          start_run, warm_up)
    from frontier_report import fmt, fmt_ms
    from frontier_sets import Requests, collect_set, requests_from_store, truth_store
from physdyn.config import PhysicsConfig, config_from_dict  # noqa: E402
from physdyn.config.uncertainty import resolve_uncertainty  # noqa: E402
from physdyn.eval.scores import score_pushes  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.pipeline.spread import SampledPushes, SpreadStage  # noqa: E402
from physdyn.predict.predictor import Predictor  # noqa: E402
from physdyn.sim.perturb import perturb_pushes  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402

SETS = ("pybullet", "wheel")
REFERENCE_HZ = 960  # the conventions' physics step
ENSEMBLE_HZ = (60, 120, 240)
ENSEMBLE_SIZES = (1, 4, 16, 64)
SAMPLE_COUNTS = (16, 32, 64)
SAMPLED_PUSHES_N = 32  # the sampled_pushes stage's forecast, beside a predictor whose own stage is another
SPREAD_SAMPLES = 64  # samples of the fixed-spread forecast
UNCERTAINTY = "default"
# one seed per stream: the reference's pushes, the ensembles', physdyn's (plus the push's index), the spread's
SEEDS = {"reference": 960, "ensemble": 1, "physdyn": 10_000, "spread": 2}
QUICK = {"meshes": 2, "pushes": 2}
BARS = {"brier": 0.03, "coverage_90": (0.85, 0.95), "ece": 0.05, "aim": 1.1}


# --------------------------------------------------------------------------------------------------
# Perturbed pushes as requests
# --------------------------------------------------------------------------------------------------
def member_requests(req: Requests, members: int, seed: int, nominal: bool = False) -> tuple[Requests, np.ndarray]:
    """Each push of ``req`` as ``members`` pushes drawn from the uncertainty (seed ``seed``), after the push
    itself with ``nominal``: the requests, push by push, and (R * M,) the push of each."""
    lin, ang, mu = perturb_pushes(req.v0, req.w0, req.friction, resolve_uncertainty(UNCERTAINTY),
                                  np.random.default_rng(seed), members)
    if nominal:
        lin = np.concatenate([req.v0[:, None], lin], axis=1)
        ang = np.concatenate([req.w0[:, None], ang], axis=1)
        mu = np.concatenate([req.friction[:, None], mu], axis=1)
    count = lin.shape[1]
    push = np.repeat(np.arange(len(req)), count)
    zeros = np.zeros((len(push), 3))
    out = Requests([req.mesh[p] for p in push], req.q0[push], lin.reshape(-1, 3), ang.reshape(-1, 3), mu.reshape(-1),
                   req.steps[push], zeros, req.q0[push], np.zeros(len(push), bool), zeros)
    return out, push


def worlds_at(physics: PhysicsConfig, steps_hz: tuple, schedules: tuple = ()) -> dict[Any, PhysicsWorld]:
    """One world per physics step (keyed by hz) and, with ``schedules``, per step schedule of the frontier
    (keyed by it, starting at its fine step)."""
    worlds: dict[Any, PhysicsWorld] = {hz: PhysicsWorld(dataclasses.replace(physics, time_step=1.0 / hz)) for hz in steps_hz}
    worlds.update({plan: PhysicsWorld(dataclasses.replace(physics, time_step=1.0 / plan[0])) for plan in schedules})
    return worlds


def reference(meshes: dict, req: Requests, physics: PhysicsConfig, rate_hz: float, members: int, cache: Path) -> dict:
    """The reference members of every push: disp (R, K, 3) from step 0, q (R, K, 4), toppled (R, K); made once
    into ``cache`` (an .npz)."""
    if cache.is_file():
        with np.load(cache) as saved:
            return {key: saved[key] for key in ("disp", "q", "toppled")}
    runs, _ = member_requests(req, members, SEEDS["reference"])
    worlds = worlds_at(physics, (REFERENCE_HZ,))
    out = pybullet_rows(worlds, meshes, runs, rate_hz, new_mesh_each=True)[REFERENCE_HZ]
    worlds[REFERENCE_HZ].close()
    ref = {"disp": out.disp.reshape(len(req), members, 3), "q": out.q.reshape(len(req), members, 4),
           "toppled": out.toppled.reshape(len(req), members)}
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, **ref)
    return ref


# --------------------------------------------------------------------------------------------------
# physdyn's forecasts, timed request by request after each mesh's PyBullet turn
# --------------------------------------------------------------------------------------------------
class PhysdynForecasts:
    """``run(pushes)``: each push's ``predict_distribution`` at every N of ``SAMPLE_COUNTS`` (the predictor's own
    distribution stage), at ``SAMPLED_PUSHES_N`` with the ``sampled_pushes`` stage where that is not its own, and
    its one ``predict``, each on a fresh copy of its mesh with the predictor's prepared meshes forgotten (untimed)."""

    def __init__(self, predictor: Predictor, meshes: dict, req: Requests, repeats: int):
        self.predictor, self.meshes, self.req, self.repeats = predictor, meshes, req, repeats
        self.variants = {"own": (predictor, SAMPLE_COUNTS)}
        pipeline = predictor.model
        if isinstance(getattr(pipeline, "distribution", None), SpreadStage):
            sampled = Predictor(dataclasses.replace(pipeline, distribution=SampledPushes()), name=predictor.name,
                                physics=predictor.physics)
            self.variants["sampled_pushes"] = (sampled, (SAMPLED_PUSHES_N,))
        R = len(req)
        self.samples = {(v, n): {"disp": np.zeros((R, n, 3)), "q": np.zeros((R, n, 4)), "p": np.zeros(R)}
                        for v, (_, counts) in self.variants.items() for n in counts}
        self.one = {"disp": np.zeros((R, 3)), "q": np.zeros((R, 4)), "toppled": np.zeros(R, bool), "p": np.zeros(R)}
        self.spent = dict.fromkeys(list(self.samples) + ["one"], 0.0)

    def _fresh(self, key: str, predictor: Predictor):
        predictor.forget_meshes()
        return self.meshes[key].copy()

    def run(self, pushes) -> None:
        req = self.req
        for r in pushes:
            for variant, (predictor, counts) in self.variants.items():
                seconds = req.steps[r] / predictor.rate_hz
                for n in counts:
                    spent, out = best_of(self.repeats, lambda mesh, n=n, predictor=predictor: predictor.predict_distribution(
                        mesh, req.v0[r], req.w0[r], seconds=seconds, uncertainty=UNCERTAINTY, samples=n,
                        seed=SEEDS["physdyn"] + int(r), orientation_xyzw=req.q0[r]),
                        lambda predictor=predictor: self._fresh(req.mesh[r], predictor))
                    self.spent[variant, n] += spent
                    p = out["com_position"]
                    self.samples[variant, n]["disp"][r] = p[:, -1] - p[:, 0]
                    self.samples[variant, n]["q"][r] = out["orientation_xyzw"][:, -1]
                    self.samples[variant, n]["p"][r] = out["topple_probability"][-1]
            predictor = self.predictor
            spent, one = best_of(self.repeats, lambda mesh: predictor.predict(
                mesh, req.v0[r], req.w0[r], seconds=req.steps[r] / predictor.rate_hz, orientation_xyzw=req.q0[r]),
                lambda: self._fresh(req.mesh[r], predictor))
            self.spent["one"] += spent
            self.one["disp"][r] = one["com_position"][-1] - one["com_position"][0]
            self.one["q"][r] = one["orientation_xyzw"][-1]
            self.one["toppled"][r] = one["toppled"]
            probability = one["topple_probability"]
            self.one["p"][r] = float(np.max(probability)) if probability is not None else float(one["toppled"])


# --------------------------------------------------------------------------------------------------
# Rows: a forecast's samples scored against the reference
# --------------------------------------------------------------------------------------------------
def scored_row(name: str, kind: str, count: int, ms: float, disp: np.ndarray, q: np.ndarray, p: np.ndarray,
               ref: dict, **extra: Any) -> dict:
    """disp (R, N, 3) and q (R, N, 4) the forecast's final displacements and orientations, p (R,) its topple
    probabilities; the row's means over pushes (coverage needs N >= 3)."""
    scores = score_pushes(disp[..., :2], ref["disp"][..., :2], q, ref["q"], p, ref["toppled"].astype(float),
                          levels=(0.5, 0.9) if disp.shape[1] >= 3 else ())
    means, per_push = scores.mean, scores.per_push
    # medians beside the means: one rolling object far from its forecast can carry a set's mean
    return {"name": name, "kind": kind, "count": count, "ms": ms, **extra,
            **{key: means.get(key, float("nan")) for key in ("position_es_cm", "orientation_es_deg", "brier", "ece",
                                                             "coverage_50", "coverage_90")},
            "position_es_median_cm": float(np.median(per_push["position_es_cm"])),
            "orientation_es_median_deg": float(np.median(per_push["orientation_es_deg"])),
            "position_es_per_push_cm": per_push["position_es_cm"].tolist()}


def floor_row(ref: dict) -> dict:
    # the floors come with any forecast's scores: the reference's own members stand in as samples
    scored = score_pushes(ref["disp"][..., :2], ref["disp"][..., :2], ref["q"], ref["q"],
                          ref["toppled"].mean(axis=1), ref["toppled"].astype(float), levels=())
    scores, per_push = scored.mean, scored.per_push
    return {"name": f"floor (a perfect forecast; {ref['disp'].shape[1]} runs at 1/{REFERENCE_HZ} s)", "kind": "floor",
            "count": None, "ms": None, "position_es_cm": scores["position_floor_cm"],
            "orientation_es_deg": scores["orientation_floor_deg"], "brier": scores["brier_floor"], "ece": float("nan"),
            "coverage_50": float("nan"), "coverage_90": float("nan"),
            "position_es_median_cm": float(np.median(per_push["position_floor_cm"])),
            "orientation_es_median_deg": float(np.median(per_push["orientation_floor_deg"])),
            "position_es_per_push_cm": per_push["position_floor_cm"].tolist()}


def ensemble_rows(outs: dict, push: np.ndarray, R: int, ref: dict, rate_hz: float) -> list[dict]:
    """Each step's ensembles of K = ``ENSEMBLE_SIZES`` runs: K = 1 the push as given, else its first K drawn
    pushes; cost the body's build plus K mean runs."""
    rows = []
    for key, out in outs.items():
        per_push = lambda a: a.reshape((R, -1) + a.shape[1:])  # noqa: E731
        disp, q, toppled = per_push(out.disp), per_push(out.q), per_push(out.toppled)
        name = f"PyBullet 1/{key} s" if key in ENSEMBLE_HZ else schedule_name(key, rate_hz)
        for k in ENSEMBLE_SIZES:
            take = slice(0, 1) if k == 1 else slice(1, 1 + k)
            rows.append(scored_row(name, "pybullet", k, out.ms["build"] + k * out.ms["rollout"], disp[:, take],
                                   q[:, take], toppled[:, take].mean(axis=1), ref, step=str(key)))
    return rows


def physdyn_rows(name: str, forecasts: PhysdynForecasts, ref: dict, spread_cm: float, seed: int) -> list[dict]:
    """The distribution forecast at every N (and with sampled pushes), the one prediction as a point and with the
    fixed spread."""
    R = len(forecasts.req)
    own = forecasts.predictor.model.distribution.registered_name
    rows = [scored_row(f"physdyn {name}, predict_distribution ({own if variant == 'own' else variant})",
                       "physdyn" if variant == "own" else "physdyn_sampled", n, 1000 * forecasts.spent[variant, n] / R,
                       s["disp"], s["q"], s["p"], ref) for (variant, n), s in forecasts.samples.items()]
    one, ms = forecasts.one, 1000 * forecasts.spent["one"] / R
    rows.append(scored_row(f"physdyn {name}, one prediction", "point", 1, ms, one["disp"][:, None], one["q"][:, None],
                           one["toppled"].astype(float), ref))
    noise = np.zeros((R, SPREAD_SAMPLES, 3))
    noise[..., :2] = np.random.default_rng(seed).normal(0.0, spread_cm / 100.0, (R, SPREAD_SAMPLES, 2))
    rows.append(scored_row(f"physdyn {name}, one prediction + {spread_cm:g} cm Gaussian", "spread", SPREAD_SAMPLES, ms,
                           one["disp"][:, None] + noise, np.repeat(one["q"][:, None], SPREAD_SAMPLES, axis=1),
                           one["p"], ref))
    return rows


# --------------------------------------------------------------------------------------------------
# One set
# --------------------------------------------------------------------------------------------------
def measure_set(set_name: str, args: argparse.Namespace, predictor: tuple[str, Predictor], work: Path) -> dict:
    """Reference, ensembles and physdyn's forecasts on one mesh set: its rows, in table order."""
    name, model = predictor
    meshes = collect_set(set_name, work, args.meshes)
    store = truth_store(meshes, args.pushes)
    rate = store.rate_hz
    if abs(model.rate_hz - rate) > 1e-9:
        raise SystemExit(f"predictor {name} predicts at {model.rate_hz} Hz, the truth is recorded at {rate} Hz")
    physics = config_from_dict(PhysicsConfig, store.attrs["physics"])
    parsed = {key: load_mesh(key) for key in dict.fromkeys(map(str, store.source))}  # files parsed before any timing
    req = requests_from_store(store)
    progress = Progress(set_name)
    uncertainty = json.dumps(dataclasses.asdict(resolve_uncertainty(UNCERTAINTY)), sort_keys=True)
    digest = hashlib.sha256(f"{uncertainty} {SEEDS['reference']} {physics}".encode()).hexdigest()[:10]
    cache = work / set_name / f"{meshes.folder.name}_x{args.pushes}_reference_k{args.members}_{digest}.npz"
    ref = progress.measure(f"reference, {args.members} runs a push at 1/{REFERENCE_HZ} s",
                           lambda: reference(parsed, req, physics, rate, args.members, cache))

    warm_up(model, next(iter(parsed.values())))
    model.predict_distribution(next(iter(parsed.values())).copy(), [0.5, 0, 0], [0, 0, 0], seconds=0.5, samples=4)
    runs, push = member_requests(req, max(ENSEMBLE_SIZES), SEEDS["ensemble"], nominal=True)
    forecasts = PhysdynForecasts(model, parsed, req, args.repeats)
    worlds = worlds_at(physics, ENSEMBLE_HZ, SCHEDULES)
    outs = progress.measure(f"PyBullet ensembles (1 + {max(ENSEMBLE_SIZES)} runs a push, every step) and physdyn, "
                            "mesh by mesh", lambda: pybullet_rows(
                                worlds, parsed, runs, rate, new_mesh_each=True, repeats=args.repeats,
                                after_mesh=lambda idx: forecasts.run(np.unique(push[idx]))))
    for world in worlds.values():
        world.close()
    rows = [floor_row(ref)]
    rows += ensemble_rows(outs, push, len(req), ref, rate)
    rows += physdyn_rows(name, forecasts, ref, args.spread_cm, SEEDS["spread"])
    spread = np.median(np.sqrt(ref["disp"][..., :2].var(axis=1, ddof=1).mean(axis=-1)))
    return {"meshes": len(parsed), "pushes": len(req), "rows": rows, "reference_spread_cm": 100 * float(spread),
            "mesh_of_push": list(req.mesh),
            "toppling_pushes": float(ref["toppled"].any(axis=1).mean()), "skipped": meshes.skipped}


# --------------------------------------------------------------------------------------------------
# Report: table, verdicts, plot
# --------------------------------------------------------------------------------------------------
def table(rows: list[dict]) -> str:
    head = ["forecast", "K or N", "ms per push", "ES position (cm)", "ES orientation (deg)", "Brier", "ECE",
            "coverage 50 %", "coverage 90 %", "median ES position (cm)", "median ES orientation (deg)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["name"], "-" if row["count"] is None else str(row["count"]), fmt_ms(row["ms"]),
                 fmt(row["position_es_cm"], 2), fmt(row["orientation_es_deg"], 1), fmt(row["brier"], 3),
                 fmt(row["ece"], 3), fmt(row["coverage_50"], 2), fmt(row["coverage_90"], 2),
                 fmt(row["position_es_median_cm"], 2), fmt(row["orientation_es_median_deg"], 1)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def default_samples() -> int:
    return int(inspect.signature(Predictor.predict_distribution).parameters["samples"].default)


def ratio(ours: float, theirs: float) -> float:
    """ours / theirs; a score of 0 (a Brier score where nothing topples) is matched only by 0."""
    return ours / theirs if theirs > 0 else (1.0 if ours == 0 else float("inf"))


def verdicts(set_name: str, rows: list[dict]) -> list[str]:
    """The targets of the default distribution forecast (``predict_distribution``'s default N), one line each."""
    n = default_samples()
    ours = next(r for r in rows if r["kind"] == "physdyn" and r["count"] == n)
    pyb = [r for r in rows if r["kind"] == "pybullet"]
    one_120 = next(r for r in pyb if r["step"] == "120" and r["count"] == 1)
    k16 = next(r for r in pyb if r["step"] == "120" and r["count"] == 16)
    word = lambda ok: "met" if ok else "NOT met"  # noqa: E731
    cheaper = [r for r in pyb if r["ms"] <= ours["ms"]]
    beaten = [r for r in cheaper if not (ours["position_es_cm"] < r["position_es_cm"]
                                         and ours["orientation_es_deg"] < r["orientation_es_deg"])]
    label = f"{set_name}: physdyn N = {n}"
    lines = [f"{label}: cost {ours['ms']:.1f} ms a push vs one PyBullet run at 1/120 s {one_120['ms']:.1f} ms "
             f"({ours['ms'] / one_120['ms']:.2f}x): {word(ours['ms'] <= one_120['ms'])}."]
    if not cheaper:
        lines.append(f"{label}: scores vs every PyBullet forecast that costs no more: none costs no more "
                     f"(the cheapest, {min(pyb, key=lambda r: r['ms'])['name']} K = 1, costs "
                     f"{min(r['ms'] for r in pyb):.1f} ms): met, vacuously.")
    else:
        worse = "; ".join(f"{r['name']} K = {r['count']} ({r['ms']:.1f} ms): {r['position_es_cm']:.2f} cm, "
                          f"{r['orientation_es_deg']:.1f} deg" for r in beaten)
        lines.append(f"{label}: ES {ours['position_es_cm']:.2f} cm / {ours['orientation_es_deg']:.1f} deg vs the "
                     f"{len(cheaper)} PyBullet forecasts that cost no more: {word(not beaten)}"
                     + (f"; not better than {worse}." if beaten else "."))
    lines.append(f"{label}: Brier {ours['brier']:.3f} (bar {BARS['brier']}): {word(ours['brier'] <= BARS['brier'])}; "
                 f"ECE over the set's pushes {ours['ece']:.3f} (the bar {BARS['ece']} is the test split's).")
    low, high = BARS["coverage_90"]
    lines.append(f"{label}: coverage of the 90 % region {ours['coverage_90']:.2f} (bar {low}-{high}): "
                 f"{word(low <= ours['coverage_90'] <= high)}.")
    ratios = {key: ratio(ours[key], k16[key]) for key in ("position_es_cm", "orientation_es_deg", "brier")}
    lines.append(f"{label}: against 16 PyBullet runs at 1/120 s ({k16['ms']:.1f} ms, {k16['ms'] / ours['ms']:.1f}x "
                 f"physdyn's cost): ES position {ratios['position_es_cm']:.2f}x, ES orientation "
                 f"{ratios['orientation_es_deg']:.2f}x, Brier {ratios['brier']:.2f}x (the aim: each within "
                 f"{BARS['aim']}x): {word(all(v <= BARS['aim'] for v in ratios.values()))}.")
    return lines


def heaviest(set_name: str, rows: list[dict], meshes: list[str]) -> str:
    """The meshes that carry most of the default forecast's mean position score, beside PyBullet 1/120 s K = 1's."""
    n = default_samples()
    ours = np.asarray(next(r for r in rows if r["kind"] == "physdyn" and r["count"] == n)["position_es_per_push_cm"])
    theirs = np.asarray(next(r for r in rows if r["kind"] == "pybullet" and r["step"] == "120"
                             and r["count"] == 1)["position_es_per_push_cm"])
    keys = np.asarray(meshes)
    share = {key: ours[keys == key].sum() / len(ours) for key in dict.fromkeys(meshes)}
    top = sorted(share, key=share.get, reverse=True)[:2]
    parts = [f"{Path(key).stem} ({np.sum(keys == key)} pushes: {share[key]:.2f} of physdyn's {ours.mean():.2f} cm, "
             f"{theirs[keys == key].sum() / len(theirs):.2f} of PyBullet 1/120 s K = 1's {theirs.mean():.2f} cm)"
             for key in top]
    return f"{set_name}: the mean ES position over pushes is carried by " + "; ".join(parts) + "."


def plot(results: dict[str, dict], path: Path) -> None:
    """Score against cost per push (log x): a column per set, a row per score; PyBullet's steps as lines over
    K, physdyn's forecast as points per N, its one prediction (point and fixed spread) as single points."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    scores = (("position_es_cm", "ES final position (cm)"), ("orientation_es_deg", "ES final orientation (deg)"),
              ("brier", "Brier (toppling)"), ("coverage_90", "coverage of the 90 % region"))
    fig = Figure(figsize=(5.2 * len(results), 3.2 * len(scores)))
    FigureCanvasAgg(fig)
    axes = np.array(fig.subplots(len(scores), len(results), squeeze=False))
    for col, (set_name, result) in enumerate(results.items()):
        rows = result["rows"]
        for row_i, (key, label) in enumerate(scores):
            ax = axes[row_i, col]
            steps = dict.fromkeys(r["step"] for r in rows if r["kind"] == "pybullet")
            for step in steps:
                line = [r for r in rows if r["kind"] == "pybullet" and r["step"] == step]
                name = line[0]["name"].replace("PyBullet ", "")
                ax.plot([r["ms"] for r in line], [r[key] for r in line], "o-", ms=4, label=f"PyBullet {name}, K = 1-64")
            ours = [r for r in rows if r["kind"] == "physdyn"]
            ax.plot([r["ms"] for r in ours], [r[key] for r in ours], "s", color="black",
                    label=f"physdyn distribution ({ours[0]['name'].split('(')[-1].rstrip(')')}), N = 16/32/64")
            for r in ours:
                ax.annotate(str(r["count"]), (r["ms"], r[key]), textcoords="offset points", xytext=(4, 4), fontsize=7)
            for r in (r for r in rows if r["kind"] == "physdyn_sampled"):
                ax.plot([r["ms"]], [r[key]], "^", color="tab:purple", label=f"physdyn sampled pushes, N = {r['count']}")
            for kind, marker, text in (("spread", "D", "one prediction + fixed spread"), ("point", "x", "physdyn one prediction")):
                r = next(r for r in rows if r["kind"] == kind)
                ax.plot([r["ms"]], [r[key]], marker, color="crimson" if kind == "spread" else "gray", label=text)
            if key == "coverage_90":
                ax.axhspan(BARS["coverage_90"][0], BARS["coverage_90"][1], color="green", alpha=0.1, label="0.85-0.95")
            else:
                ax.axhline(rows[0][key], color="0.4", linestyle="--", label="floor (perfect forecast)")
            ax.set_xscale("log")
            ax.set(xlabel="ms per push (CPU, one core, new mesh)", ylabel=label)
            if row_i == 0:
                ax.set_title(f"{set_name}: {result['meshes']} new meshes, {result['pushes']} pushes")
            ax.grid(True, which="both", alpha=0.3)
    axes[0, -1].legend(fontsize=6, loc="upper right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def report(results: dict[str, dict], header: list[str], spread_cm: float) -> str:
    parts = ["# The frontier of distributions (benchmarks/distributions.py)", "", *[f"- {line}" for line in header], ""]
    for set_name, result in results.items():
        parts += [f"## {set_name}", "",
                  f"{result['meshes']} meshes, {result['pushes']} pushes; pushes with a toppling reference run: "
                  f"{result['toppling_pushes']:.2f}; the reference's median spread (rms per horizontal axis): "
                  f"{result['reference_spread_cm']:.2f} cm (the fixed spread: {spread_cm:g} cm).", "",
                  table(result["rows"]), "", *verdicts(set_name, result["rows"]),
                  heaviest(set_name, result["rows"], result["mesh_of_push"]), ""]
        if result["skipped"]:
            parts += ["Skipped: " + "; ".join(f"{s['mesh']} ({s['reason']})" for s in result["skipped"]), ""]
    return "\n".join(parts)


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", nargs="+", choices=SETS, default=list(SETS))
    ap.add_argument("--meshes", type=int, default=20, help="meshes per set")
    ap.add_argument("--pushes", type=int, default=3, help="simulated pushes per mesh")
    ap.add_argument("--members", type=int, default=32, help=f"reference runs per push at 1/{REFERENCE_HZ} s")
    ap.add_argument("--predictor", default="fast=fast", metavar="NAME=CHECKPOINT",
                    help="physdyn's predictor (as benchmarks/frontier.py takes it; default fast=fast)")
    ap.add_argument("--spread-cm", type=float, default=3.0, help="the fixed spread's sigma per horizontal axis, cm")
    ap.add_argument("--work", default="runs/distributions", help="meshes, the wheel, truth stores, references "
                                                                 "(reused when present)")
    ap.add_argument("--out", default=None, help="markdown report, figures beside it as .json "
                                                "(default reports/distributions/distributions.md)")
    ap.add_argument("--plot", default=None, help="the plot (default: --out with .png)")
    ap.add_argument("--repeats", type=int, default=1, help="time every piece this many times, keep the fastest")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke check: " + ", ".join(f"--{k} {v}" for k, v in QUICK.items())
                         + "; report and plot under WORK/quick/ unless given")
    args = ap.parse_args()
    if args.quick:
        for key, value in QUICK.items():
            setattr(args, key, value)
    for key in ("meshes", "pushes", "repeats"):
        if getattr(args, key) < 1:
            ap.error(f"--{key}: at least 1, got {getattr(args, key)}")
    if args.members < 2:
        ap.error(f"--members: at least 2 (the floor compares pairs of runs), got {args.members}")
    if not args.spread_cm > 0:
        ap.error(f"--spread-cm: above 0, got {args.spread_cm}")
    args.out = Path(args.out or (Path(args.work) / "quick" / "distributions.md" if args.quick
                                 else "reports/distributions/distributions.md"))
    args.plot = Path(args.plot or args.out.with_suffix(".png"))
    return args


def main() -> None:
    args = parse_args()
    header, started, work = start_run(args.work)
    (name, predictor), = load_predictors([args.predictor], work).items()
    results = {}
    for set_name in args.sets:
        with warnings.catch_warnings():  # notes about a mesh (an open surface...) are the user's, not ours
            warnings.simplefilter("ignore")
            results[set_name] = result = measure_set(set_name, args, (name, predictor), work)
        print(f"\n{set_name}\n{table(result['rows'])}", flush=True)
        print("\n".join(verdicts(set_name, result["rows"])), flush=True)
        print(heaviest(set_name, result["rows"], result["mesh_of_push"]), flush=True)
    header.append(closing_line(started))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(report(results, header, args.spread_cm))
    args.out.with_suffix(".json").write_text(json.dumps({"header": header, "sets": results}, indent=1, default=str))
    plot(results, args.plot)
    print(f"\n{header[-1]}\nwrote {args.out}, {args.out.with_suffix('.json')} and {args.plot}")


if __name__ == "__main__":
    main()
