"""`physdyn test` on an ensemble store: the distribution forecast's proper scores beside their floors, equal to
``score_pushes`` on the very samples, and nothing of the kind on a store without an ensemble."""

from __future__ import annotations

import json

import numpy as np
import pytest

from physdyn.cli import main
from physdyn.config import DataConfig, load_config
from physdyn.data.simulated_store import generate_dataset
from physdyn.data.store import load_store
from physdyn.eval.distribution_eval import SCORE_KEYS, evaluate_distribution
from physdyn.eval.evaluate import evaluate
from physdyn.eval.scores import score_pushes
from physdyn.pipeline.distribution import sample_requests
from physdyn.pipeline.presets import load_pipeline
from tests.conftest import REPO

# 3 primitives (one of them in the test split), 3 pushes each, 4 members of 1.5 s: about 2 s of simulation.
TINY = ["families.primitives.shapes=3", "families.primitives.sims_per_shape=3", "shapes_per_block=3", "num_points=64",
        "physics.max_duration=2.0", "ensemble.seconds=1.5"]


def tiny_store(folder, members: int) -> str:
    cfg = load_config(DataConfig, REPO / "configs" / "data" / "primitives.yaml", TINY + [f"ensemble.members={members}"])
    generate_dataset(cfg, str(folder), workers=1, progress=False)
    return str(folder)


@pytest.fixture(scope="module")
def ensemble_store(tmp_path_factory) -> str:
    return tiny_store(tmp_path_factory.mktemp("ensemble") / "e.zarr", members=4)


def test_physdyn_test_scores_the_samples_against_the_members(ensemble_store, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["test", "--checkpoint", "contact_prior", "--data", ensemble_store, "--samples", "8", "--out", str(out),
                 "--no-viewer"]) == 0
    assert "distribution (sampled_pushes) of 8 samples" in capsys.readouterr().out
    block = json.loads((out / "metrics.json").read_text())["distribution"]
    assert block["samples"] == 8 and block["members"] == 4 and block["uncertainty_source"] == "store"
    # the contact prior takes friction, so its sampled pushes draw it: the report says so
    assert block["distribution"] == "sampled_pushes" and block["friction_varied"] is True
    assert "sampled_pushes distribution stage" in (out / "report.md").read_text()
    assert set(SCORE_KEYS) <= set(block["forecast"]) and block["deterministic"]["coverage_90"] is None
    assert (out / "topple_reliability.png").read_bytes()[:4] == b"\x89PNG"
    table = [line for line in (out / "report.md").read_text().splitlines() if line.startswith("| contact_prior, ")]
    assert len(table) == 2 and "8 samples" in table[0] and "topple_reliability.png" in (out / "report.md").read_text()

    # the same forecast again, its samples kept, scored here from the store's own arrays
    store = load_store(ensemble_store)
    result = evaluate_distribution(load_pipeline("contact_prior"), store, samples=8, keep_samples=True)
    samples, sims = result["trajectories"]["forecast"], result["trajectories"]["sims"]
    np.testing.assert_array_equal(sims, np.flatnonzero(store.split == 2))
    first = store.start[sims]
    lin, ang, _ = sample_requests(store.linear_velocity[first], store.angular_velocity[first], None, "default", 8, 0)
    np.testing.assert_array_equal(samples["lin_vel0"], lin)
    members_p = store.extra["ensemble/com_position"][sims]  # (P, K, T, 3)
    members_q = store.extra["ensemble/orientation_xyzw"][sims]
    # both start from the push's recorded step-0 orientation: final orientations compare as they are
    np.testing.assert_allclose(samples["orientation_xyzw"][:, :, 0], np.repeat(store.orientation_xyzw[first][:, None], 8, 1))
    np.testing.assert_allclose(members_q[:, :, 0], np.repeat(store.orientation_xyzw[first][:, None], 4, 1), atol=1e-12)
    assert samples["com_position"].shape[2] == members_p.shape[2]
    p = samples["com_position"]
    direct = score_pushes(p[:, :, -1, :2] - p[:, :, 0, :2], members_p[:, :, -1, :2] - members_p[:, :, 0, :2],
                          samples["orientation_xyzw"][:, :, -1], members_q[:, :, -1], samples["topple_probability"],
                          store.extra["ensemble/topple_label"][sims].any(axis=-1))
    for key, value in direct.mean.items():
        assert block["forecast"][key] == pytest.approx(value, rel=1e-12, abs=1e-12), key
    assert block["forecast"]["position_floor_cm"] < block["forecast"]["position_es_cm"]

    # replaced without the distribution: no block, and the old diagram is gone
    assert main(["test", "--checkpoint", "contact_prior", "--data", ensemble_store, "--out", str(out), "--no-viewer",
                 "--no-distribution", "--overwrite"]) == 0
    assert "distribution" not in json.loads((out / "metrics.json").read_text())
    assert not (out / "topple_reliability.png").exists()


def test_one_exact_sample_scores_its_mean_distance_to_the_members(ensemble_store):
    store = load_store(ensemble_store)
    pipeline = load_pipeline("contact_prior")
    result = evaluate_distribution(pipeline, store, samples=1, uncertainty="none", keep_samples=True)
    assert result["forecast"] == result["deterministic"] and result["forecast"]["coverage_50"] is None
    # the deterministic final position, read off `physdyn test`'s own roll-out of each push (a roll-out is causal)
    rolled = evaluate(pipeline, store, keep_trajectories=True)["trajectories"]
    T = store.extra["ensemble/com_position"].shape[2]
    assert rolled["predicted"].com_position.shape[1] >= T
    final = rolled["predicted"].com_position[:, T - 1, :2] - rolled["predicted"].com_position[:, 0, :2]
    members = store.extra["ensemble/com_position"][rolled["sims"]]
    members = members[:, :, -1, :2] - members[:, :, 0, :2]
    by_hand = [100 * np.mean([np.hypot(*(final[p] - y)) for y in members[p]]) for p in range(len(final))]
    np.testing.assert_allclose(result["per_push"]["forecast.position_es_cm"], by_hand, rtol=1e-9)
    assert result["forecast"]["position_es_cm"] == pytest.approx(np.mean(by_hand), rel=1e-9)


def test_a_store_without_an_ensemble_has_no_distribution_scores(tmp_path, capsys):
    plain = tiny_store(tmp_path / "plain.zarr", members=0)
    assert evaluate_distribution(load_pipeline("contact_prior"), plain) is None
    out = tmp_path / "report"
    assert main(["test", "--checkpoint", "contact_prior", "--data", plain, "--out", str(out), "--no-viewer",
                 "--samples", "8"]) == 0
    assert "holds no ensemble" in capsys.readouterr().err  # asked for, so said why not
    assert "distribution" not in json.loads((out / "metrics.json").read_text())
    assert not (out / "topple_reliability.png").exists() and "Distribution" not in (out / "report.md").read_text()


@pytest.mark.parametrize("flags, message", [(["--samples", "0"], "samples"), (["--uncertainty", "loud"], "--uncertainty")])
def test_bad_distribution_flags_are_one_line_and_write_nothing(flags, message, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["test", "--checkpoint", "contact_prior", "--data", str(tmp_path / "none.zarr"), "--out", str(out),
                 *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()
