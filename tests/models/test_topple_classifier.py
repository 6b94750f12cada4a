"""The step-0 topple classifier: its features by hand, its fit on a real store, its place in roll-outs."""

import numpy as np
import pytest
import trimesh

from physdyn.data.store import load_store
from physdyn.geometry.sampling import sample_surface_points
from physdyn.models.topple_classifier import (FEATURE_NAMES, ToppleClassifier, best_threshold, fit_clipped_logistic,
                                              fit_topple_classifier, logistic_regression, store_features, topple_features)


def _features(points, v, w):
    return dict(zip(FEATURE_NAMES, topple_features(points[None], [v], [w])[0]))


def test_footprint_and_tipping_features_of_a_box_by_hand():
    # A 0.2 x 0.3 (x, y) x 0.4 m box, centre of mass at the origin: its base is the footprint.
    points = sample_surface_points(trimesh.creation.box((0.2, 0.3, 0.4)), 2048, 3, seed=0)
    f = _features(points, [1.0, 0.0, 0.0], [0.0, 2.0, 0.0])  # pushed along +x, tipping forwards (w_y > 0 tips +x)
    assert f["h_com"] == pytest.approx(0.2, abs=1e-3)
    assert f["foot_area"] == pytest.approx(0.06, rel=0.05)
    assert f["edge_travel"] == pytest.approx(0.1, abs=2e-3) and f["edge_back"] == pytest.approx(0.1, abs=2e-3)
    assert f["edge_min"] == pytest.approx(0.1, abs=2e-3) and f["edge_tip"] == pytest.approx(0.1, abs=2e-3)
    assert f["tip_energy_travel"] == pytest.approx(9.81 * (np.hypot(0.2, 0.1) - 0.2), rel=0.02)
    sideways = _features(points, [0.0, 1.0, 0.0], [-2.0, 0.0, 0.0])  # along +y: the far edge is 0.15 away
    assert sideways["edge_travel"] == pytest.approx(0.15, abs=2e-3) and sideways["edge_tip"] == pytest.approx(0.15, abs=2e-3)
    assert sideways["tilt_ratio"] < f["tilt_ratio"]  # the same spin tips it less over the longer side
    on_edge = _features(points @ trimesh.transformations.rotation_matrix(np.pi / 4, [0, 1, 0])[:3, :3].T,
                        [1.0, 0.0, 0.0], [0.0, 0.0, 0.0])  # balanced on an edge: no area, nowhere to go
    assert on_edge["foot_area"] < 0.05 * f["foot_area"] and on_edge["edge_min"] < 5e-3  # a 5 mm strip


def test_a_batch_of_pushes_over_a_few_clouds_gives_each_push_its_own_features():
    # Repeated clouds are measured once and their pushes taken together: the same rows as one at a time.
    rng = np.random.default_rng(0)
    box = sample_surface_points(trimesh.creation.box((0.2, 0.3, 0.4)), 512, 3, seed=0)
    cylinder = sample_surface_points(trimesh.creation.cylinder(0.05, 0.3), 512, 3, seed=1)
    edge = box @ trimesh.transformations.rotation_matrix(np.pi / 4, [0, 1, 0])[:3, :3].T  # a thin strip
    turn = trimesh.transformations.rotation_matrix(np.pi / 4, [1, 0, 0]) @ trimesh.transformations.rotation_matrix(0.6, [0, 1, 0])
    corner = box @ turn[:3, :3].T  # on a corner: no footprint hull, every edge distance 0
    clouds = np.stack([box, cylinder, edge, box, cylinder, corner, box])
    v, w = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    w[3] = 0.0  # no tilt spin: the tipping direction falls back to +x
    batch = topple_features(clouds, v, w)
    alone = np.concatenate([topple_features(clouds[i : i + 1], v[i : i + 1], w[i : i + 1]) for i in range(7)])
    np.testing.assert_allclose(batch, alone, rtol=1e-12, atol=1e-12)
    assert len(np.unique(batch[:, FEATURE_NAMES.index("foot_area")])) == 4 and np.isfinite(batch).all()
    assert batch[5, FEATURE_NAMES.index("foot_area")] == 0.0
    assert all(batch[5, FEATURE_NAMES.index(k)] == 0.0 for k in ("edge_travel", "edge_back", "edge_tip"))
    assert topple_features(clouds[:0], v[:0], w[:0]).shape == (0, len(FEATURE_NAMES))  # no pushes, no rows


def test_logistic_regression_and_threshold_recover_a_known_rule():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2000, 3))
    y = (x[:, 0] - 2 * x[:, 1] > 0.5).astype(float)
    w, b = logistic_regression(x, y, ridge=1e-6)
    assert np.mean(((x @ w + b) > 0) == y) > 0.98
    assert w[1] / w[0] == pytest.approx(-2, rel=0.15) and abs(w[2]) < 0.1 * abs(w[0])
    p = np.array([0.1, 0.2, 0.6, 0.7, 0.8])
    assert best_threshold(p, np.array([0, 0, 0, 1, 1], bool)) in (0.7,)


def test_a_few_huge_ratios_do_not_flatten_the_fit():
    # The ratio features have tails of 1e6; standardised as they are, ten such values made the fit answer
    # "no" for every push. Clipped to the training percentiles the rule is found.
    rng = np.random.default_rng(0)
    a = rng.normal(size=3000)
    y = (a > 0.5).astype(float)
    ratio = a.copy()
    ratio[rng.choice(len(a), 10, replace=False)] = 1e6
    x = np.stack([ratio, rng.normal(size=len(a))], axis=1)
    fit = fit_clipped_logistic(x, y)
    clf = ToppleClassifier(**fit, timing=np.array([0.0, 1.0]), friction=0.25, rate_hz=15.0)
    assert np.mean((clf.probability(x) >= 0.5) == y) > 0.98
    assert fit["high"][0] < 10 and clf.probability(np.array([[1e6, 0.0]]))[0] > 0.99  # clipped, still "topples"
    again = ToppleClassifier.from_dict(clf.to_dict())
    np.testing.assert_allclose(again.probability(x), clf.probability(x))
    old = clf.to_dict()
    del old["low"], old["high"]  # a classifier saved before clipping: read and used without it
    assert ToppleClassifier.from_dict(old).low is None


def test_fitted_on_a_store_it_beats_always_no_and_says_when(tiny_store):
    store = load_store(tiny_store)
    clf, report = fit_topple_classifier(store)
    train = np.flatnonzero(store.split == 0)
    truth = store.toppled[train].astype(bool)
    decided = clf.probability(store_features(store, train, None, 0.25)) >= 0.5
    assert np.mean(decided == truth) == pytest.approx(report["train_accuracy"])
    assert report["train_accuracy"] > max(truth.mean(), 1 - truth.mean()) + 0.05
    # per step: 0 at the push, growing with the training split's topple times to the sequence's probability
    steps = clf.per_step(np.array([0.2, 0.9]), 40)
    assert steps.shape == (2, 41) and (steps[:, 0] == 0).all() and (np.diff(steps, axis=1) >= 0).all()
    np.testing.assert_allclose(steps[:, -1], [0.2, 0.9])
    back = ToppleClassifier.from_dict(clf.to_dict())
    np.testing.assert_allclose(back.per_step(np.array([0.5]), 5), clf.per_step(np.array([0.5]), 5))
    with pytest.raises(ValueError, match="other features"):
        ToppleClassifier.from_dict({**clf.to_dict(), "features": ["speed"]})


def test_with_physics_it_also_reads_a_short_simulation_of_the_hull(tiny_store):
    from physdyn.data.windows import store_world_inertia, world_oriented_points
    from physdyn.models.topple_classifier import PHYSICS_FEATURE_NAMES, physics_features

    store = load_store(tiny_store)
    clf, report = fit_topple_classifier(store, physics=True)
    assert clf.physics and clf.feature_names == FEATURE_NAMES + PHYSICS_FEATURE_NAMES
    train = np.flatnonzero(store.split == 0)
    truth = store.toppled[train].astype(bool)
    x = store_features(store, train, None, 0.25, physics=True)
    assert x.shape == (len(train), len(FEATURE_NAMES) + len(PHYSICS_FEATURE_NAMES))
    # the roll-out's verdict alone (tilted past 45 degrees within 1 s) already beats always "no"
    sim_says = x[:, -1] > 0.5
    assert np.mean(sim_says == truth) > max(truth.mean(), 1 - truth.mean()) + 0.05
    assert np.mean((clf.probability(x) >= 0.5) == truth) == pytest.approx(report["train_accuracy"])
    # the physics columns are the body's roll-outs with its own inertia, the store's
    first = store.start[train[:6]]
    world = world_oriented_points(store.points[store.shape_id[train[:6]]], store.orientation_xyzw[first])
    own = physics_features(world, store.linear_velocity[first], store.angular_velocity[first], 0.25,
                           store_world_inertia(store, train[:6], store.orientation_xyzw[first]))
    np.testing.assert_allclose(x[:6, len(FEATURE_NAMES):], own, atol=1e-9)
    back = ToppleClassifier.from_dict(clf.to_dict())
    assert back.physics and not ToppleClassifier.from_dict({**clf.to_dict(), "features": list(FEATURE_NAMES),
                                                            "weights": clf.weights[:len(FEATURE_NAMES)]}).physics
