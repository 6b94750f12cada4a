"""Roll-outs: integration is exact on true changes, warm starts feed the truth, evaluation runs end to end."""

import json

import numpy as np
import pytest
import torch

from physdyn.data.store import load_store
from physdyn.data.windows import world_oriented_points
from physdyn.eval.baselines import CheckpointError, load_checkpoint
from physdyn.pipeline.presets import load_pipeline
from physdyn.eval.evaluate import EvaluationError, compare, evaluate, gather_truth, select_sequences
from physdyn.eval.metrics import rotation_angle_deg
from physdyn.eval.rollout import DELTA_KEYS, RolloutOptions, integrate, rollout, teacher_forced
from physdyn.models.dynamics_network import DynamicsPrediction
from physdyn.models.training import fit, load_experiment_config
from tests.conftest import run_cli
from tests.models.conftest import QUICKSTART, shrunk_overrides


@pytest.fixture(scope="module")
def tiny_checkpoint(tiny_store, tmp_path_factory):
    """A real (few-step) quickstart checkpoint trained on the tiny store."""
    out = tmp_path_factory.mktemp("eval_run")
    return str(fit(load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, out, "trainer.max_steps=20"))).last_checkpoint)


@pytest.fixture(scope="module")
def store(tiny_store):
    return load_store(tiny_store)


def _first_states(truth):
    return (truth["com_position"][:, 0], truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, 0],
            truth["angular_velocity"][:, 0])


def test_integrating_true_changes_reproduces_the_stored_trajectories(store):
    sims = np.arange(store.num_sims)[:: max(1, store.num_sims // 20)]
    truth = gather_truth(store, sims)
    p0, q0, v0, w0 = _first_states(truth)
    out = integrate(p0, q0, v0, w0, {k: truth[k] for k in DELTA_KEYS})
    for key in ("com_position", "linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(out[key], truth[key], atol=1e-9, err_msg=key)
    assert rotation_angle_deg(out["orientation_xyzw"], truth["orientation_xyzw"]).max() < 1e-5
    np.testing.assert_allclose(np.linalg.norm(out["orientation_xyzw"], axis=-1), 1.0, atol=1e-12)
    assert truth["toppled"].any()  # the check covered real toppling rotations too
    # one sequence alone (composed on Python numbers) gives bitwise the rows of the batch
    for r in (0, len(sims) - 1):
        one = integrate(p0[r:r + 1], q0[r:r + 1], v0[r:r + 1], w0[r:r + 1], {k: truth[k][r:r + 1] for k in DELTA_KEYS})
        for key, value in one.items():
            np.testing.assert_array_equal(value[0], out[key][r], err_msg=key)


class ReplayTruth:
    """A stand-in predictor that returns the true changes of the sequences it is rolled out on."""

    def __init__(self, truth):
        self.truth, self.t, self.points = truth, 0, None

    def encode_points(self, points):
        self.points = points
        return torch.zeros(len(points), 1)

    def step(self, feature, v, w, state):
        t = self.t
        self.t += 1
        d = [torch.as_tensor(self.truth[k][:, t]) for k in DELTA_KEYS]
        return DynamicsPrediction(*d, topple_probability=torch.full((len(v),), 0.25), state=(state or 0) + 1)


def test_rollout_loop_with_true_changes_is_exact_and_orients_the_cloud(store):
    sims = select_sequences(store, "test")[:6]
    truth = gather_truth(store, sims)
    p0, q0, v0, w0 = _first_states(truth)
    points = store.points[store.shape_id[sims]]
    model = ReplayTruth(truth)
    S = truth["delta_position"].shape[1]
    # evaluate and predict pass the bodies' spin inertia always; a predictor without it is rolled out all the same
    out = rollout(model, points, q0, p0, v0, w0, S, RolloutOptions(spin_inertia=np.full(len(sims), 1e-3)))
    np.testing.assert_allclose(model.points, world_oriented_points(points, q0), atol=1e-6)
    np.testing.assert_allclose(out.com_position, truth["com_position"], atol=1e-6)  # float32 changes
    np.testing.assert_allclose(out.linear_velocity, truth["linear_velocity"], atol=1e-5)
    assert rotation_angle_deg(out.orientation_xyzw, truth["orientation_xyzw"]).max() < 1e-3
    # the fed velocities are the roll-out's own (here: the truth, up to float32 rounding)
    np.testing.assert_array_equal(out.fed_linear_velocity, out.linear_velocity[:, :-1])
    assert out.topple_probability.shape == (6, S + 1)
    assert np.all(out.topple_probability[:, 0] == 0) and np.all(out.topple_probability[:, 1:] == 0.25)


def test_warm_start_feeds_the_true_velocities_first(store, tiny_checkpoint):
    model = load_checkpoint(tiny_checkpoint)
    sims = select_sequences(store, "test")[:4]
    truth = gather_truth(store, sims, num_steps=12)
    p0, q0, v0, w0 = _first_states(truth)
    points = store.points[store.shape_id[sims]][:, : model.num_points]
    K = 3
    warm = (truth["linear_velocity"][:, 1:K + 1], truth["angular_velocity"][:, 1:K + 1])
    out = rollout(model, points, q0, p0, v0, w0, 12, RolloutOptions(warm_start_velocities=warm))
    np.testing.assert_allclose(out.fed_linear_velocity[:, :K + 1], truth["linear_velocity"][:, :K + 1], atol=1e-12)
    np.testing.assert_allclose(out.fed_angular_velocity[:, :K + 1], truth["angular_velocity"][:, :K + 1], atol=1e-12)
    # after the warm start the model's own predictions are fed back
    np.testing.assert_allclose(out.fed_linear_velocity[:, K + 1],
                               truth["linear_velocity"][:, K] + out.delta_linear_velocity[:, K], atol=1e-12)
    assert not np.allclose(out.fed_linear_velocity[:, K + 1], truth["linear_velocity"][:, K + 1], atol=1e-4)
    cold = rollout(model, points, q0, p0, v0, w0, 12)
    np.testing.assert_allclose(cold.fed_linear_velocity[:, 1], v0 + cold.delta_linear_velocity[:, 0], atol=1e-12)
    # without a warm start the velocity track is the integrated one, and the recurrent state is carried:
    # the same inputs at every step as teacher forcing give the same changes
    np.testing.assert_array_equal(cold.linear_velocity[:, :-1], cold.fed_linear_velocity)
    full = rollout(model, points, q0, p0, v0, w0, 12, RolloutOptions((truth["linear_velocity"][:, 1:12], truth["angular_velocity"][:, 1:12])))
    # the roll-out's own orientations: a model fed its orientation then gets the same inputs both ways
    forced = teacher_forced(model, points, q0, truth["linear_velocity"][:, :12], truth["angular_velocity"][:, :12],
                            full.orientation_xyzw[:, :12])
    for key in DELTA_KEYS:
        np.testing.assert_allclose(full.deltas()[key], forced[key], atol=1e-5, err_msg=key)
    np.testing.assert_allclose(full.topple_probability[:, 1:], forced["topple_probability"], atol=1e-6)


def test_any_horizon(store, tiny_checkpoint):
    model = load_checkpoint(tiny_checkpoint)
    sims = select_sequences(store, "test")[:2]
    truth = gather_truth(store, sims)
    p0, q0, v0, w0 = _first_states(truth)
    points = store.points[store.shape_id[sims]][:, : model.num_points]
    for steps in (0, 1, 150):
        out = rollout(model, points, q0, p0, v0, w0, steps)
        assert out.com_position.shape == (2, steps + 1, 3) and out.orientation_xyzw.shape == (2, steps + 1, 4)
        assert out.delta_rotation.shape == (2, steps, 3) and out.topple_probability.shape == (2, steps + 1)
        np.testing.assert_array_equal(out.com_position[:, 0], p0)
        assert np.isfinite(out.com_position).all()
        np.testing.assert_allclose(np.linalg.norm(out.orientation_xyzw, axis=-1), 1.0, atol=1e-12)
    with pytest.raises(ValueError, match="warm_start_velocities"):
        rollout(model, points, q0, p0, v0, w0, 3, RolloutOptions((np.zeros((2, 1, 3)), np.zeros((1, 1, 3)))))


def test_evaluation_end_to_end_with_a_real_checkpoint(store, tiny_checkpoint):
    result = evaluate(tiny_checkpoint, store, warm_start=1)
    n_test = int(np.sum(store.split == 2))
    assert result["num_sequences"] == n_test and result["warm_start"] == 1
    groups = result["rollout"]
    assert groups["non_toppling"]["count"] + groups["toppling"]["count"] == groups["all"]["count"] == n_test
    assert groups["non_toppling"]["count"] == int(np.sum((store.split == 2) & ~store.toppled))
    assert result["headline"]["count"] == groups["non_toppling"]["count"]
    for key in ("linear_velocity", "angular_velocity", "position", "angle_deg"):
        assert np.isfinite(groups["all"]["rollout"][key]) and np.isfinite(groups["all"]["single_step"][key])
    assert set(result["per_category"]) <= set(store.category_names)
    assert sum(c["all"]["count"] for c in result["per_category"].values()) == n_test
    topple = result["topple"]
    assert topple["tp"] + topple["fn"] == int(np.sum((store.split == 2) & store.toppled))
    curves = result["curves"]["all"]
    assert len(curves["position_m"]) == int(store.lengths()[store.split == 2].max())
    assert curves["position_m"][0] == pytest.approx(0.0)
    json.dumps(result)  # JSON-ready
    # a category filter and the per-sequence table agree with the full run
    cat = store.category_names[int(store.sim_category()[store.split == 2][0])]
    sub = evaluate(tiny_checkpoint, store, categories=[cat])
    assert sub["num_sequences"] == result["per_category"][cat]["all"]["count"]
    with pytest.raises(EvaluationError, match="unknown category"):
        evaluate(tiny_checkpoint, store, categories=["chairs"])


def test_compare_names_the_verdict_and_takes_checkpoints_as_baselines(store, tiny_checkpoint):
    out = compare(tiny_checkpoint, store, baselines=("stay_put", "coulomb_slide", tiny_checkpoint))
    names = [row["predictor"] for row in out["table"]]
    assert names[0] == out["model"] and {"stay_put", "coulomb_slide"} <= set(names) and len(names) == 4
    ours = out["results"][out["model"]]["headline"]["final_position_m_median"]
    slide = out["results"]["coulomb_slide"]["headline"]["final_position_m_median"]
    assert ("does not beat" in out["verdict"]) == (ours >= slide)
    assert "Coulomb" in out["verdict"] and "median final position error" in out["verdict"]


def test_a_file_that_is_not_a_physdyn_checkpoint_is_a_clear_error(tmp_path):
    other = tmp_path / "other.ckpt"
    torch.save({"state_dict": {}, "epoch": 3}, other)
    text = tmp_path / "notes.ckpt"
    text.write_text("hello")
    for path, match in ((other, "not a physdyn DynamicsModel checkpoint"), (text, "not a PyTorch checkpoint"),
                        (tmp_path / "missing.ckpt", "no checkpoint file")):
        with pytest.raises(CheckpointError, match=match) as info:
            load_checkpoint(path)
        assert "\n" not in str(info.value)


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_physdyn_test_command_writes_the_report(tiny_store, tiny_checkpoint, tmp_path):
    out = tmp_path / "report"
    proc = run_cli("test", "--checkpoint", tiny_checkpoint, "--data", tiny_store, "--out", str(out), "--warm-start", "1",
                   "--baseline-checkpoint", tiny_checkpoint)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Coulomb-sliding baseline" in proc.stdout
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["table"]) == 4 and metrics["results"][metrics["model"]]["warm_start"] == 1
    assert (out / "report.md").read_text().count("coulomb_slide") >= 1
    for png in ("rollout_error_vs_time.png", "errors_per_category.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The viewer shows the very roll-outs that were scored: best, median and worst of each category.
    from physdyn.viz.viewer import read_viewer_data

    scenes = read_viewer_data(out / "viewer.html")["scenes"]
    per_seq = metrics["results"][metrics["model"]]["per_sequence"]
    store_data = load_store(tiny_store)
    assert len(scenes) == 3 * len(set(per_seq["category"]))
    for scene in scenes:
        sim = int(scene["title"].split("(sim ")[1].split(",")[0])
        i = per_seq["sim"].index(sim)
        final = np.asarray(scene["predicted"]["com_position"][-1]) - np.asarray(scene["reference"]["com_position"][-1])
        np.testing.assert_allclose(np.linalg.norm(final), per_seq["final.position_m"][i], atol=1e-5)
        np.testing.assert_allclose(scene["reference"]["com_position"], store_data.com_position[store_data.frames(sim)], atol=1e-6)
    # replaced without a viewer: the old page goes with the evaluation it showed
    proc = run_cli("test", "--checkpoint", tiny_checkpoint, "--data", tiny_store, "--out", str(out), "--overwrite", "--no-viewer")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert not (out / "viewer.html").exists() and (out / "metrics.json").is_file()
    bad = tmp_path / "bad.ckpt"
    torch.save({"weights": [1, 2]}, bad)
    proc = run_cli("test", "--checkpoint", str(bad), "--data", tiny_store, "--out", str(tmp_path / "x"))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a physdyn DynamicsModel checkpoint" in lines[0]


def test_the_torch_rollout_gives_the_reference_loops_numbers(tiny_checkpoint, store):
    # rollout_changes keeps the whole loop in torch; the step-by-step numpy loop is the reference.
    model = load_checkpoint(tiny_checkpoint)
    sims = select_sequences(store, "test")[:5]
    truth = gather_truth(store, sims)
    p0, q0, v0, w0 = _first_states(truth)
    points = store.points[store.shape_id[sims]][:, :64]
    warm = (truth["linear_velocity"][:, 1:3], truth["angular_velocity"][:, 1:3])
    for kwargs in ({}, {"warm_start_velocities": warm}):
        fast = rollout(model, points, q0, p0, v0, w0, 20, RolloutOptions(**kwargs))
        slow = rollout(model, points, q0, p0, v0, w0, 20, RolloutOptions(**kwargs, reference_loop=True))
        for key in ("com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability",
                    "fed_linear_velocity", *DELTA_KEYS):
            np.testing.assert_allclose(getattr(fast, key), getattr(slow, key), rtol=1e-5, atol=1e-5, err_msg=key)
    assert np.abs(fast.com_position[:, -1] - fast.com_position[:, 0]).max() > 1e-3  # it moved: not a trivial match


def test_fit_topple_puts_a_classifier_in_the_checkpoint_and_roll_outs_use_it(tiny_checkpoint, tiny_store, store, tmp_path, capsys):
    from physdyn.cli import main
    from physdyn.eval import metrics as M
    from physdyn.models.topple_classifier import store_features

    out = tmp_path / "topple.ckpt"
    assert main(["fit-topple", "--checkpoint", tiny_checkpoint, "--data", tiny_store, "--out", str(out)]) == 0
    assert "validation accuracy" in capsys.readouterr().out
    assert main(["fit-topple", "--checkpoint", tiny_checkpoint, "--out", str(out)]) == 2  # kept without --overwrite
    assert "already exists" in capsys.readouterr().err
    plain, model = load_pipeline(tiny_checkpoint), load_pipeline(out)
    assert plain.topple.registered_name == "head" and model.topple.registered_name == "logistic"
    clf = model.topple.classifier
    sims = select_sequences(store, "test")
    result = evaluate(model, store, "test", keep_trajectories=True)
    kept = result["trajectories"]
    # the roll-out's per-step probabilities are the classifier's: P(topples) x F(t), from the full cloud
    p = clf.probability(store_features(store, sims, None, clf.friction))
    np.testing.assert_allclose(kept["predicted"].topple_probability, clf.per_step(p, kept["truth"]["valid"].shape[1]), atol=1e-12)
    decided = M.predicted_topple(kept["predicted"].topple_probability, kept["truth"]["state_valid"])
    assert result["topple"]["accuracy"] == pytest.approx(np.mean(decided == store.toppled[sims].astype(bool)))
    # the trajectories themselves are the model's, unchanged (to float32 rounding: without the head's
    # probabilities the roll-out runs the network on the moving sequences only, smaller matrix products)
    np.testing.assert_allclose(kept["predicted"].com_position, evaluate(plain, store, "test", keep_trajectories=True)["trajectories"]["predicted"].com_position,
                               rtol=1e-5, atol=1e-7)


def test_fit_topple_physics_and_roll_outs_simulate_with_the_bodies_inertia(tiny_checkpoint, tiny_store, store, tmp_path, capsys):
    from physdyn.cli import main
    from physdyn.models.topple_classifier import store_features

    out = tmp_path / "topple_physics.ckpt"
    assert main(["fit-topple", "--checkpoint", tiny_checkpoint, "--data", tiny_store, "--physics", "--out", str(out)]) == 0
    assert "simulating the hull" in capsys.readouterr().out
    clf = load_pipeline(out).topple.classifier
    assert clf.physics
    sims = select_sequences(store, "test")
    kept = evaluate(str(out), store, "test", keep_trajectories=True)["trajectories"]
    # evaluate hands the classifier each body's own inertia (the store's), as fit-topple did
    p = clf.probability(store_features(store, sims, None, clf.friction, physics=True))
    np.testing.assert_allclose(kept["predicted"].topple_probability, clf.per_step(p, kept["truth"]["valid"].shape[1]), atol=1e-12)


def test_physdyn_test_with_cloud_sim_reports_the_simulator_on_the_cloud(tiny_checkpoint, tiny_store, tmp_path, capsys):
    import json

    from physdyn.cli import main

    assert main(["test", "--checkpoint", tiny_checkpoint, "--data", tiny_store, "--out", str(tmp_path / "rep"),
                 "--cloud-sim", "--no-viewer"]) == 0
    assert "evaluating cloud_sim" in capsys.readouterr().err
    metrics = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    sim, slide = metrics["results"]["cloud_sim"]["headline"], metrics["results"]["coulomb_slide"]["headline"]
    assert sim["final_position_m_median"] < slide["final_position_m_median"]
    assert any(line.startswith("| cloud_sim |") for line in (tmp_path / "rep" / "report.md").read_text().splitlines())


def test_sim_seconds_simulates_the_impact_then_the_networks_continue(tiny_checkpoint, store, tmp_path):
    # model.sim_seconds (an inference setting): the first steps are PyBullet's on the cloud's hull, with the
    # body's inertia, at the conventions' physics step; from there the networks' own changes, their LSTM
    # warmed up on the simulated velocities.
    from physdyn.config import PhysicsConfig
    from physdyn.data.windows import store_world_inertia
    from physdyn.geometry.rotations import quat_to_matrix
    from physdyn.models.export import export_checkpoint
    from physdyn.sim.cloud_body import CloudSimulator

    path = export_checkpoint(tiny_checkpoint, tmp_path / "sim.ckpt", settings=["model.sim_seconds=0.2"])
    plain, hybrid = load_checkpoint(tiny_checkpoint), load_checkpoint(path)
    k = round(0.2 * store.rate_hz)  # 3 steps at 15 Hz
    sims = select_sequences(store, "test")[:5]
    truth = gather_truth(store, sims, 20)
    p0, q0, v0, w0 = _first_states(truth)
    cloud = store.points[store.shape_id[sims]]
    points = cloud[:, :64]
    inertia = store_world_inertia(store, sims, q0)
    given = RolloutOptions(topple_points_body=cloud, body_inertia=inertia)
    got = rollout(hybrid, points, q0, p0, v0, w0, 20, given)
    with CloudSimulator(time_step=PhysicsConfig().time_step) as sim:
        R = quat_to_matrix(q0)
        expected = sim.trajectories(cloud, q0, p0, v0, w0, 0.25, k, store.rate_hz, np.swapaxes(R, 1, 2) @ inertia @ R)
    np.testing.assert_allclose(got.com_position[:, : k + 1], expected["com_position"], atol=1e-9)
    np.testing.assert_allclose(got.linear_velocity[:, : k + 1], expected["linear_velocity"], atol=1e-9)
    np.testing.assert_allclose(np.abs((got.orientation_xyzw[:, : k + 1] * expected["orientation_xyzw"]).sum(-1)), 1.0, atol=1e-9)
    # after step k: the network's changes, fed the simulated velocities and orientations as a warm start
    from physdyn.data.windows import relative_rotation

    turns = relative_rotation(q0, expected["orientation_xyzw"][:, 1:])
    warm = plain.rollout_changes(world_oriented_points(points, q0).astype(np.float32), v0, w0, 20,
                                 expected["linear_velocity"][:, 1:], expected["angular_velocity"][:, 1:], warm_turn=turns)
    for i, key in enumerate(DELTA_KEYS):
        np.testing.assert_allclose(getattr(got, key)[:, k:], warm["changes"][:, k:, 3 * i : 3 * i + 3].numpy(), atol=1e-6, err_msg=key)
    # fed the integrated orientation instead (the warm start of observed velocities), the networks differ
    blind = plain.rollout_changes(world_oriented_points(points, q0).astype(np.float32), v0, w0, 20,
                                  expected["linear_velocity"][:, 1:], expected["angular_velocity"][:, 1:])
    assert (blind["changes"] - warm["changes"])[:, k:].abs().max() > 1e-6
    # the reference loop gives the same roll-out, and a horizon within the simulated start ends on its state
    slow = rollout(hybrid, points, q0, p0, v0, w0, 20, RolloutOptions(topple_points_body=cloud, body_inertia=inertia, reference_loop=True))
    np.testing.assert_allclose(slow.com_position, got.com_position, atol=1e-6)
    short = rollout(hybrid, points, q0, p0, v0, w0, 2, given)
    np.testing.assert_allclose(short.linear_velocity[:, -1], expected["linear_velocity"][:, 2], atol=1e-9)
    np.testing.assert_allclose(short.angular_velocity[:, -1], expected["angular_velocity"][:, 2], atol=1e-9)
    again = integrate(p0, q0, v0, w0, got.deltas())  # the states are their changes' sum: one trajectory
    np.testing.assert_allclose(again["com_position"], got.com_position, atol=1e-9)
    # a caller's warm start (observed velocities) takes the place of the simulated start
    observed = (truth["linear_velocity"][:, 1:3], truth["angular_velocity"][:, 1:3])
    np.testing.assert_allclose(rollout(hybrid, points, q0, p0, v0, w0, 20, RolloutOptions(observed)).com_position,
                               rollout(plain, points, q0, p0, v0, w0, 20, RolloutOptions(observed)).com_position, atol=1e-9)
    # through evaluate and the public predictor, and 0 leaves a model as it was
    assert np.isfinite(evaluate(hybrid, store, "test")["headline"]["final_position_m_median"])
    import trimesh

    from physdyn.predict.predictor import load_predictor

    box = trimesh.creation.box(extents=[0.12, 0.08, 0.06])
    fast, slow_one = load_predictor(str(path)).predict_many([box, box], lin_vel=[[1.0, 0, 0], [0.6, 0.2, 0]],
                                                            ang_vel=[[0, 0, 3.0], [0, 0, 0]], seconds=1.0)
    one = load_predictor(str(path)).predict(box, lin_vel=[1.0, 0, 0], ang_vel=[0, 0, 3.0], seconds=1.0)
    np.testing.assert_allclose(np.asarray(fast["com_position"]), np.asarray(one["com_position"]), atol=1e-6)
    moved = np.asarray(one["com_position"])[-1, :2] - np.asarray(one["com_position"])[0, :2]
    assert 0.05 < np.linalg.norm(moved) < 0.3  # it slides: 1 m/s under mu g stops within 0.2 m
    from physdyn.eval.rollout import sim_steps

    hybrid.config.model.sim_seconds = 0.01  # less than a recorded step: still one, not silently none
    assert sim_steps(hybrid) == 1
    zero = load_checkpoint(export_checkpoint(path, tmp_path / "zero.ckpt", settings=["model.sim_seconds=0"]))
    assert sim_steps(zero) == 0
    np.testing.assert_allclose(rollout(zero, points, q0, p0, v0, w0, 20).com_position,
                               rollout(plain, points, q0, p0, v0, w0, 20).com_position, atol=1e-12)


def test_a_push_the_simulated_start_topples_is_reported_toppled(tiny_checkpoint, tiny_store, store):
    from physdyn.data.windows import store_world_inertia
    from physdyn.geometry.rotations import tilt_angle
    from physdyn.models.topple_classifier import fit_topple_classifier

    from physdyn.pipeline.engine import Pipeline
    from physdyn.pipeline.correction import NoCorrection
    from physdyn.pipeline.motion import NetworkMotion, SimulatedStartMotion
    from physdyn.pipeline.topple import LogisticTopple

    network = load_checkpoint(tiny_checkpoint)
    classifier = LogisticTopple(fit_topple_classifier(store)[0])
    model = Pipeline(NetworkMotion(network), classifier, NoCorrection())
    early = np.flatnonzero(store.toppled.astype(bool) & (store.topple_step >= 1) & (store.topple_step <= 4))
    calm = np.flatnonzero(~store.toppled.astype(bool))[:4]
    sims = np.concatenate([early[:4], calm])
    assert len(early) >= 2
    truth = gather_truth(store, sims, 12)
    p0, q0, v0, w0 = _first_states(truth)
    cloud, points = store.points[store.shape_id[sims]], store.points[store.shape_id[sims]][:, :64]
    inertia = store_world_inertia(store, sims, q0)
    given = RolloutOptions(topple_points_body=cloud, body_inertia=inertia)
    plain = rollout(model, points, q0, p0, v0, w0, 12, given)
    simulating = Pipeline(SimulatedStartMotion(network, 0.4), classifier, NoCorrection())  # 6 steps
    got = rollout(simulating, points, q0, p0, v0, w0, 12, given)
    tilt = np.degrees(tilt_angle(q0[:, None], got.orientation_xyzw[:, :7]))
    for b in range(len(sims)):
        over = np.flatnonzero(tilt[b] > 45)
        if len(over):  # toppled within the simulated start: certain from that step on, whatever the classifier said
            assert (got.topple_probability[b, over[0]:] == 1.0).all()
            np.testing.assert_allclose(got.topple_probability[b, : over[0]], plain.topple_probability[b, : over[0]])
        else:
            np.testing.assert_allclose(got.topple_probability[b], plain.topple_probability[b])
    assert (tilt[: len(early[:4])] > 45).any(axis=1).sum() >= 1  # the early topples do topple in the simulated start
