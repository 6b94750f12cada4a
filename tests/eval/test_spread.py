"""The ``calibrated`` distribution stage: its samples follow the laws it was given, its fit recovers laws from
data drawn from them, and `physdyn fit-spread` writes a preset that predicts and tests, or refuses bad input
with one line and writes nothing."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from physdyn.config.uncertainty import resolve_uncertainty
from physdyn.errors import ConfigError
from physdyn.geometry.rotations import turn_about_vertical
from physdyn.pipeline.presets import load_pipeline
from physdyn.pipeline.spread import CalibratedSpread, heading_turn, outcome_frame, push_scale
from physdyn.pipeline.spread_fit import fit_spread, spread_coverage
from tests.eval.test_distribution_eval import tiny_store
from tests.eval.test_predict_distribution import cli

LAWS = CalibratedSpread.Config(push=[[-3.0, 1.0, 0.0], [-3.5, 1.0, 0.0], [-2.0, 0.0, 0.5]],
                               model=[[-4.0, 0.0, 0.0], [-4.5, 0.5, 0.0], [-2.5, 0.0, 0.3]],
                               toppled=[[-1.5, 0.0, 0.0], [-2.0, 0.0, 0.0]])


def nominal_slide(P: int = 3, T: int = 31) -> dict[str, np.ndarray]:
    """P pushes sliding along +x by 0.1, 0.2, 0.3 m and turning by 0.2, 0.4, 0.6 rad, decelerating."""
    t = np.linspace(0.0, 1.0, T)
    ease = 1.0 - (1.0 - t) ** 2
    p = np.zeros((P, T, 3))
    p[..., 0] = 0.1 * np.arange(1, P + 1)[:, None] * ease
    p[..., 2] = 0.05
    q = turn_about_vertical(0.2 * np.arange(1, P + 1)[:, None] * ease, np.array([0.0, 0.0, 0.0, 1.0]))
    topple = np.zeros((P, T))
    topple[1, T // 2 :] = 0.3
    return {"com_position": p, "orientation_xyzw": q, "topple_by_step": topple}


def test_samples_follow_the_laws_along_the_path():
    stage = CalibratedSpread(LAWS)
    nominal = nominal_slide()
    lin = np.array([[1.0, 0.0, 0.0]] * 3)
    out = stage.spread(nominal, lin, np.zeros((3, 3)), resolve_uncertainty("default"), 20000, np.random.default_rng(0))
    p, q, toppled = out["com_position"], out["orientation_xyzw"], out["toppled"]
    assert p.shape == (3, 20000, 31, 3) and q.shape == (3, 20000, 31, 4)
    np.testing.assert_allclose(p[:, :, 0], np.repeat(nominal["com_position"][:, None, 0], 20000, axis=1))
    # a toppled draw for push 1 as often as its topple probability, none for the others
    assert toppled[[0, 2]].sum() == 0 and abs(toppled[1].mean() - 0.3) < 0.02
    frame = outcome_frame(nominal["com_position"], nominal["orientation_xyzw"], lin)
    want = stage.sigmas(frame["features"], push_scale(resolve_uncertainty("default")))
    upright = ~toppled
    end = p[:, :, -1, :2] - nominal["com_position"][:, None, -1, :2]
    turn = heading_turn(q.reshape(-1, 31, 4)).reshape(3, 20000, 31)[..., -1] - frame["turn"][:, None]
    for b in range(3):
        got = [end[b, upright[b], 0].std(), end[b, upright[b], 1].std(), turn[b, upright[b]].std()]
        np.testing.assert_allclose(got, want[b], rtol=0.03)
    # a toppled draw ends by the toppled law
    np.testing.assert_allclose(end[1, toppled[1], 0].std(), np.exp(frame["features"][1] @ stage.toppled[0]), rtol=0.05)
    # halfway along the path (by distance), half the offset
    travelled = np.abs(nominal["com_position"][0, :, 0] - nominal["com_position"][0, 0, 0])
    mid = int(np.argmin(np.abs(travelled - travelled[-1] / 2)))
    ratio = (p[0, :, mid, 1] - nominal["com_position"][0, mid, 1]) / end[0, :, 1]
    np.testing.assert_allclose(ratio, travelled[mid] / travelled[-1], atol=1e-9)


def test_a_wider_uncertainty_spreads_the_push_part_only():
    stage = CalibratedSpread(LAWS)
    features = outcome_frame(nominal_slide()["com_position"], nominal_slide()["orientation_xyzw"], np.eye(3))["features"]
    low, default = (stage.sigmas(features, push_scale(resolve_uncertainty(u))) for u in ("low", "default"))
    model_only = np.exp(features @ stage.model.T)
    assert (low < default).all() and (low > model_only).all()
    np.testing.assert_allclose(push_scale(resolve_uncertainty("low")), [1 / 3] * 3)


def test_the_fit_recovers_laws_from_data_drawn_from_them():
    rng = np.random.default_rng(1)
    P, K = 3000, 12
    travel, turn = np.exp(rng.uniform(np.log(0.02), np.log(0.6), P)), np.exp(rng.uniform(np.log(0.01), np.log(2), P))
    features = np.stack([np.ones(P), np.log(travel + 0.01), np.log(turn + 0.05)], axis=1)
    truth = CalibratedSpread(LAWS)
    push = np.exp(features @ truth.push.T)
    model = np.exp(features @ truth.model.T)
    upright = rng.random((P, K)) > 0.1
    residual = model[:, None] * rng.standard_normal((P, 1, 3)) + push[:, None] * rng.standard_normal((P, K, 3))
    residual[..., :2] = np.where(upright[..., None], residual[..., :2],
                                 np.exp(features @ truth.toppled.T)[:, None] * rng.standard_normal((P, K, 2)))
    data = {"features": features, "residual": residual, "upright": upright, "scale": np.ones(3)}
    fitted = CalibratedSpread(fit_spread([data], "synthetic"))
    np.testing.assert_allclose(fitted.push, truth.push, atol=0.06)
    # the model's part rides on the push's, and few members topple: compared where they matter, as standard deviations
    np.testing.assert_allclose(np.exp(features @ fitted.toppled.T), np.exp(features @ truth.toppled.T), rtol=0.1)
    np.testing.assert_allclose(np.exp(features @ fitted.model.T), model, rtol=0.25)
    np.testing.assert_allclose(spread_coverage(fitted, data), 0.9, atol=0.015)


def test_outside_the_fitted_range_the_spread_is_the_edges():
    # a spin in place barely travels: its spread is that of the least travel the laws were fitted on, not a power
    # law's extrapolation (which grows without bound as travel goes to zero with a negative power)
    laws = CalibratedSpread.Config(push=LAWS.push, model=[[-4.0, -1.0, 1.0], [-4.5, 0.5, 0.0], [-2.5, 0.0, 0.3]],
                                   toppled=LAWS.toppled, travel_range=[0.05, 0.8], turn_range=[0.05, 6.0])
    stage = CalibratedSpread(laws)
    scale = push_scale(resolve_uncertainty("default"))
    features = lambda travel, turn: np.array([[1.0, np.log(travel + 0.01), np.log(turn + 0.05)]])  # noqa: E731
    np.testing.assert_allclose(stage.sigmas(features(0.001, 30.0), scale), stage.sigmas(features(0.05, 6.0), scale))
    np.testing.assert_allclose(stage.toppled_sigmas(features(5.0, 0.0)), stage.toppled_sigmas(features(0.8, 0.05)))
    inside = stage.sigmas(features(0.3, 1.0), scale)
    assert not np.allclose(inside, stage.sigmas(features(0.05, 6.0), scale))


def test_the_fit_refuses_stores_that_cannot_say_the_spread():
    from physdyn.errors import PhysdynError

    rng = np.random.default_rng(2)
    features = np.stack([np.ones(200), rng.uniform(-4, 0, 200), rng.uniform(-3, 1, 200)], axis=1)
    data = {"features": features, "residual": rng.standard_normal((200, 8, 3)) * 0.01, "upright": np.ones((200, 8), bool),
            "scale": np.ones(3)}
    with pytest.raises(PhysdynError, match="zero uncertainty"):
        fit_spread([{**data, "scale": np.array([1.0, 0.0, 1.0])}])
    with pytest.raises(PhysdynError, match="too few"):
        fit_spread([{**data, "upright": np.zeros((200, 8), bool)}])
    fitted = fit_spread([data])  # all upright: where a toppled sample ends falls back to a law of the upright ones
    assert np.isfinite(np.asarray(fitted.toppled)).all() and fitted.travel_range[0] <= fitted.travel_range[1]


def test_bad_coefficients_are_a_one_line_config_error():
    with pytest.raises(ConfigError, match="distribution.params.model: 3 rows"):
        CalibratedSpread(CalibratedSpread.Config(model=[[1.0, 2.0]]))
    with pytest.raises(ConfigError, match="distribution.params.push"):
        CalibratedSpread(CalibratedSpread.Config(push=[[np.nan, 0, 0]] * 3))
    with pytest.raises(ConfigError, match="distribution.params.travel_range"):
        CalibratedSpread(CalibratedSpread.Config(travel_range=[0.5, 0.1]))


def test_fit_spread_writes_a_preset_that_predicts_and_tests(tmp_path):
    store = tiny_store(tmp_path / "e.zarr", members=4)
    out = tmp_path / "prior_spread.yaml"
    code, text, err = cli("fit-spread", "contact_prior", "--data", store, "--out", out)
    assert code == 0, err
    written = yaml.safe_load(out.read_text())
    assert written["distribution"]["name"] == "calibrated" and written["motion"]["name"] == "contact_prior"
    pipeline = load_pipeline(out)
    assert pipeline.distribution.registered_name == "calibrated" and "wrote" in text
    code, text, err = cli("test", "--checkpoint", out, "--data", store, "--samples", 8, "--out", tmp_path / "report",
                          "--no-viewer")
    assert code == 0 and "distribution (calibrated) of 8 samples" in text, err
    # replacing needs --overwrite; a store without members is refused; neither writes anything
    before = out.read_text()
    code, _, err = cli("fit-spread", "contact_prior", "--data", store, "--out", out)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--overwrite" in err and out.read_text() == before
    plain = tiny_store(tmp_path / "plain.zarr", members=0)
    code, _, err = cli("fit-spread", "contact_prior", "--data", plain, "--out", tmp_path / "x.yaml")
    assert code == 2 and "ensemble" in err and not (tmp_path / "x.yaml").exists()
