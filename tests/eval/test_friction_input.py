"""Friction as an input of a prediction: ``PreparedBody.with_friction``, `physdyn predict --friction`, a batch
line's "friction", and `physdyn test` on a store simulated at random frictions. The contact prior (``fast``,
``contact_prior``) slides at the given friction; other models refuse it with one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from physdyn.data.store import load_store
from physdyn.errors import PredictionError
from physdyn.eval.evaluate import evaluate
from physdyn.pipeline.presets import load_pipeline
from physdyn.predict.body import prepare_body
from physdyn.predict.predictor import load_predictor
from tests.eval.test_distribution_eval import TINY
from tests.eval.test_predict_distribution import cli

LIN, ANG = [1.2, 0.0, 0.0], [0.0, 0.0, 2.0]


@pytest.fixture(scope="module")
def fast():
    return load_predictor("fast")


@pytest.fixture(scope="module")
def box():
    return prepare_body(trimesh.creation.box(extents=(0.12, 0.08, 0.05)))


def final_xy(result) -> np.ndarray:
    return result["com_position"][-1, :2] - result["com_position"][0, :2]


def test_the_models_own_friction_gives_its_prediction(fast, box):
    plain = fast.predict(box, LIN, ANG)
    own = fast.predict(box.with_friction(fast.own_friction), LIN, ANG)
    assert fast.own_friction == pytest.approx(0.25)
    np.testing.assert_allclose(own["com_position"], plain["com_position"], atol=1e-6)
    np.testing.assert_allclose(own["orientation_xyzw"], plain["orientation_xyzw"], atol=1e-6)


def test_the_prediction_follows_pybullet_at_the_given_friction(fast, box):
    default = fast.predict(box, LIN, ANG)
    for mu in (0.1, 0.5):
        given = fast.predict(box.with_friction(mu), LIN, ANG, compare_sim=True)
        truth = final_xy(given["simulated"])
        # the simulator's friction is the given one too: farther on less friction, shorter on more
        assert (np.linalg.norm(truth) > np.linalg.norm(final_xy(default))) == (mu < 0.25)
        assert np.linalg.norm(final_xy(given) - truth) < 0.5 * np.linalg.norm(final_xy(default) - truth)


def test_a_batch_takes_a_friction_per_request(fast, box):
    mus = [0.1, None, 0.4]
    many = fast.predict_many([box.with_friction(mu) for mu in mus], LIN, ANG)
    for mu, result in zip(mus, many):
        one = fast.predict(box.with_friction(mu), LIN, ANG)
        np.testing.assert_allclose(result["com_position"], one["com_position"], atol=1e-6)
    assert final_xy(many[0])[0] > final_xy(many[1])[0] > final_xy(many[2])[0]


def test_a_model_that_takes_no_friction_refuses_it(box):
    bundled = load_predictor("bundled")
    with pytest.raises(PredictionError, match="predicts at the friction it was trained at"):
        bundled.predict(box.with_friction(0.4), LIN, ANG)
    for bad in (0.0, -0.2, float("nan"), 7.0, "0.3"):
        with pytest.raises(PredictionError, match="friction must be"):
            box.with_friction(bad)


@pytest.mark.parametrize("flags", [["--friction", "-0.1"], ["--friction", "nan"],
                                   ["--friction", "0.4", "--checkpoint", "bundled"]])
def test_a_bad_friction_is_one_line_exit_2_and_nothing_written(tmp_path, flags):
    mesh = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.12, 0.08, 0.05)).export(mesh)
    code, _, err = cli("predict", mesh, "--lin-vel", *LIN, "--ang-vel", *ANG, "--out", tmp_path / "p.json", *flags)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "friction" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.obj"]


def test_the_command_line_and_a_batch_line_take_friction(tmp_path):
    mesh = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.12, 0.08, 0.05)).export(mesh)
    code, _, err = cli("predict", mesh, "--lin-vel", *LIN, "--ang-vel", *ANG, "--friction", 0.1, "--out", tmp_path / "a.json")
    assert code == 0, err
    requests = tmp_path / "r.jsonl"
    requests.write_text(json.dumps({"mesh": "box.obj", "lin_vel": LIN, "ang_vel": ANG, "friction": 0.1, "out": "b.json"}) + "\n"
                        + json.dumps({"mesh": "box.obj", "lin_vel": LIN, "ang_vel": ANG, "out": "c.json"}) + "\n")
    code, _, err = cli("predict", "--batch", requests, "--out-dir", tmp_path / "out")
    assert code == 0, err
    # --friction is every line's default, as the line's own "friction" is its own
    code, _, err = cli("predict", "--batch", requests, "--out-dir", tmp_path / "low", "--friction", 0.1)
    assert code == 0, err
    low = json.loads((tmp_path / "low" / "c.json").read_text())
    a, b, c = (json.loads(p.read_text()) for p in (tmp_path / "a.json", tmp_path / "out" / "b.json", tmp_path / "out" / "c.json"))
    np.testing.assert_allclose(a["com_position"], b["com_position"], atol=1e-6)
    assert a["com_position"][-1][0] > c["com_position"][-1][0] + 0.05  # less friction, a longer slide
    np.testing.assert_allclose(low["com_position"], a["com_position"], atol=1e-6)


def test_physdyn_test_rolls_out_at_each_simulations_friction(tmp_path):
    from physdyn.config import DataConfig, load_config
    from physdyn.data.simulated_store import generate_dataset
    from tests.conftest import REPO

    cfg = load_config(DataConfig, REPO / "configs" / "data" / "primitives.yaml",
                      TINY + ["ensemble.members=0", "friction.random=true", "friction.min=0.1", "friction.max=0.5",
                              "split.test_fraction=0.9", "split.val_fraction=0.0"])
    generate_dataset(cfg, str(tmp_path / "f.zarr"), workers=1, progress=False)
    store = load_store(str(tmp_path / "f.zarr"))
    assert np.ptp(store.friction) > 0.1
    pipeline = load_pipeline("contact_prior")
    given = evaluate(pipeline, store)["per_sequence"]
    pipeline.motion.takes_friction = False  # the same prior at its own friction, for comparison
    own = evaluate(pipeline, store)["per_sequence"]
    key = next(k for k in given if k.startswith("final.") and "position" in k)
    assert np.median(given[key]) < np.median(own[key])
