"""Ensemble stores (`physdyn simulate` with an `ensemble:` block): each push's members are real simulations of
the perturbed push, seeded per push, and come through resume, parallel workers and bad input like the pushes."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from physdyn.cli import main
from physdyn.config import DataConfig, load_config, resolve_uncertainty
from physdyn.data.simulated_store import block_part, generate_dataset
from physdyn.data.store import StoreWriter, load_store
from physdyn.predict.simulator import simulate_from_state
from physdyn.sim.generate import build_family, config_hash, ensemble_streams, plan, prepare_shape, run_block
from physdyn.sim.perturb import perturb_pushes
from tests.conftest import REPO

PRIMITIVES = REPO / "configs" / "data" / "primitives.yaml"
# 3 shapes in 2 blocks, 2 pushes each, 3 members of 1.5 s: a few seconds of simulation.
TINY = ["families.primitives.shapes=3", "families.primitives.sims_per_shape=2", "shapes_per_block=2", "num_points=64",
        "physics.max_duration=2.0", "ensemble.members=3", "ensemble.seconds=1.5"]
ENSEMBLE = ["linear_velocity0", "angular_velocity0", "friction", "com_position", "orientation_xyzw", "topple_label",
            "topple_step"]
PUSHES = ["shape_id", "start", "friction", "impulse", "com_position", "orientation_xyzw", "linear_velocity",
          "angular_velocity", "topple_label"]


def tiny_config(*extra: str) -> DataConfig:
    return load_config(DataConfig, PRIMITIVES, TINY + list(extra))


def assert_same_store(a, b, names=tuple(f"ensemble/{n}" for n in ENSEMBLE)):
    for name in PUSHES:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in names:
        np.testing.assert_array_equal(a.extra[name], b.extra[name], err_msg=name)


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("ensemble") / "e.zarr"
    generate_dataset(tiny_config(), str(out), workers=1, progress=False)
    return str(out)


def shape_specs(cfg: DataConfig) -> list:
    """The bodies the store's shapes were simulated with, rebuilt from the config."""
    blocks, _ = plan(cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return [prepare_shape(cfg, build_family(cfg, t.family), t)["spec"] for tasks in blocks for t in tasks]


def test_members_are_simulations_of_the_stored_perturbed_pushes(store):
    cfg, d = tiny_config(), load_store(store)
    e = {name: d.extra[f"ensemble/{name}"] for name in ENSEMBLE}
    P, K, T = e["topple_label"].shape
    assert (P, K, T) == (d.num_sims, 3, 23) and d.attrs["ensemble"]["members"] == 3
    specs = shape_specs(cfg)
    for p in range(P):
        q0 = d.orientation_xyzw[d.start[p]]
        for k in range(K):
            physics = dataclasses.replace(cfg.physics, lateral_friction_object=e["friction"][p, k] / 0.5)
            sim = simulate_from_state(specs[d.shape_id[p]], q0, e["linear_velocity0"][p, k], e["angular_velocity0"][p, k],
                                      cfg.rate_hz, T, physics)
            np.testing.assert_array_equal(e["com_position"][p, k], sim["com_position"])
            np.testing.assert_array_equal(e["orientation_xyzw"][p, k], sim["orientation_xyzw"])
            np.testing.assert_array_equal(e["topple_label"][p, k], sim["topple_label"])
        steps = np.where(e["topple_label"][p].any(axis=1), e["topple_label"][p].argmax(axis=1), -1)
        np.testing.assert_array_equal(e["topple_step"][p], steps)
    # the perturbations are the conventions' draws from each push's own stream
    blocks, _ = plan(cfg)
    streams = [s for tasks in blocks for t in tasks for s in ensemble_streams(cfg, t)]
    for p, stream in enumerate(streams):
        start = d.start[p]
        lin, ang, mu = perturb_pushes(d.linear_velocity[start], d.angular_velocity[start], d.friction[p:p + 1],
                                      resolve_uncertainty("default"), np.random.default_rng(stream), K)
        np.testing.assert_array_equal(lin[0], e["linear_velocity0"][p])
        np.testing.assert_array_equal(ang[0], e["angular_velocity0"][p])
        np.testing.assert_array_equal(mu[0], e["friction"][p])


def test_members_spread_under_uncertainty_and_are_the_push_without(store, tmp_path):
    cfg, d = tiny_config(), load_store(store)
    final = d.extra["ensemble/com_position"][:, :, -1, :2]  # (P, K, 2)
    spread = np.linalg.norm(final[:, :, None] - final[:, None, :], axis=-1)
    assert np.all(spread[:, ~np.eye(3, dtype=bool)] > 1e-6)  # every two members of a push differ
    specs = shape_specs(cfg)
    for p in range(d.num_sims):
        start = d.start[p]
        push = simulate_from_state(specs[d.shape_id[p]], d.orientation_xyzw[start], d.linear_velocity[start],
                                   d.angular_velocity[start], cfg.rate_hz, 23, cfg.physics)
        assert np.all(np.linalg.norm(final[p] - push["com_position"][-1, :2], axis=-1) > 1e-6)
    # known exactly: every member is the unperturbed push, re-simulated from its step-0 state
    exact_cfg = tiny_config("ensemble.uncertainty=none", "families.primitives.shapes=1", "ensemble.members=2")
    generate_dataset(exact_cfg, str(tmp_path / "none.zarr"), progress=False)
    exact = load_store(tmp_path / "none.zarr")
    for p in range(exact.num_sims):
        start = exact.start[p]
        np.testing.assert_array_equal(exact.extra["ensemble/linear_velocity0"][p], exact.linear_velocity[[start] * 2])
        np.testing.assert_array_equal(exact.extra["ensemble/friction"][p], exact.friction[[p] * 2])
        push = simulate_from_state(specs[exact.shape_id[p]], exact.orientation_xyzw[start], exact.linear_velocity[start],
                                   exact.angular_velocity[start], cfg.rate_hz, 23, cfg.physics)
        for k in range(2):
            np.testing.assert_array_equal(exact.extra["ensemble/com_position"][p, k], push["com_position"])


def test_an_ensemble_leaves_the_pushes_as_they_were(store, tmp_path):
    generate_dataset(tiny_config("ensemble.members=0"), str(tmp_path / "plain.zarr"), progress=False)
    plain = load_store(tmp_path / "plain.zarr")
    assert_same_store(load_store(store), plain, names=())
    assert "ensemble" not in plain.attrs and not any(k.startswith("ensemble/") for k in plain.extra)


@pytest.mark.slow  # three simulations of the store, one of them interrupted (about 6 s)
def test_same_members_whatever_the_worker_count_and_after_resume(store, tmp_path):
    generate_dataset(tiny_config(), str(tmp_path / "w2.zarr"), workers=2, progress=False)
    assert_same_store(load_store(store), load_store(tmp_path / "w2.zarr"))
    # interrupted after its first block: --resume simulates the second alone
    cfg, out = tiny_config(), tmp_path / "resumed.zarr"
    blocks, _ = plan(cfg)
    writer = StoreWriter.create(str(out), {"config_hash": config_hash(cfg), "rate_hz": cfg.rate_hz})
    writer.write_block(0, *block_part(run_block(cfg, 0, blocks[0])))
    report = generate_dataset(cfg, str(out), resume=True, progress=False)
    assert report.blocks_resumed == 1
    assert_same_store(load_store(store), load_store(out))


@pytest.mark.parametrize("override", ["ensemble.uncertainty.speed_rel=-1", "ensemble.uncertainty.spin_abs=nan",
                                      "ensemble.uncertainty.direction_deg=90", "ensemble.uncertainty=loud"])
def test_a_bad_uncertainty_is_one_line_and_writes_nothing(override, tmp_path, capsys):
    out = tmp_path / "X"
    assert main(["simulate", "--config", str(PRIMITIVES), "--out", str(out), "--quiet", *TINY, override]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "ensemble.uncertainty" in err, err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_data_info_shows_the_ensemble(store, capsys):
    assert main(["data", "info", store]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("ensemble")]
    assert line and "3 members per push (6 pushes)" in line[0] and "speed_rel=0.03" in line[0], line


def test_ensemble_presets_load():
    for name, members in (("ensemble_eval", 32), ("ensemble_train", 8), ("ensemble_calibrate", 16)):
        cfg = load_config(DataConfig, Path(REPO / "configs" / "data" / f"{name}.yaml"))
        assert cfg.ensemble.members == members and cfg.ensemble.uncertainty_config() == resolve_uncertainty("default")
        # the clouds the default model (`fast`) reads, so `physdyn test` and `fit-spread` take the store as it is
        assert (cfg.points_method, cfg.num_points) == ("hull_surface", 256), name


@pytest.mark.ray
@pytest.mark.slow  # starts a local Ray instance (tens of seconds)
def test_ray_executor_gives_the_same_members(store, tmp_path):
    pytest.importorskip("ray")
    generate_dataset(tiny_config(), str(tmp_path / "r.zarr"), workers=2, executor="ray", progress=False)
    assert_same_store(load_store(store), load_store(tmp_path / "r.zarr"))
