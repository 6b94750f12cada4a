"""`physdyn fit`: train a DynamicsModel on a store, with checkpoints, logs and resumption.

A run directory (``out_dir``, default ``runs/<name>``) holds ``config.yaml`` (the resolved config),
``best.ckpt`` (lowest ``val/loss``), ``last.ckpt``, ``csv/metrics.csv``, ``tensorboard/`` and, once training
ends, ``finished.json``. An existing run directory is never overwritten silently: continue it with
``resume=True`` (``--resume``) or replace it with ``overwrite=True`` (``--overwrite``).
"""

from __future__ import annotations

import contextlib
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import lightning
import numpy as np
import torch
from lightning.pytorch.callbacks import EarlyStopping, LearningRateMonitor, ModelCheckpoint

from physdyn.config import ExperimentConfig, load_config
from physdyn.data.datamodule import DynamicsDataModule
from physdyn.data.normalization import Normalization
from physdyn.models.checkpoint_file import read_checkpoint
from physdyn.models.experiment_checks import check_experiment_config
from physdyn.data.store import StoreData
from physdyn.errors import ConfigError, PhysdynError
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.run_directory import (
    FINISHED, check_resumed_config, is_global_zero_process, prepare_run_directory, run_directory, save_config_yaml,
)
from physdyn.models.trainer_setup import build_trainer, ignore_lightning_noise, validate_trainer_args
from physdyn.write_lock import refuse_if_busy, write_lock
from physdyn.files import remove_stale_temporaries, write_text_atomic


@dataclass
class FitResult:
    best_checkpoint: Path | None  # <out_dir>/best.ckpt (lowest val/loss)
    last_checkpoint: Path | None  # <out_dir>/last.ckpt
    out_dir: Path
    metrics: dict[str, float] = field(default_factory=dict)  # final logged values, plus best_val_loss


def validate_experiment_config(cfg: ExperimentConfig) -> ExperimentConfig:
    """Check what the schema cannot: component params against their registries, choices, ranges
    (``check_experiment_config``), and the trainer's keys against Lightning's Trainer."""
    check_experiment_config(cfg)
    validate_trainer_args(cfg.trainer)
    return cfg


def _median_friction(friction: np.ndarray, default: float = 0.25) -> float:
    """The friction the Coulomb prior assumes; imported trials may record none (NaN): the conventions' 0.25."""
    known = friction[np.isfinite(friction)]
    return float(np.median(known)) if len(known) else default


def load_experiment_config(path: str | Path | None, overrides: list[str] | None = None) -> ExperimentConfig:
    """Load a preset with ``key=value`` overrides and validate it; errors are one-line ConfigErrors."""
    return validate_experiment_config(load_config(ExperimentConfig, path, overrides))


def fit(config: ExperimentConfig, resume: bool = False, overwrite: bool = False, store: StoreData | None = None) -> FitResult:
    """Train a DynamicsModel as ``config`` says; see the module docstring for the run directory.

    ``resume`` continues from ``<out_dir>/last.ckpt`` (``config.ckpt_path`` from that checkpoint instead);
    ``store`` skips reading ``config.data.store`` again (tests, notebooks).
    """

    cfg = validate_experiment_config(config)
    out_dir = run_directory(cfg)
    if is_global_zero_process():
        refuse_if_busy(out_dir)  # another fit on this folder: say so now, not after loading the store
    ckpt_path: Path | None = Path(cfg.ckpt_path) if cfg.ckpt_path else None
    if ckpt_path is None and resume:
        ckpt_path = out_dir / "last.ckpt"
        if not ckpt_path.is_file():
            raise PhysdynError(f"--resume: no {ckpt_path} to continue from; start the run without --resume")
    if ckpt_path is not None and not ckpt_path.is_file():
        raise ConfigError(f"config key 'ckpt_path': no checkpoint at {ckpt_path}")
    lightning.seed_everything(cfg.seed, workers=True, verbose=False)
    if cfg.cpu_threads > 0:
        torch.set_num_threads(int(cfg.cpu_threads))
    datamodule = DynamicsDataModule(cfg.data, store=store)
    datamodule.setup("fit")  # before touching out_dir: a bad store or category leaves an old run intact
    if resume and is_global_zero_process():
        check_resumed_config(cfg, out_dir / "config.yaml")
    normalization = datamodule.normalization
    resumed_step = None
    if ckpt_path is not None:  # keep the scales the run started with
        saved_ckpt = read_checkpoint(ckpt_path)
        resumed_step = int(saved_ckpt.get("global_step", 0)) if resume else None
        saved = saved_ckpt.get("hyper_parameters", {}).get("normalization")
        if saved:
            normalization = Normalization.from_dict(saved)
    data_info = {
        "store": str(cfg.data.store),
        "rate_hz": datamodule.rate_hz,
        "window": cfg.data.window,
        "num_points": cfg.data.num_points or int(datamodule.store.points.shape[1]),  # what the model sees
        # how the store's clouds were made: predict must make a new mesh's cloud the same way
        "points_method": datamodule.store.points_method,
        "category_names": list(datamodule.store.category_names),
        "train_sims": int(len(datamodule.sims.train)),
        # for model.prior: the training data's friction (median: a random-friction store has many) and gravity
        "friction": _median_friction(datamodule.store.friction[datamodule.sims.train]),
        "gravity": abs(float(datamodule.store.attrs.get("physics", {}).get("gravity", -9.81))),
        "val_on_train": bool(datamodule.val_uses_train),
    }
    model = DynamicsModel(cfg, normalization, data_info)
    if cfg.model.encoder_init and ckpt_path is None:
        model.load_encoder_weights(cfg.model.encoder_init)
    # Only now, with every input checked, is the run directory touched: under the writer's lock, so a second
    # `fit` on the same folder (--resume or not) is refused naming the first. Other ranks of a multi-process
    # run write nothing there and take no lock.
    with write_lock(out_dir) if is_global_zero_process() else contextlib.nullcontext():
        return _train(cfg, out_dir, model, datamodule, ckpt_path, resume, overwrite, resumed_step)


def _train(cfg: ExperimentConfig, out_dir: Path, model: DynamicsModel, datamodule: DynamicsDataModule,
           ckpt_path: Path | None, resume: bool, overwrite: bool, resumed_step: int | None) -> FitResult:
    prepare_run_directory(out_dir, resume=resume or ckpt_path is not None, overwrite=overwrite and ckpt_path is None)
    out_dir.mkdir(parents=True, exist_ok=True)
    if is_global_zero_process():  # the lock's holder: no other writer's temporary file can be in use
        remove_stale_temporaries(out_dir, ("best.ckpt", "last.ckpt", "config.yaml", FINISHED))  # a killed run's
    save_config_yaml(cfg, out_dir / "config.yaml")

    checkpoint = ModelCheckpoint(
        dirpath=out_dir, filename="best", monitor="val/loss", mode="min", save_top_k=1,
        auto_insert_metric_name=False, enable_version_counter=False,
    )
    # Lightning's save_last copies a checkpoint only when one is saved, i.e. when val/loss improves: a run
    # whose validation stopped improving kept a stale last.ckpt, and --resume went back to that step. This
    # one is written at every validation (and once more when training ends, below).
    latest = ModelCheckpoint(dirpath=out_dir, filename="last", monitor=None, save_top_k=1, save_on_train_epoch_end=False,
                             auto_insert_metric_name=False, enable_version_counter=False)
    callbacks: list = [checkpoint, latest, LearningRateMonitor(logging_interval="step")]
    es = cfg.early_stopping
    if es.enabled:
        callbacks.append(EarlyStopping(monitor="val/loss", mode="min", patience=es.patience, min_delta=es.min_delta, check_on_train_epoch_end=False))
    trainer = build_trainer(cfg.trainer, out_dir, callbacks, cfg.progress_bar, resumed_step=resumed_step)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*exists and is not empty.*")
        warnings.filterwarnings("ignore", message=".*smaller than the logging interval.*")
        if trainer.limit_val_batches:
            # A resumed run reaches an epoch's end before its first validation; best.ckpt's callback then finds
            # no val/loss, keeps the best it restored and says "did you call log('val/loss')?" (Lightning raises
            # instead once a validation has run, so a real missing metric is still caught). With validation
            # switched off the hint stays: it is then the only sign (and the warning below follows).
            warnings.filterwarnings("ignore", message=r".*monitor='val/loss'\)` could not find the monitored key.*")
        ignore_lightning_noise()
        trainer.fit(model, datamodule=datamodule, ckpt_path=str(ckpt_path) if ckpt_path else None)
    scalar = lambda d: {k: float(v) for k, v in d.items() if torch.is_tensor(v) and v.numel() == 1}  # noqa: E731
    metrics = scalar(trainer.callback_metrics)
    if not checkpoint.best_model_path and not trainer.interrupted:
        # Training stopped before any validation (max_steps inside the first epoch): validate once so the
        # run still has a best.ckpt with a val/loss.
        with warnings.catch_warnings():
            ignore_lightning_noise()
            trainer.validate(model, datamodule=datamodule, verbose=False)
        trainer.save_checkpoint(out_dir / "best.ckpt")
        metrics.update(scalar(trainer.callback_metrics))
        if "val/loss" in trainer.callback_metrics:
            checkpoint.best_model_score = trainer.callback_metrics["val/loss"]
        else:
            warnings.warn("no validation ran (an empty validation split or trainer.limit_val_batches=0): best.ckpt "
                          "holds the last weights, not the best", stacklevel=2)
    if not trainer.interrupted:
        trainer.save_checkpoint(out_dir / "last.ckpt")  # with the steps after the last validation
    if checkpoint.best_model_score is not None:
        metrics["best_val_loss"] = float(checkpoint.best_model_score)
    best = out_dir / "best.ckpt"
    last = out_dir / "last.ckpt"
    if trainer.is_global_zero:
        write_text_atomic(out_dir / FINISHED, json.dumps({"metrics": metrics, "global_step": trainer.global_step}, indent=2))
    return FitResult(best if best.is_file() else None, last if last.is_file() else None, out_dir, metrics)
