"""The learned correction of where a push ends (`physdyn fit-outcome`): it learns from a real store, its
inputs mirror as its training assumes, it moves a trajectory's end and nothing before its start, and a
checkpoint with it predicts with no simulator."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from physdyn.data.store import load_store
from physdyn.eval.outcome_fit import fit_outcome_correction
from physdyn.geometry.rotations import quat_multiply, rotvec_to_quat
from physdyn.models.outcome_correction import (MIRROR_INPUTS, MIRROR_TARGETS, OutcomeCorrection, OutcomeNet,
                                               outcome_inputs, yaw_of)
from physdyn.pipeline.correction import PointNetCorrection
from physdyn.predict.predictor import contact_prior_predictor
from tests.conftest import module_level_imports, refuse_pybullet


@pytest.fixture(scope="module")
def fitted(tiny_hull_store):
    torch.set_num_threads(1)
    store = load_store(tiny_hull_store)
    model = contact_prior_predictor(rate_hz=store.rate_hz, num_points=store.points.shape[1]).model
    return store, *fit_outcome_correction(model, [store], seeds=(0,), steps=400, batch=32, width=32)


def test_it_learns_where_the_prior_ends_wrong(fitted):
    store, correction, report = fitted
    train, held = report["splits"]["train"], report["splits"]["validation"]
    assert train["pushes"] == report["train_pushes"] > 30 and held["pushes"] > 10
    # where the pushes rest, closer than the prior's, on the training shapes and on shapes it never trained on
    # (seeds 0-2 of this fit: 0.78-0.87 and 0.80-0.83 of the prior's error)
    for split in (train, held):
        before, after = split["position_cm"]
        assert after < 0.9 * before, (before, after)
    assert len(correction.networks) == 1


@pytest.fixture(scope="module")
def fitted_pointnet(tiny_hull_store):
    torch.set_num_threads(1)
    store = load_store(tiny_hull_store)
    model = contact_prior_predictor(rate_hz=store.rate_hz, num_points=store.points.shape[1]).model
    return store, *fit_outcome_correction(model, [store], seeds=(0,), steps=400, batch=32, width=32, pointnet=True,
                                          num_points=16)


def test_a_pointnet_correction_reads_the_thinned_cloud_and_learns(fitted_pointnet):
    from physdyn.geometry.sampling import thin_hull_surface
    from physdyn.models.topple_pointnet import thinned_clouds

    store, correction, report = fitted_pointnet
    assert (correction.num_points, correction.thinned_from) == (16, store.points.shape[1])
    for split in (report["splits"]["train"], report["splits"]["validation"]):
        before, after = split["position_cm"]
        assert after < 0.9 * before, (before, after)
    # the clouds it reads: each given cloud thinned as at fitting, the hull's vertices first
    clouds = thinned_clouds(store.points[:3], correction.thinned_to)
    np.testing.assert_array_equal(clouds, np.stack([thin_hull_surface(c, 16) for c in store.points[:3]]))
    # it reads them: one push's inputs with each shape's cloud give different corrections; without a cloud, an error
    inputs = np.tile(np.linspace(-1.0, 1.0, 13) * correction.inputs_std + correction.inputs_mean, (3, 1))
    fixes = correction.correction(inputs, clouds)
    assert np.abs(fixes[0] - fixes[1]).max() > 1e-6 and np.abs(fixes[0] - fixes[2]).max() > 1e-6
    with pytest.raises(ValueError, match="reads each push's cloud"):
        correction.correction(inputs)
    with pytest.raises(ValueError, match="fitted on hull_surface clouds of 64 points and is given 16"):
        correction.check_given(clouds)
    # its networks run on numpy: the torch network's numbers to float32 rounding, a push alone as in a batch
    from physdyn.models.topple_pointnet import ToppleNet

    net = ToppleNet(correction.width, 13, tuple(correction.point_widths), outputs=3)
    net.load_state_dict(correction.networks[0])
    standard = (inputs - correction.inputs_mean) / correction.inputs_std
    standard[:, correction.inputs_std < 1e-6] = 0.0
    with torch.no_grad():
        torch_fix = net(torch.tensor(clouds), torch.tensor(standard, dtype=torch.float32)).double().numpy()
    np.testing.assert_allclose(fixes, torch_fix * correction.targets_std + correction.targets_mean, rtol=1e-5, atol=1e-7)
    # float32 rounding, as the batched line below: a push alone takes other product kernels than three (on some
    # CPUs 4e-6 of the turn apart, on others within 1e-6)
    np.testing.assert_allclose(correction.correction(inputs[1:2], clouds[1:2]), fixes[1:2], rtol=1e-5, atol=1e-7)
    many = np.repeat(np.arange(3), 15)  # 45 pushes: two passes of 32
    np.testing.assert_allclose(correction.correction(inputs[many], clouds[many]), fixes[many], rtol=1e-5, atol=1e-7)
    assert correction.correction(inputs[:0], clouds[:0]).shape == (0, 3)
    # a checkpoint's copy (tensors, lists and numbers) corrects alike
    again = OutcomeCorrection.from_dict(correction.to_dict())
    np.testing.assert_array_equal(again.correction(inputs, clouds), fixes)
    assert (again.num_points, again.thinned_from) == (16, store.points.shape[1])


def test_what_its_networks_trained_on_is_what_a_roll_out_gives_them(fitted_pointnet):
    from physdyn.data.windows import store_spin_inertia, store_world_inertia
    from physdyn.eval.outcome_fit import EXTRA_STEPS, outcome_training_data
    from physdyn.eval.rollout import RolloutOptions, rollout
    from physdyn.geometry.rotations import quat_conjugate
    from physdyn.models.topple_pointnet import travel_turn

    store, correction, _ = fitted_pointnet
    model = contact_prior_predictor(rate_hz=store.rate_hz, num_points=store.points.shape[1]).model
    data = outcome_training_data(model, [store], correction.num_points)
    rows = data["val"][:6]
    # what the training read for these pushes: the frame and thinned cloud of outcome_training_data
    fix = correction.correction(data["inputs"][rows], np.einsum("bij,bnj->bni", data["frame"][rows],
                                                                 data["clouds"][data["shape"][rows]]))
    # the same pushes rolled out as fitting does, with the correction and without: the ends differ by that
    sims = np.flatnonzero(store.topple_step < 0)
    horizon = int(store.lengths()[sims].max()) - 1 + EXTRA_STEPS
    sims = sims[rows]
    first = store.start[sims]
    q0, p0 = store.orientation_xyzw[first], store.com_position[first]
    v0, w0 = store.linear_velocity[first], store.angular_velocity[first]
    kwargs = {"spin_inertia": store_spin_inertia(store, sims, q0), "body_inertia": store_world_inertia(store, sims, q0)}
    plain = rollout(model, store.points[store.shape_id[sims]], q0, p0, v0, w0, horizon, RolloutOptions(**kwargs))
    model = dataclasses.replace(model, correction=PointNetCorrection(correction, store.rate_hz))
    moved = rollout(model, store.points[store.shape_id[sims]], q0, p0, v0, w0, horizon, RolloutOptions(**kwargs))
    turn = travel_turn(v0)
    shift = moved.com_position[:, -1] - plain.com_position[:, -1]
    np.testing.assert_allclose(np.einsum("bij,bj->bi", turn, shift)[:, :2], fix[:, :2], atol=1e-6)
    np.testing.assert_allclose(yaw_of(quat_multiply(moved.orientation_xyzw[:, -1],
                                                    quat_conjugate(plain.orientation_xyzw[:, -1]))), fix[:, 2], atol=1e-6)
    # a caller that reads the states only (Predictor) gets the same states, and no changes worked out again
    states_only = rollout(model, store.points[store.shape_id[sims]], q0, p0, v0, w0, horizon,
                          RolloutOptions(with_changes=False, **kwargs))
    for key in ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(states_only, key), getattr(moved, key), err_msg=key)
    assert states_only.delta_rotation is None and states_only.num_steps == moved.num_steps == horizon
    np.testing.assert_allclose(moved.delta_position, np.diff(moved.com_position, axis=1), atol=1e-12)


def test_an_input_every_training_push_shared_reads_as_it_did_in_training():
    # the resting velocities were zero in every training push (roll-outs ran past rest); a request cut off
    # while still slowing (under the rest speed) must not be corrected by kilometres (it was)
    net = OutcomeNet(8)
    correction = OutcomeCorrection([net.state_dict()], np.zeros(13), np.r_[np.ones(6), np.full(3, 1e-9), np.ones(4)],
                                   np.zeros(3), np.ones(3), width=8)
    rest, slowing = np.zeros((1, 13)), np.zeros((1, 13))
    slowing[0, 6:9] = [0.015, -0.01, 0.1]
    np.testing.assert_array_equal(correction.correction(slowing), correction.correction(rest))
    # the shipped model: a box pushed for 0.2 s ends near where the contact prior puts it
    from physdyn.predict.predictor import load_predictor

    box = trimesh.creation.box((0.1, 0.06, 0.04))
    for v0, seconds in (([0.35, 0.0, 0.0], 0.2), ([0.3, 0.0, 0.0], 2 / 15)):
        mine = load_predictor("fast").predict(box, v0, [0.0, 0.0, 0.0], seconds=seconds)
        assert np.abs(mine["com_position"][-1, :2]).max() < 0.1 and np.abs(mine["linear_velocity"]).max() < 1.0


def test_a_pointnet_correction_moves_predictions_with_no_simulator_and_a_padded_batch_equals_each(fitted_pointnet,
                                                                                                 monkeypatch):
    store, correction, _ = fitted_pointnet
    prior = contact_prior_predictor(rate_hz=store.rate_hz, num_points=store.points.shape[1])
    corrected = contact_prior_predictor(rate_hz=store.rate_hz, num_points=store.points.shape[1])
    corrected.model = dataclasses.replace(corrected.model, correction=PointNetCorrection(correction, store.rate_hz))
    box = trimesh.creation.box((0.08, 0.05, 0.04))
    corrected.predict(box.copy(), [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.2)  # imports done, mesh prepared
    refuse_pybullet(monkeypatch)
    pushes = [([0.8, 0.2, 0.0], [0.0, 0.0, 4.0], 2.0), ([0.6, -0.3, 0.0], [0.0, 0.0, -2.0], 3.0)]
    alone = [corrected.predict(box, v, w, seconds=t) for v, w, t in pushes]
    theirs = prior.predict(box, *pushes[0][:2], seconds=2.0)
    np.testing.assert_allclose(alone[0]["com_position"][0], theirs["com_position"][0])
    assert not np.allclose(alone[0]["com_position"][-1], theirs["com_position"][-1], atol=1e-5)
    batch = corrected.predict_many([box, box], [p[0] for p in pushes], [p[1] for p in pushes], [p[2] for p in pushes])
    for one, many in zip(alone, batch):
        for key in ("com_position", "orientation_xyzw", "linear_velocity"):
            np.testing.assert_allclose(many[key], one[key], atol=1e-5, err_msg=key)


def test_the_inputs_mirror_as_the_training_assumes():
    rng = np.random.default_rng(0)
    B = 40
    v0, w0 = rng.normal(size=(B, 3)), rng.normal(size=(B, 3))
    p0, p = rng.normal(size=(B, 3)), rng.normal(size=(B, 3))
    v, w = rng.normal(size=(B, 3)), rng.normal(size=(B, 3))
    q0 = rotvec_to_quat(rng.normal(size=(B, 3)))
    q = rotvec_to_quat(rng.normal(size=(B, 3)))
    inputs, turn = outcome_inputs(v0, w0, np.ones(B), p0, q0, p, q, v, w)
    # along the travel: the whole horizontal speed at step 0; the resting displacement in that frame
    np.testing.assert_allclose(inputs[:, 0], np.hypot(v0[:, 0], v0[:, 1]))
    np.testing.assert_allclose(np.hypot(inputs[:, 9], inputs[:, 10]), np.hypot(*(p - p0)[:, :2].T))
    # the whole push mirrored in the world (y -> -y; spins are axial vectors; rotations R -> F R F)
    flip, qf = np.diag([1.0, -1.0, 1.0]), np.array([-1.0, 1.0, -1.0, 1.0])
    mirrored, _ = outcome_inputs(v0 @ flip, -(w0 @ flip), np.ones(B), p0 @ flip, q0 * qf, p @ flip, q * qf,
                                 v @ flip, -(w @ flip))
    np.testing.assert_allclose(mirrored, inputs * MIRROR_INPUTS, atol=1e-9)
    # the targets (along, across, turn) are differences of these columns, so they mirror as columns 9-11
    np.testing.assert_array_equal(MIRROR_TARGETS, MIRROR_INPUTS[9:12])


def constant_correction(along: float, across: float, turn: float) -> OutcomeCorrection:
    """A correction whose network always says (along, across, turn): the last layer all bias."""
    net = OutcomeNet(8)
    with torch.no_grad():
        net.layers[-1].weight.zero_()
        net.layers[-1].bias.copy_(torch.tensor([along, across, turn]))
    return OutcomeCorrection([net.state_dict()], np.zeros(13), np.ones(13), np.zeros(3), np.ones(3), width=8)


def sliding_rows(T: int = 12, rest: int = 8, turn: float = 0.6) -> dict[str, np.ndarray]:
    """Three pushes along +y, sliding to rest by step ``rest`` and turning by ``turn``; the third still
    moving at its last step."""
    dt = 1 / 15
    t = np.minimum(np.arange(T), rest) / rest
    path = np.stack([np.zeros(T), 0.2 * (2 * t - t * t), np.full(T, 0.05)], axis=1)
    p = np.repeat(path[None], 3, axis=0)
    q = rotvec_to_quat(np.repeat((turn * t)[None, :, None] * np.array([0.0, 0.0, 1.0]), 3, axis=0))
    v = np.gradient(p, dt, axis=1)
    v[:, rest:] = 0.0
    v[2, -1] = [0.0, 0.3, 0.0]
    return {"com_position": p, "orientation_xyzw": q, "linear_velocity": v, "angular_velocity": np.zeros((3, T, 3))}


def test_it_moves_the_end_and_spreads_the_change_over_the_path():
    dt = 1 / 15
    given = sliding_rows()
    states = {k: a.copy() for k, a in given.items()}
    v0 = np.tile([0.0, 0.5, 0.0], (3, 1))
    rows = constant_correction(0.03, -0.01, 0.2).apply(states, v0, np.zeros((3, 3)), np.full(3, 1e-3), dt,
                                                      toppled=np.array([False, True, False]))
    np.testing.assert_array_equal(rows, [True, False, False])  # the toppled and the moving push are left alone
    for key in states:
        np.testing.assert_array_equal(states[key][1:], given[key][1:])
    new, old = states["com_position"][0], given["com_position"][0]
    np.testing.assert_allclose(new[0], old[0])  # the start stays, and so do the step-0 velocities
    np.testing.assert_array_equal(states["linear_velocity"][0, 0], given["linear_velocity"][0, 0])
    np.testing.assert_array_equal(states["angular_velocity"][0, 0], given["angular_velocity"][0, 0])
    # travel is +y: along +0.03 m is +y, across (+x turned left of the travel) -0.01 m is +x
    np.testing.assert_allclose(new[-1] - old[-1], [0.01, 0.03, 0.0], atol=1e-12)
    assert (np.diff(np.linalg.norm(new[:, :2] - old[:, :2], axis=1)) >= -1e-12).all()  # the change grows along the path
    turn = yaw_of(states["orientation_xyzw"][0])
    assert turn[-1] == pytest.approx(0.6 + 0.2) and turn[0] == pytest.approx(0.0)
    # at rest after the correction too, from the step after the roll-out's rest on
    np.testing.assert_allclose(states["linear_velocity"][0, 9:], 0.0, atol=1e-12)
    np.testing.assert_allclose(states["angular_velocity"][0, 9:], 0.0, atol=1e-12)


def test_a_roll_out_that_does_not_turn_turns_along_its_path_and_a_cut_one_is_judged_at_its_end():
    dt = 1 / 15
    given = sliding_rows(T=30, rest=8, turn=0.0)  # slides to rest by step 8 without turning
    states = {k: a.copy() for k, a in given.items()}
    correction = constant_correction(0.0, 0.0, 0.2)
    rows = correction.apply(states, np.tile([0.0, 0.5, 0.0], (3, 1)), np.zeros((3, 3)), np.full(3, 1e-3), dt,
                            lengths=np.array([30, 5, 20]))
    # the first rests at its end; the second is cut at step 4, still sliding: left alone though the batch's
    # roll-out rests by its end; the third is judged at its own last step (19), where it rests
    np.testing.assert_array_equal(rows, [True, False, True])
    np.testing.assert_array_equal(states["orientation_xyzw"][1], given["orientation_xyzw"][1])
    turn = yaw_of(states["orientation_xyzw"][0])
    np.testing.assert_allclose(turn[8:], 0.2, atol=1e-12)  # the whole turn by the time the path ends, not later
    assert 0.0 < turn[4] < 0.2
    np.testing.assert_allclose(states["angular_velocity"][0, 9:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(yaw_of(states["orientation_xyzw"][2]), turn, atol=1e-12)  # cut later, the same
    # a push that rests exactly at its own last step: padded in a batch or alone, the same states, velocities too
    padded = {k: a.copy() for k, a in given.items()}
    correction.apply(padded, np.tile([0.0, 0.5, 0.0], (3, 1)), np.zeros((3, 3)), np.full(3, 1e-3), dt,
                     lengths=np.array([30, 5, 9]))
    alone = {k: a[2:3, :9].copy() for k, a in given.items()}
    assert correction.apply(alone, np.array([[0.0, 0.5, 0.0]]), np.zeros((1, 3)), np.full(1, 1e-3), dt)[0]
    for key in alone:
        np.testing.assert_allclose(padded[key][2, :9], alone[key][0], atol=1e-12, err_msg=key)


def test_a_push_is_toppled_by_its_own_end_not_the_batchs():
    from physdyn.eval.rollout import toppled_by_own_end

    q0 = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    tilt = rotvec_to_quat(np.array([0.0, 1.0, 0.0]) * np.linspace(0.0, 1.2, 10)[:, None])  # past 45 deg from step 6
    poses = np.repeat(tilt[None], 3, axis=0)
    np.testing.assert_array_equal(toppled_by_own_end(None, q0, poses, np.array([10, 6, 7])), [True, False, True])
    probability = np.repeat(np.linspace(0.0, 0.9, 10)[None], 3, axis=0)  # reaches 0.5 at step 5
    np.testing.assert_array_equal(toppled_by_own_end(probability, q0, poses, np.array([10, 5, 6])), [True, False, True])
    assert toppled_by_own_end(probability, q0, poses).all()


def test_fit_outcome_says_what_is_missing_in_one_line(tiny_hull_store, monkeypatch):
    import types

    from physdyn.errors import PhysdynError
    from physdyn.eval import outcome_fit

    model = contact_prior_predictor(num_points=64).model
    everything_topples = types.SimpleNamespace(topple_step=np.zeros(5, dtype=np.int64))
    with pytest.raises(PhysdynError, match="every push of the --data stores topples"):
        fit_outcome_correction(model, [everything_topples])
    monkeypatch.setattr(outcome_fit, "REST_SPEED", -1.0)  # nothing counts as at rest
    with pytest.raises(PhysdynError, match="come to rest"):
        fit_outcome_correction(model, [load_store(tiny_hull_store)], steps=20)


def test_fit_outcome_writes_a_checkpoint_that_predicts_with_no_simulator(tiny_hull_store, tiny_store, tmp_path,
                                                                          monkeypatch, capsys):
    from physdyn.cli import main
    from physdyn.predict.predictor import load_predictor

    out = tmp_path / "outcome.ckpt"
    args = ["fit-outcome", "--checkpoint", "contact_prior", "--data", tiny_hull_store, "--out", str(out)]
    assert main([*args, "--steps", "40", "--batch", "32"]) == 0
    assert "median error of the resting pose" in capsys.readouterr().out and out.is_file()
    with_cloud = tmp_path / "outcome_pointnet.ckpt"
    assert main(["fit-outcome", "--checkpoint", "contact_prior", "--data", tiny_hull_store, "--out", str(with_cloud),
                 "--pointnet", "--num-points", "16", "--widths", "8", "16", "32", "--steps", "40", "--batch", "32"]) == 0
    read = load_predictor(str(with_cloud)).model.correction.correction
    assert (read.num_points, read.thinned_from, tuple(read.point_widths), read.width) == (16, 64, (8, 16), 32)
    # tested on a store of clouds it cannot read: one line naming both, nothing written
    capsys.readouterr()
    assert main(["test", "--checkpoint", str(with_cloud), "--data", tiny_store, "--out", str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err
    assert "outcome correction reads hull_surface clouds of 64 points" in err and "holds surface ones" in err, err
    assert not (tmp_path / "report").exists()
    # bad input: one line, exit 2, nothing written
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and len(err.strip().splitlines()) == 1
    for bad, message in ((["--checkpoint", "contact_prior"], "pass --data"),
                         (["--checkpoint", "contact_prior", "--data", tiny_hull_store, "--num-points", "16"], "add --pointnet"),
                         (["--checkpoint", "contact_prior", "--data", tiny_hull_store, "--pointnet", "--num-points", "64"],
                          "not below"),
                         (["--checkpoint", "contact_prior", "--data", tiny_hull_store, "--pointnet", "--device", "tpu"],
                          "use cpu, cuda or cuda:N"),
                         (["--checkpoint", "contact_prior", "--data", tiny_hull_store, "--device", "cpu"], "add --pointnet"),
                         (["--checkpoint", "contact_prior", "--data", tiny_hull_store, "--widths", "8", "16"], "add --pointnet"),
                         (["--checkpoint", "contact_prior", "--data", tiny_store], "hull_surface"),
                         (["--checkpoint", "contact_prior", "--data", tiny_hull_store, "--steps", "3"], "at least 20")):
        assert main(["fit-outcome", *bad, "--out", str(tmp_path / "bad.ckpt")]) == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "bad.ckpt").exists()
    # a file named contact_prior where the user is comes first (here not a checkpoint: said in one line)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "contact_prior").write_text("not a checkpoint")
    assert main(["fit-outcome", "--checkpoint", "contact_prior", "--data", tiny_hull_store, "--out", "bad.ckpt"]) == 2
    assert "contact_prior is not a PyTorch checkpoint" in capsys.readouterr().err
    monkeypatch.undo()
    predictor = load_predictor(str(out))
    prior = contact_prior_predictor(num_points=64)
    assert predictor.model.correction.registered_name == "mlp"
    box = trimesh.creation.box((0.08, 0.05, 0.04))
    predictor.predict(box.copy(), [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.2)  # imports done, mesh prepared
    refuse_pybullet(monkeypatch)
    mine = predictor.predict(box, [0.8, 0.2, 0.0], [0.0, 0.0, 4.0], seconds=2.0)
    theirs = prior.predict(box, [0.8, 0.2, 0.0], [0.0, 0.0, 4.0], seconds=2.0)
    np.testing.assert_allclose(mine["com_position"][0], theirs["com_position"][0])
    assert not np.allclose(mine["com_position"][-1], theirs["com_position"][-1], atol=1e-5)
    assert np.isfinite(mine["com_position"]).all() and np.isfinite(mine["linear_velocity"]).all()


def test_the_shipped_fast_model_simulates_nothing_and_a_file_of_its_name_comes_first(tmp_path, monkeypatch):
    from physdyn.errors import CheckpointError
    from physdyn.models.outcome_correction import outcome_inputs as inputs_of
    from physdyn.predict.predictor import load_predictor

    predictor = load_predictor("fast")
    pipeline = predictor.model
    model, classifier = pipeline.network, pipeline.topple.classifier
    assert pipeline.correction.registered_name == "pointnet" and type(classifier).__name__ == "PointNetToppleClassifier"
    assert predictor.points_method == "hull_surface" and not pipeline.simulates
    # its classifier reads the model's 256-point cloud thinned to 64 (fit-topple --pointnet --num-points 64)
    assert (classifier.num_points, classifier.thinned_from) == (64, 256)
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    predictor.predict(box.copy(), [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.2)  # imports done, mesh prepared
    # a mesh forgotten is new again: its thinned cloud too (benchmarks/frontier.py times its thinning)
    assert any(key[0] == 64 for key in predictor._prepared.thinned)
    predictor.forget_meshes()
    assert not predictor._prepared.thinned and not predictor._prepared.meshes
    refuse_pybullet(monkeypatch)
    v0, w0 = np.array([0.8, 0.1, 0.0]), np.array([0.0, 0.0, 3.0])
    mine = predictor.predict(box, v0, w0, seconds=2.0)
    alone = contact_prior_predictor()
    alone.model.network.config.model.contact_substeps = model.config.model.contact_substeps  # fast's prior: 8 sub-steps
    prior = alone.predict(box, v0, w0, seconds=2.0)
    assert not mine["toppled"]
    np.testing.assert_allclose(mine["linear_velocity"][0], v0)  # the push as given
    np.testing.assert_allclose(mine["angular_velocity"][0], w0)
    # the end moved by what the correction says of the prior's resting state, along and across the travel
    ends = [prior[k][None] for k in ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity")]
    x, turn = inputs_of(v0[None], w0[None], np.atleast_1d(x_spin(box)), ends[0][:, 0], ends[1][:, 0], ends[0][:, -1],
                        ends[1][:, -1], ends[2][:, -1], ends[3][:, -1])
    # its correction reads the box's cloud as the predictor samples it, thinned to 64, in the push's travel frame
    from physdyn.data.windows import world_oriented_points
    from physdyn.predict.body import prepare_body

    from physdyn.models.topple_pointnet import thinned_clouds

    correction = pipeline.correction.correction
    assert (correction.num_points, correction.thinned_from) == (64, 256)
    cloud = prepare_body(box).points_body(predictor.num_points, predictor.points_method)
    seen = np.einsum("bij,bnj->bni", turn, world_oriented_points(thinned_clouds(cloud[None], correction.thinned_to),
                                                                 ends[1][:, 0]))
    fix = correction.correction(x, seen)[0]
    moved = mine["com_position"][-1, :2] - prior["com_position"][-1, :2]
    np.testing.assert_allclose([moved @ turn[0, 0, :2], moved @ turn[0, 1, :2]], fix[:2], atol=1e-9)
    # one request alone, or padded beside a longer one in a batch: the same prediction
    short = predictor.predict(box, v0, w0, seconds=0.3)
    both = predictor.predict_many([box, box], [v0, v0], [w0, w0], seconds=[0.3, 2.0])
    np.testing.assert_allclose(both[0]["com_position"], short["com_position"], atol=1e-6)
    np.testing.assert_allclose(both[1]["com_position"], mine["com_position"], atol=1e-6)
    # a file called "fast" where the user is wins over the shipped model's name; a folder of that name does not
    monkeypatch.chdir(tmp_path)
    (tmp_path / "fast").mkdir()
    assert load_predictor("fast").model.correction.registered_name == "pointnet"
    (tmp_path / "fast").rmdir()
    (tmp_path / "fast").write_text("not a checkpoint")
    with pytest.raises(CheckpointError, match="fast is not a PyTorch checkpoint"):
        load_predictor("fast")
    # an installation without the file says so
    from physdyn.models import checkpoint_file

    monkeypatch.setitem(checkpoint_file.SHIPPED, "fast", tmp_path / "gone" / "fast.ckpt")
    (tmp_path / "fast").unlink()
    with pytest.raises(CheckpointError, match="no shipped model 'fast' in this installation"):
        load_predictor("fast")


def x_spin(mesh) -> float:
    """I_zz / m of ``mesh`` about the vertical as it rests (the mesh frame, as ``predict`` places it)."""
    from physdyn.geometry.mass import vertical_inertia
    from physdyn.predict.body import prepare_body

    spec = prepare_body(mesh).spec
    return float(vertical_inertia(spec.inertia_diag, spec.principal_axes, spec.mass, np.array([0.0, 0.0, 0.0, 1.0])))


def test_the_correction_and_topple_pointnet_import_no_store_or_mesh_library():
    """What a correction needs to train and predict loads without zarr or trimesh (a GPU machine for the studies
    has neither): their modules' own imports, followed through the package, reach neither."""
    seen, reached = module_level_imports("physdyn.models.outcome_correction")
    assert "physdyn.models.topple_classifier" in seen and "torch" in reached  # it did follow the package
    assert not {"zarr", "trimesh", "numcodecs", "pybullet", "open3d"} & reached, sorted(reached)
    assert not any(n.startswith("physdyn.data") for n in seen), sorted(seen)
