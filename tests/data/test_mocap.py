"""Motion-capture import (physdyn.data.mocap_import) checked against synthetic trials with known truth
(physdyn.sim.synthetic_trials), malformed trials, and the real-world preset trained and tested on the result."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from physdyn.data.mocap_import import ImportSettings, average_quaternions, import_trial, split_trials
from physdyn.data.store import load_store
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_rotvec, rotvec_to_quat
from physdyn.sim.synthetic_trials import CSV_HEADER, tracked_shape, write_trial_csv
from tests.conftest import REPO, run_cli

BOX = "box:0.073,0.060,0.170"
FLOOR_OFFSET = 0.012  # m: the synthetic tracker's origin sits 12 mm below the floor
RATE = 30.0

# Tolerances of the import against the simulator (measured values in docs/real-world.md).
TRIM_FRAMES = 1.5  # |trim time - release time| in output frames
V0_RELATIVE = 0.15  # step 0 straddles the release kink: central differences smooth it
V_ABS = 0.08  # m/s, later steps
YAW_RATE_ABS = 0.8  # rad/s, vertical component of w (the simulator's horizontal w chatters: see the docs)
POSITION_ABS = 1.5e-3  # m
ANGLE_DEG = 1.0
FLOOR_ABS = 0.7e-3  # m


@pytest.fixture(scope="module")
def trials(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("mocap") / "trials"
    run_cli("simulate-mocap", "--out", str(out), "--trials", "12", "--seed", "0",
            "--floor-offset", str(FLOOR_OFFSET), check=True)
    return out


@pytest.fixture(scope="module")
def store(trials, tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("stores") / "box_real.zarr"
    proc = run_cli("import-mocap", str(trials), "--shape", BOX, "--out", str(out), check=True)
    assert "input rate 120" in proc.stdout and "12 trials (9 train, 1 val, 2 test)" in proc.stdout, proc.stdout
    return str(out)


def _truth_at(truth, key: str, times: np.ndarray) -> np.ndarray:
    values = truth[key]
    return np.stack([np.interp(times, truth["time"], values[:, i]) for i in range(values.shape[1])], axis=1)


def _angle_deg(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(quat_to_rotvec(quat_multiply(q_a, quat_conjugate(q_b))), axis=-1))


def test_synthetic_trials_import_to_the_simulators_values(trials):
    shape = tracked_shape(box=BOX)
    csvs = sorted(trials.glob("*.csv"))
    assert len(csvs) == 12 and all(p.with_suffix(".truth.npz").exists() for p in csvs)
    assert csvs[0].read_text().splitlines()[0] == CSV_HEADER
    for path in csvs:
        trial = import_trial(path, shape)
        truth = np.load(path.with_suffix(".truth.npz"))
        # The trim point is where the push ends.
        assert abs(trial.time[0] - float(truth["release"])) * RATE <= TRIM_FRAMES, path.name
        v_true = _truth_at(truth, "linear_velocity", trial.time)
        w_true = _truth_at(truth, "angular_velocity", trial.time)
        err_v = np.linalg.norm(trial.linear_velocity - v_true, axis=1)
        assert err_v[0] <= V0_RELATIVE * np.linalg.norm(v_true[0]), (path.name, err_v[0])
        assert err_v[1:].max() <= V_ABS, (path.name, err_v.max())
        assert np.abs(trial.angular_velocity[1:, 2] - w_true[1:, 2]).max() <= YAW_RATE_ABS, path.name
        # The floor: the offset the tracker added, plus where the simulator's resting box sits (its contact
        # margin keeps the lowest vertex ~1 mm above z = 0).
        rest_gap = np.median(shape.lowest_vertex_z(truth["com_position"][-30:], truth["orientation_xyzw"][-30:]))
        assert abs(trial.floor_offset - (FLOOR_OFFSET + rest_gap)) <= FLOOR_ABS, (path.name, trial.floor_offset)
        p_true = _truth_at(truth, "com_position", trial.time) - np.array([0, 0, rest_gap])
        assert np.linalg.norm(trial.com_position - p_true, axis=1).max() <= POSITION_ABS, path.name
        q_true = Slerp(truth["time"], Rotation.from_quat(truth["orientation_xyzw"]))(trial.time).as_quat()
        assert _angle_deg(trial.orientation_xyzw, q_true).max() <= ANGLE_DEG, path.name
        assert trial.topple_step == -1  # a push at the centre-of-mass height slides the box
        assert len(trial) >= 15 and trial.input_rate_hz == pytest.approx(120.0, rel=1e-3)


def test_store_holds_the_trials_in_the_conventions_layout(store):
    d = load_store(store)
    assert d.rate_hz == RATE and d.category_names == ["real"] and d.num_shapes == 1 and d.num_sims == 12
    assert d.points.shape == (1, 1024, 3) and d.points.dtype == np.float32
    np.testing.assert_allclose(np.abs(d.points).max(axis=(0, 1)), [0.0365, 0.030, 0.085], atol=1e-3)  # body frame
    assert np.isnan(d.friction).all() and np.isnan(d.impulse).all()
    assert sorted(np.bincount(d.split, minlength=3).tolist()) == [1, 2, 9]
    assert list(d.extra["sims/trial"]) == [f"trial_{i:03d}.csv" for i in range(12)]
    np.testing.assert_allclose(np.linalg.norm(d.orientation_xyzw, axis=1), 1.0, atol=1e-9)
    first = d.start[:-1]
    speed = np.linalg.norm(d.linear_velocity, axis=1)
    assert all(speed[first[i]] == speed[d.frames(i)].max() for i in range(12))  # step 0 = peak speed


def test_split_is_by_trial_56_train_10_test_for_66():
    split = split_trials(66, ImportSettings(seed=4))
    assert (split == 2).sum() == 10 and (split != 2).sum() == 56 and (split == 1).sum() == 6
    assert np.array_equal(split, split_trials(66, ImportSettings(seed=4)))
    assert not np.array_equal(split, split_trials(66, ImportSettings(seed=5)))
    assert (split_trials(3, ImportSettings()) == 1).sum() == 1


def test_markley_average_is_the_centre_and_ignores_signs():
    rng = np.random.default_rng(0)
    centre = rotvec_to_quat(np.array([0.3, -1.0, 2.0]))
    delta = rng.normal(0, 0.02, (2, 3))
    window = quat_multiply(rotvec_to_quat(np.concatenate([delta, -delta])), centre)
    window[1] *= -1
    mean = average_quaternions(window)
    assert _angle_deg(mean, centre) < 1e-3
    assert abs(np.linalg.norm(mean) - 1) < 1e-12


def _malformed_folder(trials: Path, folder: Path) -> dict[str, str]:
    """Two good trials plus one of each malformed kind; returns file -> expected reason fragment."""
    folder.mkdir()
    for name in ("trial_000.csv", "trial_001.csv"):
        shutil.copy(trials / name, folder / name)
    data = np.loadtxt(trials / "trial_002.csv", delimiter=",", skiprows=1)
    t, p, q = data[:, 0], data[:, 1:4], data[:, 4:]
    rest = int(float(np.load(trials / "trial_002.truth.npz")["push_start"]) * 120)
    write_trial_csv(folder / "short.csv", t[:10], p[:10], q[:10])
    keep = np.r_[0:100, 110:len(t)]
    write_trial_csv(folder / "gap.csv", t[keep], p[keep], q[keep])
    flipped = q.copy()
    flipped[150:] *= -1
    write_trial_csv(folder / "flip.csv", t, p, flipped)
    scaled = q.copy()
    scaled[120] *= 1.2
    write_trial_csv(folder / "nonunit.csv", t, p, scaled)
    write_trial_csv(folder / "still.csv", t[:rest], p[:rest], q[:rest])
    text = (trials / "trial_002.csv").read_text().splitlines()
    (folder / "header.csv").write_text("\n".join(["t,x,y,z,qx,qy,qz,qw"] + text[1:]) + "\n")
    nan_p = p.copy()
    nan_p[130, 0] = np.nan
    write_trial_csv(folder / "nan.csv", t, nan_p, q)
    return {"short.csv": "too short", "gap.csv": "gap of", "flip.csv": "sign flips", "nonunit.csv": "non-unit quaternion",
            "still.csv": "never moves", "header.csv": "malformed header", "nan.csv": "NaN"}


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_malformed_trials_are_reported_and_the_rest_imported(trials, tmp_path):
    expected = _malformed_folder(trials, tmp_path / "mixed")
    out = tmp_path / "mixed.zarr"
    proc = run_cli("import-mocap", str(tmp_path / "mixed"), "--shape", BOX, "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert f"skipped {len(expected)} trial(s)" in proc.stdout
    lines = proc.stdout.splitlines()
    for name, reason in expected.items():
        assert any(name in line and reason in line for line in lines), (name, proc.stdout)
    d = load_store(out)
    assert list(d.extra["sims/trial"]) == ["trial_000.csv", "trial_001.csv"]
    assert {Path(s["file"]).name for s in d.attrs["skipped"]} == set(expected)
    # Re-aligning sign flips on request imports that trial too; an existing store needs --overwrite.
    again = run_cli("import-mocap", str(tmp_path / "mixed"), "--shape", BOX, "--out", str(out), "--fix-sign-flips")
    assert again.returncode == 2 and "already exists" in again.stderr and "--overwrite" in again.stderr
    again = run_cli("import-mocap", str(tmp_path / "mixed"), "--shape", BOX, "--out", str(out), "--fix-sign-flips",
                    "--overwrite", "--friction", "0.25", check=True)
    d = load_store(out)
    assert "flip.csv" in list(d.extra["sims/trial"]) and np.all(d.friction == 0.25)
    # Nothing usable: one-line error, nothing written.
    bad = tmp_path / "bad"
    bad.mkdir()
    shutil.copy(tmp_path / "mixed" / "header.csv", bad / "header.csv")
    proc = run_cli("import-mocap", str(bad), "--shape", BOX, "--out", str(tmp_path / "bad.zarr"))
    assert proc.returncode == 2 and "malformed header" in proc.stderr and not (tmp_path / "bad.zarr").exists()
    proc = run_cli("import-mocap", str(bad), "--shape", "box:1,2", "--out", str(tmp_path / "x.zarr"))
    assert proc.returncode == 2 and "box:W,D,H" in proc.stderr


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_realworld_preset_trains_and_tests_with_warm_start(store, tmp_path):
    import torch

    from physdyn.models.training import fit, load_experiment_config
    from tests.models.conftest import shrunk_overrides

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    cfg = load_experiment_config(REPO / "configs/experiment/realworld.yaml",
                                 shrunk_overrides(store, tmp_path / "run", "trainer.accelerator=cpu", "data.num_workers=0"))
    assert cfg.loss.kind == "absolute" and cfg.model.head.name == "no_topple"
    result = fit(cfg)
    assert result.best_checkpoint is not None and result.best_checkpoint.is_file()
    proc = run_cli("test", "--checkpoint", str(result.best_checkpoint), "--data", store, "--warm-start", "1",
                   "--out", str(tmp_path / "report"), check=True)
    assert "realworld on 2 non-toppling test sequences" in proc.stdout
    # trials imported without --friction: the sliding baseline is skipped and the verdict says why
    assert "no Coulomb-sliding baseline: the store records no friction coefficient" in proc.stdout
    assert "--friction MU" in proc.stdout
    assert (tmp_path / "report" / "metrics.json").is_file()
