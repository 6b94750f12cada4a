"""Topple accuracy of the bundled model's topple head against step-0 classifiers (docs/research/topple-from-cloud.md).

    python benchmarks/topple.py            # quickstart test split; thresholds chosen on its validation split

Rows: always "no"; the topple head's rule (any step's probability >= 0.5) and the same with the threshold
chosen on validation; one physics ratio (tilt kinetic energy / energy to tip over the edge the top tips
towards) with its threshold chosen on validation; the logistic regression of ``physdyn fit-topple`` fitted
on the quickstart store, the large store and the store of five times the shapes; with ``--families``
gradient-boosted trees, a random forest and an MLP on the same features (scikit-learn needed); the 1 s
PyBullet roll-out of the cloud's hull alone and ``fit-topple --physics`` (its four features added); and
the classifier shipped in the bundled checkpoint.
About two minutes on 2 CPU cores (the roll-outs of the validation and test splits dominate).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from physdyn.data.store import load_store
from physdyn.eval import metrics as M
from physdyn.eval.evaluate import evaluate, select_sequences
from physdyn.predict.predictor import BUNDLED_CHECKPOINT
from physdyn.pipeline.presets import load_pipeline
from physdyn.pipeline.topple import HeadTopple
from physdyn.models.topple_classifier import (FEATURE_NAMES, best_threshold, clipped_scaling, fit_topple_classifier,
                                              standardise, store_features)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default=str(BUNDLED_CHECKPOINT))
    parser.add_argument("--data", default="data/quickstart.zarr")
    parser.add_argument("--large", default="data/quickstart_large.zarr", help="the same shapes with more pushes")
    parser.add_argument("--shapes", default="data/quickstart_shapes.zarr",
                        help="five times the shapes, other ones (configs/data/quickstart_shapes.yaml)")
    parser.add_argument("--families", action="store_true",
                        help="also fit other classifier families on the large store's features (needs scikit-learn)")
    args = parser.parse_args()
    started = time.time()
    store = load_store(args.data)
    pipeline = load_pipeline(args.checkpoint)
    shipped = getattr(pipeline.topple, "classifier", None)
    model = dataclasses.replace(pipeline, topple=HeadTopple())  # the head's own probabilities first
    friction = pipeline.network.prior_friction
    val, test = select_sequences(store, "val"), select_sequences(store, "test")
    y = {"val": store.toppled[val].astype(bool), "test": store.toppled[test].astype(bool)}
    head = {}
    for split in ("val", "test"):
        kept = evaluate(model, store, split, keep_trajectories=True)["trajectories"]
        prob, valid = kept["predicted"].topple_probability, kept["truth"]["state_valid"]
        head[split] = np.where(valid, prob, 0.0).max(axis=1)
    rows = [("always 'no'", np.zeros(len(test), bool))]
    rows.append(("topple head, any step >= 0.5", head["test"] >= 0.5))
    t = best_threshold(head["val"], y["val"])
    rows.append((f"topple head, threshold {t:.2f} chosen on val", head["test"] >= t))
    x = {"val": store_features(store, val, None, 0.25, 1), "test": store_features(store, test, None, 0.25, 2)}
    ratio = {k: v[:, FEATURE_NAMES.index("tilt_ratio")] for k, v in x.items()}
    t = best_threshold(ratio["val"], y["val"])
    rows.append((f"tilt energy ratio >= {t:.2f} (no learning)", ratio["test"] >= t))
    clf, _ = fit_topple_classifier(store, None, friction)
    rows.append(("fit-topple on the quickstart store", clf.probability(x["test"]) >= 0.5))
    # with the 1 s roll-out of the cloud's hull (the body's inertia): about 40 s more
    x_physics = store_features(store, test, None, 0.25, 2, physics=True)
    sim_says = x_physics[:, -1] > 0.5
    rows.append(("the roll-out alone (tilt >= 45 deg within 1 s)", sim_says))
    clf_physics, _ = fit_topple_classifier(store, None, friction, physics=True)
    rows.append(("fit-topple --physics on the quickstart store", clf_physics.probability(x_physics) >= 0.5))
    try:
        large = load_store(args.large)
        clf_large, _ = fit_topple_classifier(large, None, friction)
        rows.append(("fit-topple on the large store", clf_large.probability(x["test"]) >= 0.5))
        if args.families:
            rows += _families(large, x, y)
    except Exception as exc:  # noqa: BLE001 - the large store is optional
        print(f"(no large-store row: {exc})")
    try:
        shapes = load_store(args.shapes)
        clf_shapes, _ = fit_topple_classifier(shapes, None, friction)
        rows.append(("fit-topple on the five-times-the-shapes store", clf_shapes.probability(x["test"]) >= 0.5))
    except Exception as exc:  # noqa: BLE001 - the shapes store is optional
        print(f"(no shapes-store row: {exc})")
    if shipped is not None:
        result = evaluate(pipeline, store, "test")
        print(f"shipped classifier through the roll-out: test accuracy {result['topple']['accuracy']:.3f}")
        features = x_physics if shipped.physics else x["test"]
        rows.append(("shipped classifier (features on this cloud)", shipped.probability(features) >= 0.5))
    print(f"\n{args.data} test split: {len(test)} pushes, {int(y['test'].sum())} topple\n")
    print(f"{'predictor':<58} {'accuracy':>8} {'caught':>7} {'false alarms':>13}")
    for name, decided in rows:
        c = M.topple_classification(decided, y["test"])
        print(f"{name:<58} {c['accuracy']:8.3f} {int(c['tp']):7d} {int(c['fp']):13d}")
    print(f"\n{time.time() - started:.0f} s")


def _families(large, x: dict, y: dict) -> list:
    """Other classifiers on the same features (fitted on the large store's training split, clipped and
    standardised as fit-topple does, threshold chosen on validation): is the logistic regression or are
    the features the limit? scikit-learn is a benchmark-only dependency (pip install scikit-learn)."""
    from sklearn.ensemble import HistGradientBoostingClassifier, RandomForestClassifier
    from sklearn.neural_network import MLPClassifier

    train = np.flatnonzero(large.split == 0)
    x_train, y_train = store_features(large, train, None, 0.25, 0), large.toppled[train].astype(int)
    scaling = clipped_scaling(x_train)
    z = lambda a: standardise(a, **scaling)  # noqa: E731
    rows = []
    for name, clf in (("gradient-boosted trees", HistGradientBoostingClassifier(max_iter=500, learning_rate=0.05, random_state=0)),
                      ("random forest, 300 trees", RandomForestClassifier(300, min_samples_leaf=2, random_state=0)),
                      ("MLP 128-128", MLPClassifier((128, 128), alpha=1e-3, max_iter=400, early_stopping=True, random_state=0))):
        clf.fit(z(x_train), y_train)
        threshold = best_threshold(clf.predict_proba(z(x["val"]))[:, 1], y["val"])
        rows.append((f"{name} on the large store's features", clf.predict_proba(z(x["test"]))[:, 1] >= threshold))
    return rows


if __name__ == "__main__":
    main()
