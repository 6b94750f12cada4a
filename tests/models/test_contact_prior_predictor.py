"""The contact prior alone as a predictor (``model.predictor: none``, ``contact_prior_predictor``): what the
planner screens with. Real roll-outs of a box against Coulomb's law."""

import math
import warnings

import numpy as np
import pytest
import trimesh

from physdyn.predict.predictor import contact_prior_predictor
from physdyn.registry import PREDICTORS


@pytest.fixture(scope="module")
def prior():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return contact_prior_predictor()


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box((0.12, 0.08, 0.05))


def test_none_is_a_registered_predictor_with_no_features():
    import torch

    net = PREDICTORS.build("none", {}, "model.predictor.params", input_dim=22)
    features, state = net(torch.zeros(3, 5, 22))
    assert features.shape == (3, 5, 0) and state is None and not list(net.parameters())


def test_a_slide_without_spin_stops_where_coulomb_friction_stops_it(prior, box):
    mu_g = 0.25 * 9.81
    result = prior.predict(box, [1.2, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=1.0)
    distance = result["com_position"][-1, 0] - result["com_position"][0, 0]
    # Coulomb's v^2 / (2 mu g), less the half sub-step the prior's semi-implicit Euler loses (1/240 s sub-steps)
    assert distance == pytest.approx(1.2**2 / (2 * mu_g) - 1.2 * (1 / 240) / 2, abs=5e-4)
    assert np.abs(result["com_position"][-1, 1:] - result["com_position"][0, 1:]).max() < 1e-6
    np.testing.assert_allclose(result["linear_velocity"][-1], 0.0, atol=1e-6)
    assert result["topple_probability"] is None and not result["toppled"]  # it never topples


def test_a_spinning_slide_goes_farther_turns_with_its_spin_and_both_stop_together(prior, box):
    still = prior.predict(box, [1.2, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=1.0)
    spun = prior.predict(box, [1.2, 0.0, 0.0], [0.0, 0.0, 8.0], seconds=1.0)
    # friction over a spinning footprint points partly across the travel, so less of it slows the slide
    travel = lambda r: np.linalg.norm(r["com_position"][-1, :2] - r["com_position"][0, :2])  # noqa: E731
    assert travel(spun) > travel(still) + 0.01
    q = spun["orientation_xyzw"][-1]
    yaw = 2 * math.atan2(q[2], q[3])
    assert yaw > 0.3  # counter-clockwise, as the spin
    np.testing.assert_allclose(spun["linear_velocity"][-1], 0.0, atol=1e-6)
    np.testing.assert_allclose(spun["angular_velocity"][-1], 0.0, atol=1e-6)


def test_its_roll_outs_are_batched_as_one_requests(prior, box):
    v = np.array([[1.0, 0.2, 0.0], [0.6, -0.5, 0.0], [1.5, 0.0, 0.0]])
    w = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, -6.0], [0.0, 0.0, 0.0]])
    many = prior.predict_many([box] * 3, v, w, seconds=1.2)
    for i in range(3):
        one = prior.predict(box, v[i], w[i], seconds=1.2)
        np.testing.assert_allclose(many[i]["com_position"], one["com_position"], atol=1e-5)
        np.testing.assert_allclose(many[i]["orientation_xyzw"], one["orientation_xyzw"], atol=1e-5)


def test_no_network_reads_the_shape_feature_so_the_encoder_is_not_run(box, monkeypatch):
    # The encoder's output would feed a network the prior alone does not have: skipping it changes no number.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prior = contact_prior_predictor()
    ran = []
    monkeypatch.setattr(prior.model.network.predictor, "out_dim", 1)  # as if a network read it: the encoder runs
    monkeypatch.setattr(prior.model.network.encoder, "forward", lambda *a, _f=prior.model.network.encoder.forward: ran.append(1) or _f(*a))
    before = prior.predict(box, [1.0, 0.3, 0.0], [0.0, 0.0, 6.0], seconds=1.0)
    assert ran

    def refuse(*args, **kwargs):
        raise AssertionError("the encoder ran")

    monkeypatch.setattr(prior.model.network.predictor, "out_dim", 0)
    monkeypatch.setattr(prior.model.network.encoder, "forward", refuse)
    after = prior.predict(box, [1.0, 0.3, 0.0], [0.0, 0.0, 6.0], seconds=1.0)
    np.testing.assert_array_equal(after["com_position"], before["com_position"])
    np.testing.assert_array_equal(after["orientation_xyzw"], before["orientation_xyzw"])


def test_half_the_sub_steps_integrate_the_same_slide_and_spin_within_two_percent(prior, box):
    # model.contact_substeps (the fast model's 8): the same friction integrated more coarsely (its
    # semi-implicit Euler loses about half a sub-step of travel: 2 mm of a 29 cm slide at 1.2 m/s)
    coarse = contact_prior_predictor()
    coarse.model.network.config.model.contact_substeps = 8
    for v, w in (([1.2, 0.0, 0.0], [0.0, 0.0, 0.0]), ([1.0, 0.3, 0.0], [0.0, 0.0, 8.0])):
        fine, half = (p.predict(box, v, w, seconds=1.5) for p in (prior, coarse))
        gap = np.linalg.norm(fine["com_position"][-1] - half["com_position"][-1])
        travel = np.linalg.norm(fine["com_position"][-1] - fine["com_position"][0])
        assert 0.0 < gap < 0.02 * travel
        turn = [2 * math.atan2(r["orientation_xyzw"][-1, 2], r["orientation_xyzw"][-1, 3]) for r in (fine, half)]
        assert abs(turn[0] - turn[1]) <= 0.02 * abs(turn[0])



def test_a_broken_preset_is_refused_with_the_key_that_training_would_name(tmp_path, monkeypatch):
    import shutil

    import yaml

    from physdyn import config
    from physdyn.errors import ConfigError

    shutil.copytree(config.PRESETS, tmp_path / "configs")
    preset = tmp_path / "configs" / "experiment" / "contact_prior.yaml"
    raw = yaml.safe_load(preset.read_text())
    raw["model"]["contact_substeps"] = 0  # the schema takes any int; only the config check refuses it
    preset.write_text(yaml.safe_dump(raw))
    monkeypatch.setattr(config, "PRESETS", tmp_path / "configs")
    with pytest.raises(ConfigError, match="model.contact_substeps"):
        contact_prior_predictor()
