"""The uncertainty of a push: presets, checked values, and the perturbation as docs/conventions.md defines it."""

from __future__ import annotations

import numpy as np
import pytest

from physdyn.config import (UNCERTAINTY_PRESETS, DataConfig, UncertaintyConfig, load_config, resolve_uncertainty,
                            uncertainty_at_level)
from physdyn.errors import ConfigError
from physdyn.sim.perturb import perturb_pushes

LIN = np.array([[1.2, -0.5, 0.01], [0.0, 0.8, 0.0]])
ANG = np.array([[0.1, -0.2, 3.0], [0.0, 0.0, 0.0]])
MU = np.array([0.25, 0.4])


def test_presets_are_levels_of_one_family():
    assert UNCERTAINTY_PRESETS["default"] == UncertaintyConfig() == UncertaintyConfig(0.03, 3.0, 0.03, 0.3, 0.03)
    assert UNCERTAINTY_PRESETS["low"] == uncertainty_at_level(0.01) and UNCERTAINTY_PRESETS["none"].is_zero
    assert resolve_uncertainty({"speed_rel": 0.05}) == UncertaintyConfig(speed_rel=0.05)  # the rest from default
    assert resolve_uncertainty(UncertaintyConfig(spin_abs=0.0)).spin_abs == 0.0


@pytest.mark.parametrize("value, key", [
    ({"speed_rel": -1}, "u.speed_rel"), ({"friction_rel": float("nan")}, "u.friction_rel"),
    ({"speed_rel": 0.6}, "u.speed_rel"), ({"direction_deg": 50}, "u.direction_deg"), ({"spin_abs": float("inf")}, "u.spin_abs"),
    ({"spin_rel": "lots"}, "u.spin_rel"), ({"speed": 0.1}, "u.speed"), ("loud", "u"), (0.03, "u"),
])
def test_a_bad_uncertainty_is_one_line_naming_the_key_and_the_fix(value, key):
    with pytest.raises(ConfigError) as err:
        resolve_uncertainty(value, "u")
    message = str(err.value)
    assert len(message.splitlines()) == 1 and f"'{key}'" in message, message


def test_the_ensemble_block_of_a_data_config():
    cfg = load_config(DataConfig, None, ["ensemble.members=4", "ensemble.uncertainty=low"])
    assert cfg.ensemble.members == 4 and cfg.ensemble.uncertainty_config() == uncertainty_at_level(0.01)
    inline = load_config(DataConfig, None, ["ensemble.uncertainty.speed_rel=0.1"])
    assert inline.ensemble.uncertainty_config() == UncertaintyConfig(speed_rel=0.1)
    with pytest.raises(ConfigError, match="'ensemble.uncertainty.speed_rel'.*expected a relative"):
        load_config(DataConfig, None, ["ensemble.uncertainty.speed_rel=-1"])
    with pytest.raises(ConfigError, match="'ensemble.members'"):
        load_config(DataConfig, None, ["ensemble.members=-2"])


def test_perturbation_is_the_conventions_by_hand():
    u = UncertaintyConfig(speed_rel=0.1, direction_deg=10.0, spin_rel=0.2, spin_abs=0.5, friction_rel=0.05)
    lin, ang, mu = perturb_pushes(LIN, ANG, MU, u, np.random.default_rng(7), 4)
    assert lin.shape == (2, 4, 3) and ang.shape == (2, 4, 3) and mu.shape == (2, 4)
    n = np.random.default_rng(7).standard_normal((2, 4, 9))
    for b in range(2):
        for k in range(4):
            speed, turn, spin_rel, spin_abs, friction = n[b, k, 0], n[b, k, 1], n[b, k, 2:5], n[b, k, 5:8], n[b, k, 8]
            a = np.deg2rad(10.0 * turn)
            turned = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ LIN[b]
            np.testing.assert_allclose(lin[b, k], turned * (1 + 0.1 * speed), rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(ang[b, k], ANG[b] + 0.2 * np.linalg.norm(ANG[b]) * spin_rel + 0.5 * spin_abs,
                                       rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(mu[b, k], MU[b] * (1 + 0.05 * friction), rtol=1e-12)


def test_zero_uncertainty_gives_the_push_exactly_and_more_members_extend_fewer():
    lin, ang, mu = perturb_pushes(LIN, ANG, MU, resolve_uncertainty("none"), np.random.default_rng(0), 3)
    np.testing.assert_array_equal(lin, np.repeat(LIN[:, None], 3, axis=1))
    np.testing.assert_array_equal(ang, np.repeat(ANG[:, None], 3, axis=1))
    np.testing.assert_array_equal(mu, np.repeat(MU[:, None], 3, axis=1))
    u = resolve_uncertainty("default")
    few = perturb_pushes(LIN[:1], ANG[:1], MU[:1], u, np.random.default_rng(3), 4)
    many = perturb_pushes(LIN[:1], ANG[:1], MU[:1], u, np.random.default_rng(3), 16)
    for a, b in zip(few, many):
        np.testing.assert_array_equal(a, b[:, :4])


def test_the_default_spread_has_the_stated_sizes():
    u = resolve_uncertainty("default")
    lin, ang, mu = perturb_pushes(LIN[:1], np.zeros((1, 3)), MU[:1], u, np.random.default_rng(1), 20000)
    speed = np.linalg.norm(lin[0, :, :2], axis=1) / np.linalg.norm(LIN[0, :2])
    turn = np.rad2deg(np.arctan2(lin[0, :, 1], lin[0, :, 0]) - np.arctan2(LIN[0, 1], LIN[0, 0]))
    assert abs(speed.std() - 0.03) < 0.001 and abs(turn.std() - 3.0) < 0.1
    assert np.allclose(ang[0].std(axis=0), 0.3, atol=0.01)  # a push that does not spin: the absolute term alone
    assert abs(mu[0].std() / MU[0] - 0.03) < 0.001
    wild = perturb_pushes(LIN[:1], ANG[:1], MU[:1], UncertaintyConfig(speed_rel=0.5, friction_rel=0.5),
                          np.random.default_rng(2), 20000)
    assert wild[2].min() >= 0 and (np.einsum("bkc,bc->bk", wild[0][..., :2], LIN[:1, :2]) >= 0).all()
