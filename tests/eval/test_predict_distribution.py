"""A distribution from a prediction: ``Predictor.predict_distribution`` and `physdyn predict --samples`.

The shipped default (``fast``, its ``calibrated`` distribution stage) and ``fast`` with the ``sampled_pushes``
stage on a small box mesh: zero uncertainty gives ``predict``'s trajectory for every sample, sampled pushes are
``predict_many``'s for the same pushes to the bit, the spread grows with the uncertainty, and the files (.npz,
.json) round-trip through the viewer."""

import contextlib
import dataclasses
import io
import json

import numpy as np
import pytest
import trimesh

from physdyn.cli import main as cli_main
from physdyn.pipeline.distribution import QUANTILE_LEVELS, sample_requests, summarise
from physdyn.predict.prediction_files import read_prediction
from physdyn.pipeline.spread import SampledPushes
from physdyn.predict.body import prepare_body
from physdyn.predict.predictor import Predictor, load_predictor
from physdyn.viz.viewer import read_viewer_data

LIN, ANG, SECONDS = [1.0, 0.2, 0.0], [0.0, 0.0, 3.0], 1.5


@pytest.fixture(scope="module")
def predictor():
    return load_predictor()


@pytest.fixture(scope="module")
def sampled(predictor):
    """``fast`` whose distribution rolls out sampled pushes."""
    return Predictor(dataclasses.replace(predictor.model, distribution=SampledPushes()), name="fast")


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "box.obj"
    trimesh.creation.box(extents=(0.12, 0.08, 0.05)).export(path)
    return path


def cli(*argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("stage", ["calibrated", "sampled_pushes"])
def test_zero_uncertainty_gives_predicts_trajectory_for_every_sample(predictor, sampled, mesh_file, stage):
    model = predictor if stage == "calibrated" else sampled
    dist = model.predict_distribution(mesh_file, LIN, ANG, SECONDS, uncertainty="none", samples=4)
    one = predictor.predict(mesh_file, LIN, ANG, SECONDS)
    assert dist["distribution"] == stage
    for s in range(4):
        np.testing.assert_allclose(dist["com_position"][s], one["com_position"], atol=1e-6)
        np.testing.assert_allclose(dist["orientation_xyzw"][s], one["orientation_xyzw"], atol=1e-6)
    np.testing.assert_allclose(dist["topple_probability"], np.maximum.accumulate(one["topple_probability"]), atol=1e-6)
    assert (dist["toppled"] == one["toppled"]).all()
    if stage == "sampled_pushes":
        np.testing.assert_array_equal(dist["sample_lin_vel"], np.tile(LIN, (4, 1)))


def test_sampled_pushes_are_predict_manys_trajectories_to_the_bit(sampled, mesh_file):
    dist = sampled.predict_distribution(mesh_file, LIN, ANG, SECONDS, samples=8, seed=3)
    # the contact prior takes friction, so the pushes' frictions are drawn too
    assert dist["sample_friction"].std() > 0 and abs(dist["sample_friction"].mean() - sampled.own_friction) < 0.03
    body = prepare_body(mesh_file)
    predictor = sampled
    many = predictor.predict_many([body.with_friction(mu) for mu in dist["sample_friction"]], dist["sample_lin_vel"],
                                  dist["sample_ang_vel"], SECONDS)
    for s, result in enumerate(many):
        np.testing.assert_array_equal(dist["com_position"][s], result["com_position"])
        np.testing.assert_array_equal(dist["orientation_xyzw"][s], result["orientation_xyzw"])
        assert dist["toppled"][s] == result["toppled"]


@pytest.mark.parametrize("stage", ["calibrated", "sampled_pushes"])
def test_keys_shapes_and_a_spread_that_grows_with_the_uncertainty(predictor, sampled, mesh_file, stage):
    predictor = predictor if stage == "calibrated" else sampled
    N, T = 16, predictor.num_steps(SECONDS)
    spread = {}
    for level in ("low", "default", {"speed_rel": 0.2, "direction_deg": 20.0}):
        dist = predictor.predict_distribution(mesh_file, LIN, ANG, SECONDS, uncertainty=level, samples=N)
        spread[str(level)] = float(np.linalg.norm(dist["region_90"]["semi_axes"]))
    assert dist["com_position"].shape == (N, T, 3) and dist["orientation_xyzw"].shape == (N, T, 4)
    assert dist["time"].shape == (T,) and dist["topple_probability"].shape == (T,)
    assert dist["final_position_mean"].shape == (3,) and set(dist["final_position_quantiles"]) == set(QUANTILE_LEVELS)
    assert set(dist["turn_deg_quantiles"]) == set(QUANTILE_LEVELS) and np.isfinite(dist["turn_deg_mean"])
    assert dist["region_50"]["semi_axes"].shape == (2,) and dist["samples"] == N and dist["checkpoint"] == "fast"
    assert dist["uncertainty"]["speed_rel"] == 0.2 and dist["uncertainty"]["spin_abs"] == 0.3  # the rest: default
    assert not np.allclose(dist["com_position"][0], dist["com_position"][1])
    assert spread["low"] < spread["default"] < spread[str({"speed_rel": 0.2, "direction_deg": 20.0})]
    p = dist["topple_probability"]
    assert (np.diff(p) >= 0).all() and (p >= 0).all() and (p <= 1).all()


def test_summarise_counts_toppled_samples_and_never_decreases():
    rng = np.random.default_rng(0)
    N, T = 10, 6
    p = np.cumsum(rng.normal(size=(N, T, 3)), axis=1)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (N, T, 1))
    toppled = np.zeros((N, T), bool)
    toppled[:3, 2] = True  # three samples topple at step 2 (and a label that flickers back is still toppled)
    out = summarise(p, q, toppled)
    np.testing.assert_allclose(out["topple_probability"], [0, 0, 0.3, 0.3, 0.3, 0.3])
    np.testing.assert_allclose(out["final_position_mean"], p[:, -1].mean(axis=0))
    np.testing.assert_allclose(out["final_position_quantiles"][50], np.median(p[:, -1], axis=0))
    assert out["turn_deg_mean"] == 0.0
    lin, ang, mu = sample_requests(LIN, ANG, [0.5], "default", 5, seed=1)
    assert lin.shape == (1, 5, 3) and ang.shape == (1, 5, 3) and mu.shape == (1, 5)
    again = sample_requests(LIN, ANG, None, "default", 5, seed=1)
    np.testing.assert_array_equal(again[0], lin)
    assert again[2] is None


@pytest.mark.parametrize("flags", [["--speed-sd", "-0.1"], ["--direction-sd-deg", "nan"], ["--spin-sd-abs", "1e9"],
                                   ["--uncertainty", "wild"], ["--samples", "0"]])
def test_a_bad_uncertainty_is_one_line_exit_2_and_nothing_written(mesh_file, tmp_path, flags):
    out = tmp_path / "d.npz"
    argv = ["predict", mesh_file, "--lin-vel", *LIN, "--ang-vel", *ANG, "--out", out, "--plot", tmp_path / "d.png"]
    argv += flags if "--samples" in flags else ["--samples", "8", *flags]
    code, _, err = cli(*argv)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "error" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("ext", [".npz", ".json"])
def test_samples_output_round_trips_through_the_viewer(mesh_file, tmp_path, ext):
    out = tmp_path / f"d{ext}"
    code, text, _ = cli("predict", mesh_file, "--lin-vel", *LIN, "--ang-vel", *ANG, "--seconds", SECONDS,
                        "--samples", 6, "--out", out, "--plot", tmp_path / "d.png")
    assert code == 0 and "topple probability" in text and (tmp_path / "d.png").stat().st_size > 0
    dist = read_prediction(out)
    assert dist["kind"] == "distribution" and dist["com_position"].shape[0] == 6
    code, _, _ = cli("view", out, "--out", tmp_path / "page.html")
    assert code == 0
    scene = read_viewer_data(tmp_path / "page.html")["scenes"][0]
    np.testing.assert_allclose(scene["fan"]["com_position"], dist["com_position"], atol=1e-6)
    np.testing.assert_allclose(scene["predicted"]["topple_probability"], dist["topple_probability"], atol=1e-6)


def test_batch_lines_with_samples(mesh_file, tmp_path):
    requests = tmp_path / "requests.jsonl"
    line = {"mesh": str(mesh_file), "lin_vel": LIN, "ang_vel": ANG, "seconds": SECONDS}
    requests.write_text("\n".join(json.dumps(r) for r in [
        {**line, "samples": 5, "uncertainty": {"speed_rel": 0.05}, "seed": 2, "out": "a.npz"},
        {**line, "out": "b.json"},
        {**line, "samples": 5, "uncertainty": {"speed_rel": -1}, "out": "c.npz"},
    ]) + "\n")
    code, _, err = cli("predict", "--batch", requests, "--out-dir", tmp_path / "out")
    assert code == 2 and "line 3" in err and "speed_rel" in err
    dist = read_prediction(tmp_path / "out" / "a.npz")
    assert dist["com_position"].shape[0] == 5 and dist["uncertainty"]["speed_rel"] == 0.05 and dist["seed"] == 2
    assert read_prediction(tmp_path / "out" / "b.json")["com_position"].ndim == 2
    assert not (tmp_path / "out" / "c.npz").exists()
