"""Training end to end from the REAL presets, shrunk for the CPU (lightning-hydra-template style)."""

from __future__ import annotations

import csv
import itertools
import json
import math
from pathlib import Path

import lightning
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from physdyn.config import ExperimentConfig, PretrainConfig, load_config
from physdyn.data.datamodule import DynamicsDataModule
from physdyn.data.normalization import Normalization
from physdyn.data.store import load_store
from physdyn.data.windows import relative_rotation, world_oriented_points
from physdyn.errors import ConfigError, PhysdynError
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.training import fit, load_experiment_config
from physdyn.registry import ENCODERS, HEADS, PREDICTORS
from tests.conftest import run_cli
from tests.models.conftest import QUICKSTART, REPO, shrunk_overrides

COMBINATIONS = list(itertools.product(ENCODERS.names(), PREDICTORS.names(), HEADS.names()))


def _csv_rows(out_dir: Path) -> list[dict]:
    with open(out_dir / "csv" / "metrics.csv") as fh:
        return list(csv.DictReader(fh))


# A plugin encoder's combinations (physdyn-dgcnn) with the tests marked slow (CI runs them): the default run
# trains every predictor and head with the built-in encoder and stays near its 3 minutes
@pytest.mark.parametrize("encoder,predictor,head", [
    pytest.param(*c, marks=() if c[0] == "pointnet" else pytest.mark.slow) for c in COMBINATIONS])
def test_every_registered_component_combination_trains(quickstart_config, encoder, predictor, head):
    cfg = quickstart_config(f"model.predictor.name={predictor}", f"model.head.name={head}")
    if encoder != cfg.model.encoder.name:  # a plugin encoder: its own defaults (the shrink is PointNet's)
        cfg.model.encoder.name, cfg.model.encoder.params = encoder, {}
    result = fit(cfg)
    assert result.last_checkpoint is not None and result.last_checkpoint.is_file()
    assert result.best_checkpoint is not None and result.best_checkpoint.is_file()
    assert math.isfinite(result.metrics["train/loss"]) and math.isfinite(result.metrics["best_val_loss"])
    assert ("train/topple" in result.metrics) == (head == "topple")
    assert (result.out_dir / "config.yaml").is_file() and (result.out_dir / "finished.json").is_file()
    assert any(r.get("train/loss_step") for r in _csv_rows(result.out_dir))
    assert any((result.out_dir / "tensorboard").iterdir())
    saved = load_config(ExperimentConfig, result.out_dir / "config.yaml")
    assert saved.model.predictor.name == predictor and saved.data.store == cfg.data.store


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_model_overfits_a_tiny_store(tiny_store, tmp_path):
    # A fixed set of real windows from the store, the module's own loss: the loss must fall >= 10x.
    # Teacher forcing keeps the inputs fixed (the preset's roll-out feedback feeds the model's own, moving
    # predictions; tests/models/test_recipe.py checks that such training lowers roll-out errors).
    lightning.seed_everything(0)
    cfg = load_experiment_config(QUICKSTART, shrunk_overrides(
        tiny_store, tmp_path, "data.batch_size=8", "model.predictor.params.hidden=64",
        "model.encoder.params.batch_norm=false", "optim.lr=1e-2", "rollout.feedback=0.0",
    ))
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    batch = next(iter(dm.val_dataloader()))
    model = DynamicsModel(cfg, dm.normalization)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.optim.lr)
    losses = []
    for _ in range(1500):
        loss = model.compute_loss(batch).total
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[0] / min(losses[-20:]) >= 10.0, (losses[0], losses[-20:])
    # the resting/padded steps were learned too: predicted changes there are small
    pred = model.predict_window(batch["points"], batch["linear_velocity"], batch["angular_velocity"],
                                orientation=batch["relative_orientation_xyzw"])
    resting = ~batch["valid"]
    assert resting.any()
    assert pred.delta_position[resting].norm(dim=-1).mean() < 0.1 * dm.normalization.position


def test_checkpoint_reloads_with_config_and_normalisation(quickstart_config, tiny_store, tmp_path):
    cfg = quickstart_config("trainer.max_steps=4")
    lightning.seed_everything(1)
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    model = DynamicsModel(cfg, dm.normalization, {"rate_hz": dm.rate_hz})
    trainer = lightning.Trainer(max_steps=4, accelerator="cpu", logger=False, enable_checkpointing=False,
                                enable_progress_bar=False, enable_model_summary=False)
    trainer.fit(model, datamodule=dm)
    path = tmp_path / "model.ckpt"
    trainer.save_checkpoint(path)

    loaded = DynamicsModel.load_from_checkpoint(path)
    assert loaded.normalization == dm.normalization
    assert loaded.config == cfg
    assert loaded.data_info["rate_hz"] == dm.rate_hz
    batch = next(iter(dm.val_dataloader()))
    turn = batch["relative_orientation_xyzw"]  # the preset feeds the orientation since the first step
    a = model.predict_window(batch["points"], batch["linear_velocity"], batch["angular_velocity"], orientation=turn)
    b = loaded.predict_window(batch["points"], batch["linear_velocity"], batch["angular_velocity"], orientation=turn)
    for key in ("delta_linear_velocity", "delta_angular_velocity", "delta_position", "delta_rotation", "topple_probability"):
        assert torch.equal(getattr(a, key), getattr(b, key)), key
    loaded.train()
    loaded.predict_window(batch["points"], batch["linear_velocity"], batch["angular_velocity"], orientation=turn)
    assert loaded.training  # predict_window runs in eval mode and restores the caller's mode
    # de-normalised outputs are in SI units: the same as normalised output x the saved scales
    feature = loaded.encode_points(batch["points"])
    with torch.no_grad():
        loaded.eval()
        changes, _, _ = loaded(feature, batch["linear_velocity"], batch["angular_velocity"], None, turn)
    scale = torch.tensor(Normalization.from_dict(loaded.hparams["normalization"]).change_scales(), dtype=torch.float32)
    assert torch.allclose(changes[..., 6:9] * scale[6:9], b.delta_position, atol=1e-6)


def test_step_by_step_rollout_api_matches_the_window(quickstart_config, tiny_store):
    cfg = quickstart_config()
    store = load_store(tiny_store)
    dm = DynamicsDataModule(cfg.data, store=store)
    dm.setup("fit")
    model = DynamicsModel(cfg, dm.normalization)
    sim = int(dm.sims.test[0])
    f = store.frames(sim)
    points = world_oriented_points(store.points[store.shape_id[sim]], store.orientation_xyzw[f.start])[None]
    v, w = store.linear_velocity[f][None, :10], store.angular_velocity[f][None, :10]
    turn = relative_rotation(store.orientation_xyzw[f.start][None], store.orientation_xyzw[f][None, :10])
    window = model.predict_window(points, v, w, orientation=turn)
    feature = model.encode_points(points)
    state, steps = None, []
    for t in range(10):
        out = model.step(feature, v[:, t], w[:, t], state, turn[:, t])
        state = out.state
        steps.append(out.delta_rotation)
    assert torch.allclose(torch.stack(steps, dim=1), window.delta_rotation, atol=1e-5)
    assert window.to_numpy()["topple_probability"].shape == (1, 10)


def test_resume_continues_and_finished_runs_are_protected(quickstart_config, recwarn):
    first = fit(quickstart_config("trainer.max_steps=2"))
    with pytest.raises(PhysdynError, match="finished run.*--overwrite"):
        fit(quickstart_config("trainer.max_steps=2"))
    metrics = first.out_dir / "csv" / "metrics.csv"
    steps_before = sorted({int(float(r["step"])) for r in csv.DictReader(metrics.open()) if r["train/loss_step"]})
    assert steps_before  # log_every_n_steps=1: one training row per step
    with pytest.raises(PhysdynError, match=r"--resume: .*model\.prior \('contact' -> 'coulomb'\)") as info:
        fit(quickstart_config("trainer.max_steps=5", "model.prior=coulomb"), resume=True)
    assert "\n" not in str(info.value)
    # a run saved before a config key existed (here rollout.input_noise, at its default) still resumes
    saved = OmegaConf.load(first.out_dir / "config.yaml")
    assert saved.rollout.input_noise == ExperimentConfig().rollout.input_noise
    del saved.rollout["input_noise"]
    OmegaConf.save(saved, first.out_dir / "config.yaml")
    resumed = fit(quickstart_config("trainer.max_steps=5"), resume=True)  # training longer may change
    assert resumed.out_dir == first.out_dir
    assert json.loads((first.out_dir / "finished.json").read_text())["global_step"] == 5
    ckpt = torch.load(resumed.last_checkpoint, map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 5
    steps_after = sorted({int(float(r["step"])) for r in csv.DictReader(metrics.open()) if r["train/loss_step"]})
    assert steps_after[: len(steps_before)] == steps_before  # the history before the resume is kept
    assert max(steps_after) > max(steps_before)
    again = fit(quickstart_config("trainer.max_steps=1"), overwrite=True)
    assert json.loads((again.out_dir / "finished.json").read_text())["global_step"] == 1
    # A run resumed, or stopped, at an epoch's end before any validation keeps its best.ckpt; Lightning's
    # "did you call log('val/loss')?" (warned once per process) would only mislead the user.
    assert not [w for w in recwarn if "monitored key" in str(w.message)]


def test_a_run_without_validation_says_its_best_ckpt_is_the_last(quickstart_config):
    with pytest.warns(UserWarning, match="no validation ran.*best.ckpt holds the last weights"):
        result = fit(quickstart_config("trainer.max_steps=2", "trainer.limit_val_batches=0"))
    assert result.best_checkpoint is not None and "best_val_loss" not in result.metrics


@pytest.mark.slow  # seconds-scale; the default run stays near 3 minutes, CI runs it (-m slow)
def test_cli_fit_output_is_free_of_lightning_noise(tiny_store, tmp_path):
    # Lightning's cloud-logger tip and a torch deprecation warning it triggers would print on every run.
    from physdyn.models.trainer_setup import LIGHTNING_NOISE

    proc = run_cli("fit", "--config", str(QUICKSTART), *shrunk_overrides(tiny_store, tmp_path / "r", "progress_bar=true"))
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "r" / "finished.json").is_file()
    for text in LIGHTNING_NOISE:
        assert text not in proc.stdout + proc.stderr, text
    # Off a terminal (a pipe here, a log or CI elsewhere): plain progress lines, no carriage-return bar.
    assert "\r" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("fit: step")]
    assert any("val/loss" in line for line in lines) and any(", done," in line for line in lines)
    assert all(line.endswith("steps/s") or line.endswith("min left") for line in lines), lines


def test_bad_config_is_a_one_line_error_naming_the_key(tiny_store, tmp_path):
    cases = [
        ("data.windw=3", "data.windw"),
        ("data.window=abc", "data.window"),
        ("model.encoder.params.widths=[3]", "model.encoder.params.widths"),
        ("model.predictor.name=gru", "model.predictor.name"),
        ("trainer.max_epoch=3", "trainer.max_epoch"),
        ("loss.kind=squared", "loss.kind"),
    ]
    for override, key in cases:  # in-process: the library raises a one-line ConfigError naming the key
        with pytest.raises(ConfigError) as info:
            load_experiment_config(QUICKSTART, [f"data.store={tiny_store}", override])
        assert key in str(info.value) and "\n" not in str(info.value), override
    with pytest.raises(ConfigError, match="data.exclude_categories.*chairs"):
        fit(load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path / "r", "data.exclude_categories=[chairs]")))
    assert not (tmp_path / "r" / "last.ckpt").exists()


@pytest.mark.slow  # a fresh process imports lightning first (about 9 s on the 2-core machine)
def test_bad_config_in_a_fresh_process_is_one_line_and_exit_status_2(tiny_store, tmp_path):
    # As a user sees it: one line on stderr, exit status 2 (tests/test_bad_inputs.py runs many more such cases
    # through the command line's main in-process)
    proc = run_cli("fit", "--config", str(QUICKSTART), f"data.store={tiny_store}", f"out_dir={tmp_path / 'r'}", "data.windw=3")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "data.windw" in lines[0], proc.stderr
    assert not (tmp_path / "r").exists()


def test_every_preset_loads_and_builds():
    presets = sorted((REPO / "configs" / "experiment").glob("*.yaml"))
    names = {p.stem for p in presets}
    assert {"quickstart", "paper", "mlp_baseline", "realworld", "pretrain"} <= names
    norm = Normalization()
    for path in presets:
        if path.stem == "pretrain":
            assert load_config(PretrainConfig, path).encoder.name == "pointnet"
            continue
        cfg = load_experiment_config(path)
        model = DynamicsModel(cfg, norm)
        # the real-world model has no topple head, nor does the contact prior alone (it never topples)
        assert model.predicts_topple == (path.stem not in ("realworld", "contact_prior")), path.stem
    paper = DynamicsModel(load_experiment_config(REPO / "configs/experiment/paper.yaml"), norm)
    assert 22.5e6 < sum(p.numel() for p in paper.parameters()) < 23.3e6
    quick = load_experiment_config(QUICKSTART)
    assert quick.data.num_points == 256 and quick.model.predictor.params == {"num_layers": 3, "hidden": 128}
    assert max(quick.model.encoder.params["point_widths"]) <= 256
    real = load_experiment_config(REPO / "configs/experiment/realworld.yaml")
    assert real.loss.kind == "absolute" and real.model.encoder.params["batch_norm"] is False


def test_leave_one_category_out(quickstart_config, tiny_store):
    store = load_store(tiny_store)
    left_out = store.category_names[2]
    result = fit(quickstart_config(f"data.exclude_categories=[{left_out}]"))
    model = DynamicsModel.load_from_checkpoint(result.last_checkpoint)
    cats = store.sim_category()
    assert model.data_info["train_sims"] == int(np.sum((store.split == 0) & (cats != 2)))


@pytest.mark.slow  # minutes-scale; CI runs it after the default suite
def test_ddp_two_cpu_processes_via_the_cli(tiny_store, tmp_path):
    out = tmp_path / "ddp"
    proc = run_cli(
        "fit", "--config", str(QUICKSTART),
        *shrunk_overrides(tiny_store, out, "trainer.strategy=ddp", "trainer.accelerator=cpu", "trainer.devices=2",
                          "trainer.max_steps=2"),
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "results in" in proc.stdout and str(out) in proc.stdout
    assert (out / "last.ckpt").is_file() and (out / "best.ckpt").is_file()
    ckpt = torch.load(out / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 2
    assert "world_size=2" in proc.stderr or "distributed_backend=gloo" in proc.stderr or "GLOBAL_RANK: 1" in proc.stderr


def test_overwrite_never_deletes_a_folder_that_is_not_a_run(quickstart_config, tmp_path):
    # `fit ... out_dir=DIR --overwrite` with the user's own files in DIR: refused, the files intact.
    cfg = quickstart_config(out="mine")
    own = Path(cfg.out_dir)
    own.mkdir(parents=True)
    (own / "thesis.tex").write_text("years of work")
    with pytest.raises(PhysdynError, match="not a physdyn run"):
        fit(cfg, overwrite=True)
    assert (own / "thesis.tex").read_text() == "years of work"
    # a real run directory is still replaced by --overwrite
    first = fit(quickstart_config("trainer.max_steps=1", out="run"))
    again = fit(quickstart_config("trainer.max_steps=1", out="run"), overwrite=True)
    assert again.out_dir == first.out_dir and (again.out_dir / "finished.json").is_file()


@pytest.mark.slow  # a real process killed mid-training; seconds to a minute
def test_a_killed_fit_resumes_to_the_planned_step_and_keeps_its_history(tiny_store, tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "killed"
    args = ["fit", "--config", str(QUICKSTART), *shrunk_overrides(tiny_store, out, "trainer.max_steps=400")]
    proc = subprocess.Popen([sys.executable, "-m", "physdyn.cli", *args], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 240
    while time.time() < deadline and not (out / "last.ckpt").is_file():
        time.sleep(0.1)
    time.sleep(1.0)  # a little past the first checkpoint
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert (out / "last.ckpt").is_file() and not (out / "finished.json").exists()
    killed_at = torch.load(out / "last.ckpt", map_location="cpu", weights_only=False)["global_step"]
    assert 0 < killed_at < 400
    resumed = run_cli(*args, "--resume", timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert json.loads((out / "finished.json").read_text())["global_step"] == 400
    steps = sorted({int(float(r["step"])) for r in csv.DictReader((out / "csv" / "metrics.csv").open()) if r["train/loss_step"]})
    assert steps[0] <= 1 and steps[-1] >= 390  # one history from the first step to the last, across the kill


def test_a_command_without_resume_is_never_told_to_pass_it(tmp_path):
    from physdyn.models.run_directory import prepare_run_directory

    run = tmp_path / "pre"
    run.mkdir()
    (run / "config.yaml").write_text("name: pre\n")  # an earlier, unfinished run
    with pytest.raises(PhysdynError) as info:
        prepare_run_directory(run, resume=False, overwrite=False, what="physdyn pretrain", resumable=False)
    assert "--resume" not in str(info.value) and "--overwrite" in str(info.value) and "physdyn pretrain" in str(info.value)
    with pytest.raises(PhysdynError, match="pass --resume to continue it"):
        prepare_run_directory(run, resume=False, overwrite=False)
    assert (run / "config.yaml").read_text() == "name: pre\n"


def test_export_keeps_what_prediction_needs_and_nothing_to_resume(quickstart_config, tiny_store, tmp_path):
    from physdyn.eval.baselines import load_checkpoint
    from physdyn.eval.evaluate import evaluate
    from physdyn.models.export import export_checkpoint
    from physdyn.models.topple_classifier import fit_topple_classifier

    run = fit(quickstart_config())
    raw = torch.load(run.last_checkpoint, map_location="cpu", weights_only=False)
    assert "optimizer_states" in raw
    raw["topple_classifier"] = fit_topple_classifier(load_store(tiny_store))[0].to_dict()
    full = tmp_path / "full.ckpt"
    torch.save(raw, full)
    slim = export_checkpoint(full, tmp_path / "slim.ckpt")
    kept = torch.load(slim, map_location="cpu", weights_only=False)
    assert "optimizer_states" not in kept and "loops" not in kept and "topple_classifier" in kept
    assert slim.stat().st_size < full.stat().st_size
    a, b = evaluate(load_checkpoint(full), tiny_store, "test"), evaluate(load_checkpoint(slim), tiny_store, "test")
    assert a["headline"] == b["headline"] and a["topple"] == b["topple"]
    with pytest.raises(PhysdynError, match="exists; pass --overwrite"):
        export_checkpoint(full, slim)
    # inference settings chosen after training go into the shipped config, checked as fit checks them
    tuned = export_checkpoint(full, tmp_path / "tuned.ckpt", settings=["model.contact_inertia=body",
                                                                        "model.residual_gate_linear=0.2", "name=shipped",
                                                                        "model.contact_footprint=area", "model.sim_seconds=0.4",
                                                                        "model.contact_substeps=8"])
    model = load_checkpoint(tuned)
    assert model.config.model.contact_inertia == "body" and model.config.model.residual_gate_linear == 0.2
    assert model.config.model.contact_footprint == "area" and model.config.model.sim_seconds == 0.4
    assert model.config.model.contact_substeps == 8
    assert model.config.name == "shipped"
    torch.testing.assert_close(model.state_dict(), load_checkpoint(slim).state_dict())
    for bad in ("model.prior=none", "model.contact_inertia=exact", "contact_inertia", "model.residual_gate_linear=[",
                "model.contact_footprint=corners", "model.sim_seconds=-1", "model.contact_substeps=0"):
        with pytest.raises(ConfigError):
            export_checkpoint(full, tmp_path / "bad.ckpt", settings=[bad])
    assert not (tmp_path / "bad.ckpt").exists()


def test_trainer_keys_physdyn_sets_itself_are_refused_by_name(tiny_store, tmp_path):
    from physdyn.models.trainer_setup import RESERVED_TRAINER_KEYS

    for key in RESERVED_TRAINER_KEYS:
        with pytest.raises(ConfigError, match=f"trainer.{key}"):
            fit(load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path / key, f"trainer.{key}=1")))
        assert not (tmp_path / key).exists()


def test_early_stopping_ends_a_run_that_stops_improving(quickstart_config):
    # An improvement must exceed 1.0 in loss to count, so patience 1 stops the run after two rounds.
    run = fit(quickstart_config("trainer.max_steps=200", "trainer.val_check_interval=2", "early_stopping.enabled=true",
                                "early_stopping.patience=1", "early_stopping.min_delta=1.0"))
    steps = json.loads((run.out_dir / "finished.json").read_text())
    assert run.last_checkpoint is not None
    assert steps["global_step"] <= 6, steps  # rounds at steps 2 and 4: no improvement of 1.0, stop


def test_cpu_threads_sets_torchs_threads_for_the_run(quickstart_config):
    before = torch.get_num_threads()
    try:
        fit(quickstart_config("cpu_threads=1", "trainer.max_steps=1"))
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ConfigError, match="cpu_threads"):
        quickstart_config("cpu_threads=-2")


def test_last_checkpoint_is_the_last_step_even_when_validation_stopped_improving(quickstart_config):
    # Lightning's save_last copies a checkpoint only when val/loss improves: a run whose validation stopped
    # improving kept an old last.ckpt, and --resume went back to it. A learning rate of 1e-30 leaves the
    # float32 weights as they are, so validation never improves on its first check whatever the data.
    run = fit(quickstart_config("trainer.max_steps=12", "trainer.val_check_interval=3", "optim.lr=1e-30",
                                "optim.lr_min=1e-30", "optim.schedule=constant"))
    last = torch.load(run.last_checkpoint, map_location="cpu", weights_only=False)
    best = torch.load(run.best_checkpoint, map_location="cpu", weights_only=False)
    assert last["global_step"] == 12
    assert best["global_step"] < 12  # validation did stop improving: the case this test is about
