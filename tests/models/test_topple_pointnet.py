"""The PointNet topple classifier (`fit-topple --pointnet`): it learns from a real store, reads its inputs in
the travel frame as the mirror assumes, survives a checkpoint file read without running code, and predicts
toppling with no simulator anywhere in the prediction."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from physdyn.data.store import load_store
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.models.topple_pointnet import (MIRROR_SCALARS, PointNetToppleClassifier, fit_pointnet_topple,
                                            store_training_set, stores_first_frames, travel_scalars, travel_turn)
from tests.conftest import refuse_pybullet


@pytest.fixture(scope="module")
def hull_store(tiny_hull_store) -> str:
    """A real store of hull_surface clouds: 25 shapes over the five categories, 150 pushes, 64 points."""
    return tiny_hull_store


@pytest.fixture(scope="module")
def fitted(hull_store):
    torch.set_num_threads(1)
    store = load_store(hull_store)
    return store, *fit_pointnet_topple([store], seeds=(0, 1), steps=300, batch=32, width=16)


def test_it_learns_whether_a_push_topples_from_the_cloud(fitted):
    store, classifier, report = fitted
    train = np.flatnonzero(store.split == 0)
    first = stores_first_frames([store], split=0)
    truth = store.topple_step[train] >= 0
    accuracy = np.mean((classifier.probability(first["points"], first["v0"], first["w0"], first["spin"]) > 0.5) == truth)
    majority = max(truth.mean(), 1 - truth.mean())
    assert accuracy > majority + 0.08, (accuracy, majority)
    assert len(classifier.networks) == 2 and report["train_sequences"] == len(train)
    # the report's validation accuracy is the ensemble's own on the validation pushes
    val = np.flatnonzero(store.split == 1)
    held = stores_first_frames([store], split=1)
    decided = classifier.probability(held["points"], held["v0"], held["w0"], held["spin"]) > 0.5
    assert report["val_accuracy"] == pytest.approx(np.mean(decided == (store.topple_step[val] >= 0)))
    # per step: nothing at the push, then the training split's topple times up to the push's probability
    steps = classifier.per_step(np.array([0.3, 0.8]), 40)
    assert (steps[:, 0] == 0).all() and (np.diff(steps, axis=1) >= 0).all()
    np.testing.assert_allclose(steps[:, -1], [0.3, 0.8])


def test_the_inputs_are_in_the_travel_frame_and_mirror_as_the_training_assumes(hull_store):
    rng = np.random.default_rng(0)
    v, w = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    turn = travel_turn(v)
    scalars = travel_scalars(v, w, np.ones(50), turn)
    # along the travel: the whole horizontal speed, nothing across
    np.testing.assert_allclose(scalars[:, 0], np.hypot(v[:, 0], v[:, 1]))
    np.testing.assert_allclose(scalars[:, 1], 0.0, atol=1e-12)
    # the push mirrored in the world (y -> -y; the spin, an axial vector, -flip w) has the mirrored scalars,
    # and its mirrored cloud, seen in its own travel frame, is the cloud with y -> -y: what training feeds
    flip = np.diag([1.0, -1.0, 1.0])
    mirrored = travel_scalars(v @ flip, -(w @ flip), np.ones(50), travel_turn(v @ flip))
    np.testing.assert_allclose(mirrored, scalars * MIRROR_SCALARS, atol=1e-12)
    cloud = rng.normal(size=(50, 16, 3))
    seen = np.einsum("bij,bnj->bni", turn, cloud)
    seen_mirrored = np.einsum("bij,bnj->bni", travel_turn(v @ flip), cloud @ flip)
    np.testing.assert_allclose(seen_mirrored, seen @ flip, atol=1e-12)
    # every push of a store: its cloud in the travel frame is the turned body cloud
    store = load_store(hull_store)
    data = store_training_set([store])
    first = store.start[7]
    expected = travel_turn(store.linear_velocity[first][None])[0] @ quat_to_matrix(store.orientation_xyzw[first])
    np.testing.assert_allclose(data.turn[7], expected, atol=1e-12)
    assert data.clouds.shape == (store.num_shapes, 64, 3) and data.label[7] == float(store.topple_step[7] >= 0)


def test_a_checkpoint_keeps_it_and_is_read_without_running_code(fitted, tmp_path):
    from physdyn.models.checkpoint_file import read_torch_file, write_torch_file
    from physdyn.pipeline.topple import classifier_from_dict

    store, classifier, _ = fitted
    write_torch_file({"topple_classifier": classifier.to_dict()}, tmp_path / "c.ckpt")
    back = classifier_from_dict(read_torch_file(tmp_path / "c.ckpt", "a checkpoint")["topple_classifier"])
    assert isinstance(back, PointNetToppleClassifier) and back.points_method == "hull_surface" and not back.physics
    first = stores_first_frames([store], split=1)
    np.testing.assert_array_equal(back.probability(first["points"], first["v0"], first["w0"], first["spin"]),
                                  classifier.probability(first["points"], first["v0"], first["w0"], first["spin"]))
    # a classifier's dict without "point_widths" (files written without it) reads as the default widths
    old = classifier.to_dict()
    del old["point_widths"]
    assert classifier_from_dict(old).point_widths == (64, 128)


def test_narrower_per_point_layers_train_and_travel_through_a_checkpoint(hull_store, tmp_path):
    from physdyn.models.checkpoint_file import read_torch_file, write_torch_file
    from physdyn.pipeline.topple import classifier_from_dict

    torch.set_num_threads(1)
    store = load_store(hull_store)
    classifier, report = fit_pointnet_topple([store], seeds=(0,), steps=300, batch=32, width=16, point_widths=(8, 12))
    shapes = {k: tuple(v.shape) for k, v in classifier.networks[0].items() if k.startswith("points")}
    assert shapes == {"points.0.weight": (8, 4), "points.0.bias": (8,), "points.2.weight": (12, 8), "points.2.bias": (12,),
                      "points.4.weight": (16, 12), "points.4.bias": (16,)}
    assert report["val_accuracy"] >= report["val_majority"]
    write_torch_file({"topple_classifier": classifier.to_dict()}, tmp_path / "c.ckpt")
    back = classifier_from_dict(read_torch_file(tmp_path / "c.ckpt", "a checkpoint")["topple_classifier"])
    assert back.point_widths == (8, 12)
    first = stores_first_frames([store], split=1)
    np.testing.assert_array_equal(back.probability(first["points"], first["v0"], first["w0"], first["spin"]),
                                  classifier.probability(first["points"], first["v0"], first["w0"], first["spin"]))


def test_a_model_with_it_predicts_toppling_with_no_simulator(fitted, tiny_store, hull_store, tmp_path, monkeypatch,
                                                            capsys):
    from physdyn.cli import main
    from physdyn.cli.fit_topple import write_with_classifier
    from physdyn.geometry.mass import vertical_inertia
    from physdyn.models.export import export_checkpoint
    from physdyn.predict.body import prepare_body
    from physdyn.predict.predictor import BUNDLED_CHECKPOINT, load_predictor

    _, classifier, _ = fitted
    # the bundled model's networks alone (no simulated start) with the PointNets instead of its roll-out classifier
    networks = export_checkpoint(BUNDLED_CHECKPOINT, tmp_path / "networks.ckpt", settings=["model.sim_seconds=0"])
    write_with_classifier(networks, classifier, tmp_path / "pointnet.ckpt")
    predictor = load_predictor(str(tmp_path / "pointnet.ckpt"))
    assert type(predictor.model.topple.classifier).__name__ == "PointNetToppleClassifier"
    box = trimesh.creation.box((0.06, 0.06, 0.3))  # tall and narrow: pushed low and hard it may topple
    predictor.predict(box.copy(), [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.2)  # imports done, mesh prepared
    # PyBullet refuses to run from here on: any simulation in the prediction would fail, as the simulator
    # beside the model shows
    refuse_pybullet(monkeypatch)
    with pytest.raises(AssertionError, match="PyBullet ran"):
        predictor.predict(box, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.5, compare_sim=True)
    results = predictor.predict_many([box, box], [[1.5, 0.0, 0.0], [0.3, 0.0, 0.0]], [[0.0, 6.0, 0.0], [0.0, 0.0, 1.0]],
                                     seconds=1.0)
    for result in results:
        p = result["topple_probability"]
        assert p is not None and p[0] == 0 and (np.diff(p) >= 0).all() and np.isfinite(result["com_position"]).all()
    # the probabilities are the classifier's, from the box's own hull_surface cloud and mass properties
    body = prepare_body(box)  # resting as given: step 0's orientation is the mesh frame
    points = body.points_body(classifier.num_points, "hull_surface")[None]
    spin = np.atleast_1d(vertical_inertia(body.spec.inertia_diag, body.spec.principal_axes, body.spec.mass,
                                          np.array([0.0, 0.0, 0.0, 1.0])))
    expected = classifier.probability(points, np.array([[1.5, 0.0, 0.0]]), np.array([[0.0, 6.0, 0.0]]), spin)
    assert results[0]["topple_probability"][-1] == pytest.approx(expected[0] * classifier.timing[-1], rel=1e-5)
    # tested on a store of other clouds than it reads: one line naming both, nothing written
    monkeypatch.undo()
    capsys.readouterr()
    assert main(["test", "--checkpoint", str(tmp_path / "pointnet.ckpt"), "--data", tiny_store, "--out",
                 str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err
    assert "reads hull_surface clouds of 64 points" in err and "holds surface ones" in err
    # nor on the classifier's kind of store, which the model (trained on surface clouds) does not read
    assert main(["test", "--checkpoint", str(tmp_path / "pointnet.ckpt"), "--data", hull_store, "--out",
                 str(tmp_path / "report")]) == 2
    assert "the model reads surface clouds and its topple classifier hull_surface ones" in capsys.readouterr().err
    assert not (tmp_path / "report").exists()


def test_many_pushes_go_through_the_network_a_few_at_a_time_with_the_same_numbers(fitted, monkeypatch):
    import physdyn.models.topple_pointnet as topple_pointnet

    store, classifier, _ = fitted
    first = stores_first_frames([store])
    for count in (150, 33):  # four passes of 32 and one of 22; one of 32 and one of a single push
        args = (first["points"][:count], first["v0"][:count], first["w0"][:count], first["spin"][:count])
        in_passes = classifier.probability(*args)
        monkeypatch.setattr(topple_pointnet, "PUSHES_PER_PASS", 10**9)
        # the same to float32 rounding (a pass of one push may take another matrix kernel, as a lone push did)
        np.testing.assert_allclose(in_passes, classifier.probability(*args), rtol=0, atol=1e-6)
        monkeypatch.setattr(topple_pointnet, "PUSHES_PER_PASS", 32)
        assert len(in_passes) == count


def test_a_few_pushes_run_on_numpy_with_the_torch_networks_numbers(fitted, monkeypatch):
    import physdyn.models.topple_pointnet as topple_pointnet

    store, classifier, _ = fitted
    first = stores_first_frames([store])
    for count in (1, 5, topple_pointnet.NUMPY_PUSHES):  # numpy; the same pushes through torch below
        args = (first["points"][:count], first["v0"][:count], first["w0"][:count], first["spin"][:count])
        on_numpy = classifier.probability(*args)
        monkeypatch.setattr(topple_pointnet, "NUMPY_PUSHES", 0)
        on_torch = classifier.probability(*args)
        monkeypatch.setattr(topple_pointnet, "NUMPY_PUSHES", 8)
        assert on_numpy.shape == on_torch.shape == (count,) and on_numpy.dtype == np.float64
        np.testing.assert_allclose(on_numpy, on_torch, rtol=0, atol=1e-6)


def test_fitted_on_thinned_clouds_it_reads_them_thinned_in_fitting_testing_and_prediction(hull_store, tmp_path,
                                                                                           monkeypatch):
    from physdyn.cli.fit_topple import write_with_classifier
    from physdyn.eval.evaluate import gather_truth, predict_rollouts
    from physdyn.geometry.mass import vertical_inertia
    from physdyn.geometry.sampling import thin_hull_surface
    from physdyn.models.checkpoint_file import read_torch_file, write_torch_file
    from physdyn.models.export import export_checkpoint
    from physdyn.models.topple_pointnet import thinned_clouds
    from physdyn.pipeline.topple import PointNetTopple, classifier_from_dict
    from physdyn.predict.body import prepare_body
    from physdyn.predict.predictor import BUNDLED_CHECKPOINT, contact_prior_predictor, load_predictor

    torch.set_num_threads(1)
    store = load_store(hull_store)
    classifier, report = fit_pointnet_topple([store], seeds=(0,), steps=300, batch=32, width=16, num_points=24)
    assert (classifier.num_points, classifier.thinned_from) == (24, 64)
    # the network was chosen on thinned clouds: its own validation accuracy is the classifier's, which thins
    assert report["val_accuracy"] == pytest.approx(report["network_val_accuracy"][0], abs=1.5 / report["val_sequences"])
    assert report["val_accuracy"] >= report["val_majority"]
    clouds = thinned_clouds(store.points[:5], classifier.thinned_to)
    assert clouds.shape == (5, 24, 3) and np.array_equal(clouds[3], thin_hull_surface(store.points[3], 24))
    # through a checkpoint; a file from before thinning reads its clouds whole
    write_torch_file({"topple_classifier": classifier.to_dict()}, tmp_path / "c.ckpt")
    assert classifier_from_dict(read_torch_file(tmp_path / "c.ckpt", "a checkpoint")["topple_classifier"]).thinned_from == 64
    old = classifier.to_dict()
    del old["thinned_from"]
    assert classifier_from_dict(old).thinned_from == 0
    # `physdyn test`'s roll-outs: each push's probability is the classifier's on its shape's thinned cloud
    model = dataclasses.replace(contact_prior_predictor(num_points=64).model, topple=PointNetTopple(classifier))
    sims = np.arange(12)
    rolled = predict_rollouts(model, store, sims, gather_truth(store, sims, 10))
    first = stores_first_frames([store], clouds=[thinned_clouds(store.points, classifier.thinned_to)])
    expected = classifier.probability(first["points"][:12], first["v0"][:12], first["w0"][:12], first["spin"][:12])
    np.testing.assert_allclose(rolled.topple_probability[:, -1], expected * classifier.per_step(np.ones(1), 10)[0, -1],
                               rtol=1e-5)
    # a prediction: the body's hull_surface cloud of the stores' size, thinned
    networks = export_checkpoint(BUNDLED_CHECKPOINT, tmp_path / "networks.ckpt", settings=["model.sim_seconds=0"])
    write_with_classifier(networks, classifier, tmp_path / "thin.ckpt")
    box = trimesh.creation.box((0.06, 0.06, 0.3))
    result = load_predictor(str(tmp_path / "thin.ckpt")).predict(box, [1.5, 0.0, 0.0], [0.0, 6.0, 0.0], seconds=1.0)
    body = prepare_body(box)
    cloud = thin_hull_surface(body.points_body(64, "hull_surface"), 24)[None]
    spin = np.atleast_1d(vertical_inertia(body.spec.inertia_diag, body.spec.principal_axes, body.spec.mass,
                                          np.array([0.0, 0.0, 0.0, 1.0])))
    expected = classifier.probability(cloud, np.array([[1.5, 0.0, 0.0]]), np.array([[0.0, 6.0, 0.0]]), spin)
    assert result["topple_probability"][-1] == pytest.approx(expected[0] * classifier.timing[-1], rel=1e-5)
    # with a simulated start, PyBullet runs on the hull of the cloud the classifier is given (hull_surface, of the
    # stores' size), neither the thinned one nor the model's surface cloud
    import physdyn.pipeline.motion as motion_module

    write_with_classifier(BUNDLED_CHECKPOINT, classifier, tmp_path / "hybrid.ckpt")
    hybrid = load_predictor(str(tmp_path / "hybrid.ckpt"))
    simulate, seen = motion_module.simulated_start, []
    monkeypatch.setattr(motion_module, "simulated_start", lambda model, points, *a: seen.append(points.shape) or simulate(model, points, *a))
    hybrid.predict(box, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], seconds=1.0)
    assert seen == [(1, 64, 3)] and hybrid.num_points == 256
    # asked to thin to as many points as the stores hold: one line, nothing written
    from physdyn.cli import main

    assert main(["fit-topple", "--pointnet", "--num-points", "64", "--checkpoint", str(networks), "--data", hull_store,
                 "--out", str(tmp_path / "whole.ckpt")]) == 2
    assert not (tmp_path / "whole.ckpt").exists()
