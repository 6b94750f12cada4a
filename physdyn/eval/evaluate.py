"""Every metric of a model or a baseline over a store's split: roll-out, single-step, per category.

``evaluate`` rolls out every selected simulation from its true step-0 state for its whole recorded length
(sequences of a batch are padded by repeating their last, resting frame; padding is masked out of every
metric), and scores it with ``physdyn.eval.metrics``. The headline, as in the paper, is on the
non-toppling sequences; toppling and all sequences are reported too, and per category.
``compare`` puts a model and the baselines side by side and says whether the model beats Coulomb sliding.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Sequence

import numpy as np

from physdyn.data import SPLITS
from physdyn.data.store import StoreData, load_store
from physdyn.data.windows import frame_targets, store_spin_inertia, store_world_inertia, subsample_indices
from physdyn.errors import PhysdynError
from physdyn.eval import metrics as M
from physdyn.eval.baselines import Baseline, predictor_name, resolve_predictor
from physdyn.eval.rollout import (DELTA_KEYS, STATE_KEYS, RolloutOptions, RolloutResult, as_pipeline, check_store_clouds,
                                  rollout, store_friction, teacher_forced)

GROUPS = ("non_toppling", "toppling", "all")


class EvaluationError(PhysdynError):
    """Nothing to evaluate: an unknown split or category, or an empty selection."""


def select_sequences(store: StoreData, split: str = "test", categories: Sequence[str] | None = None) -> np.ndarray:
    """Indices of the simulations of ``split`` (train, val or test) in the given category names."""
    if split not in SPLITS:
        raise EvaluationError(f"unknown split '{split}'; use one of {', '.join(SPLITS)}")
    keep = store.split == SPLITS[split]
    if categories:
        unknown = [c for c in categories if c not in store.category_names]
        if unknown:
            raise EvaluationError(f"unknown category '{unknown[0]}' in {store.url}; the store has: "
                                  f"{', '.join(store.category_names) or 'none'}")
        keep &= np.isin(store.sim_category(), [store.category_names.index(c) for c in categories])
    sims = np.flatnonzero(keep)
    if not len(sims):
        raise EvaluationError(f"{store.url} has no {split} simulations" + (f" in {', '.join(categories)}" if categories else "")
                              + "; choose another --split or store")
    return sims


def gather_truth(store: StoreData, sims: np.ndarray, num_steps: int | None = None) -> dict[str, np.ndarray]:
    """True trajectories of ``sims``, padded to T = num_steps + 1 (default: the longest) by repeating
    each one's last frame.

    Returns com_position (B, T, 3), orientation_xyzw (B, T, 4), linear_velocity, angular_velocity
    (B, T, 3); ``delta_*`` (B, T-1, 3) true changes (world frame); valid (B, T-1) (real transitions);
    state_valid (B, T); last (B,) index of the last real step; toppled (B,), category (B,), friction (B,).
    """
    sims = np.asarray(sims, dtype=np.int64)
    length = store.lengths()[sims]
    T = int(length.max()) if num_steps is None else int(num_steps) + 1
    t = np.arange(T)[None, :]
    frames = store.start[sims][:, None] + np.minimum(t, length[:, None] - 1)
    targets = frame_targets(store, frames[:, :-1])  # only the frames evaluated
    out = {
        "com_position": store.com_position[frames],
        "orientation_xyzw": store.orientation_xyzw[frames],
        "linear_velocity": store.linear_velocity[frames],
        "angular_velocity": store.angular_velocity[frames],
        "valid": t[:, :-1] < length[:, None] - 1,
        "state_valid": t < length[:, None],
        "last": np.minimum(length - 1, T - 1),
        "toppled": store.toppled[sims].astype(bool),
        "category": store.sim_category()[sims],
        "friction": store.friction[sims].astype(np.float64),
    }
    for key in DELTA_KEYS:
        out[key] = getattr(targets, key)
    return out


def _concat(parts: list[RolloutResult]) -> RolloutResult:
    fields = RolloutResult.__dataclass_fields__
    merged = {}
    for name in fields:
        if name == "extra":
            continue
        values = [getattr(p, name) for p in parts]
        merged[name] = None if any(v is None for v in values) else np.concatenate(values, axis=0)
    return RolloutResult(**merged)


def _chunks(n: int, size: int) -> Iterable[slice]:
    for i in range(0, n, size):
        yield slice(i, min(i + size, n))


def _model_points(store: StoreData, sims: np.ndarray, num_points: int | None, rng: np.random.Generator) -> np.ndarray:
    """The sims' body-frame clouds, subsampled (reproducibly) to the number of points the model was trained on."""
    points = store.points[store.shape_id[sims]]
    index = subsample_indices(points.shape[1], num_points, rng, len(sims))
    return points if index is None else np.take_along_axis(points, index[..., None], axis=1)


def _shapes(baseline: Baseline, store: StoreData, sims: np.ndarray) -> dict[str, np.ndarray]:
    """What a baseline that simulates the shape (``uses_shapes``) needs: every point of each sim's cloud
    (body frame) and its body's I / m in body axes; nothing for the others."""
    if not getattr(baseline, "uses_shapes", False):
        return {}
    shapes = store.shape_id[np.asarray(sims, dtype=np.int64)]
    return {"points_body": store.points[shapes],
            "inertia_per_mass": store_world_inertia(store, sims, np.tile([0.0, 0.0, 0.0, 1.0], (len(shapes), 1)))}


def predict_rollouts(predictor: Any, store: StoreData, sims: np.ndarray, truth: dict[str, np.ndarray], warm_start: int = 0,
                     batch_size: int = 256, seed: int = 0) -> RolloutResult:
    """Roll ``predictor`` out over ``sims`` for the horizon of ``truth`` (from ``gather_truth``)."""
    steps = truth["delta_position"].shape[1]
    p0, q0, v0, w0 = (truth[key][:, 0] for key in STATE_KEYS)
    if isinstance(predictor, Baseline):
        return _concat([predictor.rollout(p0[sl], q0[sl], v0[sl], w0[sl], steps, truth["friction"][sl], store.rate_hz,
                                          **_shapes(predictor, store, sims[sl])) for sl in _chunks(len(sims), batch_size)])
    k = min(int(warm_start), steps)
    warm = (truth["linear_velocity"][:, 1:k + 1], truth["angular_velocity"][:, 1:k + 1]) if k else None
    return store_rollouts(predictor, store, sims, (q0, p0, v0, w0), steps, warm, batch_size, seed)


def store_rollouts(predictor: Any, store: StoreData, sims: np.ndarray, start: tuple, steps: int,
                   warm: tuple[np.ndarray, np.ndarray] | None = None, batch_size: int = 256, seed: int = 0,
                   friction: np.ndarray | None = None) -> RolloutResult:
    """A model (``Pipeline`` or bare network) rolled out ``steps`` from ``start`` = (q0 (B, 4), p0, v0, w0 (B, 3)),
    row b on the body and cloud of ``sims[b]`` (repeats allowed); warm: true velocities of steps 1..K, (B, K, 3)
    each; friction (B,): each row's, where not its simulation's (``store_friction``)."""
    rng = np.random.default_rng(seed)
    pipeline = as_pipeline(predictor)
    topple, parts = pipeline.topple, []
    check_store_clouds(pipeline, store)
    if friction is None and not warm:  # a warm start is at the model's own
        friction = store_friction(pipeline, store.friction, sims)
    for sl in _chunks(len(sims), batch_size):
        q0, p0, v0, w0 = (x[sl] for x in start)
        points = _model_points(store, sims[sl], pipeline.network.num_points, rng)
        simulates = topple.cloud is not None or pipeline.motion.reads_stage_cloud
        # the classifier's cloud size (else the whole cloud), drawn from a stream of its own: the model's draws stay as they were
        topple_points = _model_points(store, sims[sl], None if topple.cloud is None else topple.given_count,
                                      np.random.default_rng([seed, sl.start])) if simulates else None
        parts.append(rollout(pipeline, points, q0, p0, v0, w0, steps, RolloutOptions(
            warm and (warm[0][sl], warm[1][sl]), topple_points_body=topple_points, spin_inertia=store_spin_inertia(store, sims[sl], q0),
            body_inertia=store_world_inertia(store, sims[sl], q0) if simulates else None,
            friction=None if friction is None else friction[sl])))
    return _concat(parts)


def _shape_single_steps(baseline: Baseline, store: StoreData, sims: np.ndarray, truth: dict[str, np.ndarray],
                        chunk: int = 2048) -> dict[str, np.ndarray]:
    """Teacher-forced changes (B, S, 3) of a baseline that simulates each shape (``cloud_sim``): one-step
    roll-outs from the true state of every real step only (the padding past a sequence's end, most of
    B x S on a store of mixed lengths, is left at zero: the metrics mask it), ``chunk`` starts at a time
    so the clouds handed over stay small."""
    B, S = truth["delta_position"].shape[:2]
    out = {k: np.zeros((B, S, 3)) for k in DELTA_KEYS}
    rows, steps = np.nonzero(truth["valid"][:, :S])
    for lo in range(0, len(rows), chunk):
        r, s = rows[lo : lo + chunk], steps[lo : lo + chunk]
        one = baseline.rollout(truth["com_position"][r, s], truth["orientation_xyzw"][r, s], truth["linear_velocity"][r, s],
                               truth["angular_velocity"][r, s], 1, truth["friction"][r], store.rate_hz,
                               **_shapes(baseline, store, sims[r]))
        for k in DELTA_KEYS:
            out[k][r, s] = getattr(one, k)[:, 0]
    return out


def predict_single_steps(predictor: Any, store: StoreData, sims: np.ndarray, truth: dict[str, np.ndarray],
                         batch_size: int = 256, seed: int = 0) -> dict[str, np.ndarray]:
    """Teacher-forced changes (B, S, 3): the predictor gets the TRUE state at every step."""
    B, S = truth["delta_position"].shape[:2]
    if isinstance(predictor, Baseline) and getattr(predictor, "uses_shapes", False):
        return _shape_single_steps(predictor, store, sims, truth)
    if isinstance(predictor, Baseline):
        flat = lambda key, d: truth[key][:, :S].reshape(-1, d)  # noqa: E731  every true state is a start
        one = predictor.rollout(flat("com_position", 3), flat("orientation_xyzw", 4), flat("linear_velocity", 3),
                                flat("angular_velocity", 3), 1, np.repeat(truth["friction"], S), store.rate_hz)
        return {k: getattr(one, k)[:, 0].reshape(B, S, 3) for k in DELTA_KEYS}
    rng = np.random.default_rng(seed)
    parts = []
    for sl in _chunks(B, batch_size):
        network = as_pipeline(predictor).network
        points = _model_points(store, sims[sl], network.num_points, rng)
        q0 = truth["orientation_xyzw"][sl, 0]
        parts.append(teacher_forced(network, points, q0, truth["linear_velocity"][sl, :S], truth["angular_velocity"][sl, :S],
                                    truth["orientation_xyzw"][sl, :S], spin_inertia=store_spin_inertia(store, sims[sl], q0)))
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in DELTA_KEYS}


def per_sequence_metrics(pred: RolloutResult, single: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    """(B,) arrays per metric: roll-out and single-step step errors, relative errors, final errors."""
    valid = truth["valid"]
    return {
        "rollout": M.sequence_means(M.step_errors(pred.deltas(), truth), valid),
        "single_step": M.sequence_means(M.step_errors(single, truth), valid),
        "relative": M.relative_errors(pred.deltas(), truth, valid, kind="sequence"),
        "relative_step": M.relative_errors(pred.deltas(), truth, valid, kind="step"),
        "final": M.final_errors(pred.com_position, pred.orientation_xyzw, truth["com_position"], truth["orientation_xyzw"], truth["last"]),
    }


def _summary(per_seq: dict[str, dict[str, np.ndarray]], keep: np.ndarray) -> dict[str, Any]:
    def stats(x: np.ndarray) -> dict[str, float]:
        x = x[keep]
        x = x[~np.isnan(x)]
        return {"mean": float(x.mean()) if len(x) else float("nan"), "median": float(np.median(x)) if len(x) else float("nan")}

    return {
        "count": int(np.sum(keep)),
        "rollout": M.mean_over_sequences({k: v[keep] for k, v in per_seq["rollout"].items()}),
        "single_step": M.mean_over_sequences({k: v[keep] for k, v in per_seq["single_step"].items()}),
        "relative": M.mean_over_sequences({k: v[keep] for k, v in per_seq["relative"].items()}),
        "relative_step": M.mean_over_sequences({k: v[keep] for k, v in per_seq["relative_step"].items()}),
        "final_position_m": stats(per_seq["final"]["position_m"]),
        "final_rotation_deg": stats(per_seq["final"]["rotation_deg"]),
    }


def _curves(pred: RolloutResult, truth: dict[str, np.ndarray], groups: dict[str, np.ndarray]) -> dict[str, dict[str, list[float]]]:
    """Per group: mean error at each step index over its sequences still running there (for plots), and for
    the accumulated position and rotation errors their quartiles (``*_q25``, ``*_median``, ``*_q75``) and
    ``count``. The errors are computed once for every sequence, then sliced per group."""
    step_err = M.step_errors(pred.deltas(), truth)
    pos = M.position_error_curve(pred.com_position, truth["com_position"])
    rot = M.rotation_angle_deg(pred.orientation_xyzw, truth["orientation_xyzw"])
    out = {}
    for group, keep in groups.items():
        if not keep.any():
            continue
        curves = {key: M.error_curve(err[keep], truth["valid"][keep])[0].tolist() for key, err in step_err.items()}
        sv = truth["state_valid"][keep]
        position, count = M.error_curve(pos[keep], sv)
        curves["position_m"] = position.tolist()
        curves["rotation_deg"] = M.error_curve(rot[keep], sv)[0].tolist()
        for key, err in (("position_m", pos), ("rotation_deg", rot)):
            q25, q50, q75 = M.error_quantiles(err[keep], sv)
            curves.update({f"{key}_q25": q25.tolist(), f"{key}_median": q50.tolist(), f"{key}_q75": q75.tolist()})
        curves["count"] = count.tolist()
        out[group] = curves
    return out


def _groups(toppled: np.ndarray) -> dict[str, np.ndarray]:
    return {"non_toppling": ~toppled, "toppling": toppled, "all": np.ones_like(toppled)}


def check_compatible(predictor: Any, store: StoreData, sims: np.ndarray, warm_start: int) -> None:
    """Refuse an evaluation whose numbers would mean nothing: a model trained at another recording rate
    (its steps are another length of time), or a warm start as long as the sequences."""
    info = getattr(predictor, "data_info", None)
    trained = (info or {}).get("rate_hz") if isinstance(info, dict) else None
    if trained and abs(float(trained) - float(store.rate_hz)) > 1e-6:
        raise EvaluationError(f"the model was trained at {float(trained):g} Hz and {store.url} is recorded at "
                              f"{float(store.rate_hz):g} Hz; evaluate on a store of the model's rate")
    if warm_start and not isinstance(predictor, Baseline):
        shortest = int(np.min(store.start[sims + 1] - store.start[sims]))
        if warm_start >= shortest - 1:
            raise EvaluationError(f"--warm-start {warm_start} leaves nothing to predict: the shortest sequence has "
                                  f"{shortest} steps; use fewer than {shortest - 1}")


def evaluate(model_or_baseline: Any, store: StoreData | str, split: str = "test", warm_start: int = 0,
             categories: Sequence[str] | None = None, batch_size: int = 256, seed: int = 0,
             keep_trajectories: bool = False) -> dict[str, Any]:
    """All metrics of one predictor on a split of a store.

    model_or_baseline: a ``DynamicsNetwork``, a checkpoint path, a ``Baseline`` or a baseline name
    ("stay_put", "coulomb_slide"). warm_start: K true velocity steps fed after step 0 (models only).
    categories: category names to keep (default all). Returns a JSON-ready dict: ``rollout``,
    ``per_category`` (per category name: ``non_toppling`` and ``all``), ``curves`` (per group: mean error
    per step index), ``topple`` (classification, or None without a topple head), ``per_sequence`` (lists)
    and ``headline`` (roll-out errors and final errors of the non-toppling sequences). Each group summary
    holds ``count``, ``rollout`` and ``single_step`` (step errors: linear_velocity m/s, angular_velocity
    rad/s, position m, angle_deg, axis), ``relative`` and ``relative_step`` (fractions), and
    ``final_position_m`` / ``final_rotation_deg`` (mean, median). Definitions: ``physdyn.eval.metrics``.
    ``keep_trajectories`` adds ``trajectories``: {"sims", "predicted" (``RolloutResult``), "truth"} - numpy,
    not JSON - for a viewer of the very roll-outs that were scored.
    """
    if warm_start < 0:
        raise EvaluationError(f"warm start must be >= 0 steps, got {warm_start}")
    store = load_store(store) if isinstance(store, str) else store
    predictor = resolve_predictor(model_or_baseline)
    sims = select_sequences(store, split, categories)
    check_compatible(predictor, store, sims, warm_start)
    truth = gather_truth(store, sims)
    pred = predict_rollouts(predictor, store, sims, truth, warm_start, batch_size, seed)
    single = predict_single_steps(predictor, store, sims, truth, batch_size, seed)
    per_seq = per_sequence_metrics(pred, single, truth)
    groups = _groups(truth["toppled"])
    rollout_groups = {g: _summary(per_seq, keep) for g, keep in groups.items()}
    per_category = {}
    for c in np.unique(truth["category"]):
        name = store.category_names[c] if c < len(store.category_names) else str(c)
        in_cat = truth["category"] == c
        per_category[name] = {"non_toppling": _summary(per_seq, in_cat & groups["non_toppling"]),
                              "all": _summary(per_seq, in_cat)}
    topple = None
    if pred.topple_probability is not None:
        predicted = M.predicted_topple(pred.topple_probability, truth["state_valid"])
        topple = M.topple_classification(predicted, truth["toppled"])
    nt = rollout_groups["non_toppling"]
    kept = {"trajectories": {"sims": sims, "predicted": pred, "truth": truth}} if keep_trajectories else {}
    return {
        "predictor": predictor_name(predictor, str(model_or_baseline) if isinstance(model_or_baseline, str) else "model"),
        "store": store.url,
        "split": split,
        "categories": list(categories or []),
        "warm_start": int(warm_start) if not isinstance(predictor, Baseline) else 0,
        "rate_hz": store.rate_hz,
        "num_sequences": int(len(sims)),
        "headline": {"group": "non_toppling", "count": nt["count"], **nt["rollout"],
                     "final_position_m_median": nt["final_position_m"]["median"],
                     "final_rotation_deg_median": nt["final_rotation_deg"]["median"]},
        "rollout": rollout_groups,
        "per_category": per_category,
        "topple": topple,
        "curves": _curves(pred, truth, groups),
        "per_sequence": {
            "sim": sims.tolist(), "toppled": truth["toppled"].tolist(),
            "category": [store.category_names[c] if c < len(store.category_names) else str(c) for c in truth["category"]],
            **{f"{part}.{k}": v.tolist() for part, d in per_seq.items() for k, v in d.items()},
        },
        **kept,
    }


def compare(model: Any, store: StoreData | str, baselines: Sequence[Any] = ("stay_put", "coulomb_slide"),
            split: str = "test", warm_start: int = 0, categories: Sequence[str] | None = None,
            keep_trajectories: bool = False, progress: Callable[[str], None] | None = None, **kwargs: Any) -> dict[str, Any]:
    """``evaluate`` for a model and each baseline (names, ``Baseline`` objects or checkpoints, e.g. the
    MLP baseline). Returns ``results`` (name -> evaluation), ``table`` (one row per predictor: headline
    numbers) and ``verdict``: whether the model beats Coulomb sliding on the median final position error of
    the non-toppling sequences. ``keep_trajectories``: the model's result keeps its roll-outs (``evaluate``).
    ``progress`` receives one line as each predictor starts (the CLI prints it: a long evaluation is not silent)."""
    store = load_store(store) if isinstance(store, str) else store
    results: dict[str, dict] = {}
    say = progress or (lambda line: None)
    # Bad input (a split, a category, a warm start) is refused before any progress line is printed.
    model = resolve_predictor(model)  # once: a checkpoint path is not loaded again by evaluate
    check_compatible(model, store, select_sequences(store, split, categories), warm_start)
    total = 1 + len(baselines)
    say(f"evaluating the model on the {split} split of {store.url} (1 of {total})")
    model_result = evaluate(model, store, split, warm_start, categories, keep_trajectories=keep_trajectories, **kwargs)
    model_name = model_result["predictor"]
    results[model_name] = model_result
    skipped: dict[str, str] = {}
    for number, spec in enumerate(baselines, start=2):
        say(f"evaluating {spec if isinstance(spec, str) else predictor_name(spec, 'a baseline')} ({number} of {total})")
        named = spec if isinstance(spec, str) else getattr(spec, "name", None)
        if named in ("coulomb_slide", "cloud_sim") and np.isnan(store.friction).any():
            # Imported real trials may not know their friction: a NaN baseline would read as "no data".
            skipped[named] = ("the store records no friction coefficient (sims/friction is NaN); "
                              f"import with --friction MU to compare with {named}")
            continue
        r = evaluate(spec, store, split, warm_start, categories, **kwargs)
        name = r["predictor"]
        while name in results:
            name += "'"
        results[name] = r
    table = []
    for name, r in results.items():
        h = r["headline"]
        table.append({"predictor": name, "count": h["count"], **{k: h[k] for k in M.ERROR_KEYS},
                      **{f"relative_{k}": r["rollout"]["non_toppling"]["relative"][k] for k in M.RELATIVE_KEYS},
                      "final_position_m_median": h["final_position_m_median"],
                      "final_rotation_deg_median": h["final_rotation_deg_median"],
                      "topple_accuracy": (r["topple"] or {}).get("accuracy", float("nan"))})
    text = verdict(model_name, results)
    if "coulomb_slide" in skipped:
        text = f"no Coulomb-sliding baseline: {skipped['coulomb_slide']}."
    return {"model": model_name, "results": results, "table": table, "verdict": text, "skipped_baselines": skipped}


def verdict(model_name: str, results: dict[str, dict]) -> str:
    """One sentence: does the model beat Coulomb sliding on the median final position error (non-toppling)?"""
    if "coulomb_slide" not in results:
        return "no Coulomb-sliding baseline was evaluated, so there is no verdict."
    ours = results[model_name]["headline"]["final_position_m_median"]
    theirs = results["coulomb_slide"]["headline"]["final_position_m_median"]
    if np.isnan(ours) or np.isnan(theirs):
        return "there are no non-toppling sequences to compare the model with the Coulomb-sliding baseline on."
    word = "beats" if ours < theirs else "does not beat"
    return (f"The model '{model_name}' {word} the Coulomb-sliding baseline on the median final position error of "
            f"non-toppling sequences: {ours * 100:.2f} cm vs {theirs * 100:.2f} cm.")
