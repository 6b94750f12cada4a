"""`physdyn fit`: train a DynamicsModel on a store, with checkpoints, logs and resumption.

A run directory (``out_dir``, default ``runs/<name>``) holds ``config.yaml`` (the resolved config),
``best.ckpt`` (lowest ``val/loss``), ``last.ckpt``, ``csv/metrics.csv``, ``tensorboard/`` and, once training
ends, ``finished.json``. An existing run directory is never overwritten silently: continue it with
``resume=True`` (``--resume``) or replace it with ``overwrite=True`` (``--overwrite``).
"""

from __future__ import annotations

import inspect
import json
import logging
import os
import shutil
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf

from physdyn.config import ExperimentConfig, load_config, to_dict
from physdyn.data.normalization import NORMALIZATION_MODES
from physdyn.models.losses import LOSS_KINDS
from physdyn.models.priors import CONTACT_INERTIA, PRIORS, SHAPE_PRIORS
from physdyn.data.store import StoreData
from physdyn.errors import ConfigError, PhysdynError
from physdyn.registry import ENCODERS, HEADS, PREDICTORS

# Trainer arguments physdyn sets itself from other config keys.
RESERVED_TRAINER_KEYS = {
    "callbacks": "checkpointing and early stopping are configured by physdyn (see early_stopping.*)",
    "logger": "physdyn writes CSV and TensorBoard logs into out_dir",
    "default_root_dir": "set out_dir instead",
    "enable_checkpointing": "physdyn always writes best.ckpt and last.ckpt",
    "enable_progress_bar": "set progress_bar instead",
}
FINISHED = "finished.json"


@dataclass
class FitResult:
    best_checkpoint: Path | None  # <out_dir>/best.ckpt (lowest val/loss)
    last_checkpoint: Path | None  # <out_dir>/last.ckpt
    out_dir: Path
    metrics: dict[str, float] = field(default_factory=dict)  # final logged values, plus best_val_loss


def trainer_argument_names() -> set[str]:
    from lightning import Trainer

    return set(inspect.signature(Trainer.__init__).parameters) - {"self"}


def validate_trainer_args(trainer: dict[str, Any], section: str = "trainer") -> None:
    allowed = trainer_argument_names()
    for key in trainer:
        if key in RESERVED_TRAINER_KEYS:
            raise ConfigError(f"config key '{section}.{key}': not settable here; {RESERVED_TRAINER_KEYS[key]}")
        if key not in allowed:
            raise ConfigError(f"config key '{section}.{key}': not an argument of lightning.Trainer")


def validate_experiment_config(cfg: ExperimentConfig) -> ExperimentConfig:
    """Check what the schema cannot: component params against their registries, choices, trainer keys."""
    m = cfg.model
    for section, registry, comp in (("encoder", ENCODERS, m.encoder), ("predictor", PREDICTORS, m.predictor), ("head", HEADS, m.head)):
        if not comp.name:
            raise ConfigError(f"config key 'model.{section}.name': missing; registered: {', '.join(registry.names())}")
        registry.resolve_config(comp.name, comp.params, f"model.{section}.params", name_key=f"model.{section}.name")
    choices = (("loss.kind", cfg.loss.kind, LOSS_KINDS), ("model.prior", m.prior, PRIORS),
               ("model.contact_inertia", m.contact_inertia, CONTACT_INERTIA),
               ("data.normalization", cfg.data.normalization, NORMALIZATION_MODES))
    for key, value, allowed in choices:
        if value not in allowed:
            raise ConfigError(f"config key '{key}': '{value}' is not one of {', '.join(allowed)}")
    for key in ("residual_gate_linear", "residual_gate_angular"):
        value = getattr(m, key)
        if not (value >= 0 and np.isfinite(value)):
            raise ConfigError(f"config key 'model.{key}': a speed >= 0, got {value}")
    if m.prior in SHAPE_PRIORS and not m.orientation_input:
        raise ConfigError(f"config key 'model.prior': '{m.prior}' turns the footprint with the object; set model.orientation_input=true")
    for key, value in (("rollout.feedback", cfg.rollout.feedback), ("data.first_window_fraction", cfg.data.first_window_fraction)):
        if not 0.0 <= value <= 1.0:
            raise ConfigError(f"config key '{key}': a probability between 0 and 1, got {value}")
    if not 0.0 <= cfg.rollout.input_noise < 1.0:
        raise ConfigError(f"config key 'rollout.input_noise': a std in normalised units in [0, 1), got {cfg.rollout.input_noise}")
    if not cfg.loss.huber_delta > 0:
        raise ConfigError(f"config key 'loss.huber_delta': must be positive, got {cfg.loss.huber_delta}")
    if cfg.optim.schedule not in ("exponential", "step", "constant"):
        raise ConfigError(f"config key 'optim.schedule': '{cfg.optim.schedule}' is not exponential, step or constant")
    if not 0 < cfg.optim.lr_min <= cfg.optim.lr:
        raise ConfigError(f"config key 'optim.lr_min': need 0 < lr_min <= lr, got lr_min={cfg.optim.lr_min}, lr={cfg.optim.lr}")
    for key in ("window", "batch_size", "val_windows_per_sim"):
        if getattr(cfg.data, key) < 1:
            raise ConfigError(f"config key 'data.{key}': must be at least 1, got {getattr(cfg.data, key)}")
    if cfg.data.num_workers < 0:
        raise ConfigError(f"config key 'data.num_workers': must be >= 0, got {cfg.data.num_workers}")
    validate_trainer_args(cfg.trainer)
    return cfg


def _median_friction(friction: np.ndarray, default: float = 0.25) -> float:
    """The friction the Coulomb prior assumes; imported trials may record none (NaN): the conventions' 0.25."""
    known = friction[np.isfinite(friction)]
    return float(np.median(known)) if len(known) else default


def load_experiment_config(path: str | Path | None, overrides: list[str] | None = None) -> ExperimentConfig:
    """Load a preset with ``key=value`` overrides and validate it; errors are one-line ConfigErrors."""
    return validate_experiment_config(load_config(ExperimentConfig, path, overrides))


def run_directory(cfg: ExperimentConfig | Any) -> Path:
    return Path(cfg.out_dir) if cfg.out_dir else Path("runs") / cfg.name


def is_global_zero_process() -> bool:
    """False in the extra processes of a multi-process run (Lightning/torchrun set these variables)."""
    return all(int(os.environ.get(k, "0") or 0) == 0 for k in ("LOCAL_RANK", "NODE_RANK", "RANK"))


RUN_ENTRIES = {"config.yaml", "best.ckpt", "last.ckpt", FINISHED, "csv", "tensorboard", "encoder.pt", "lightning_logs"}


def looks_like_a_run(out_dir: Path) -> bool:
    """Whether a folder was written by `physdyn fit`/`pretrain`: its config.yaml and nothing but run
    artefacts (benchmark scripts may add their own ``*.json`` beside them)."""
    names = {p.name for p in out_dir.iterdir()}
    return "config.yaml" in names and all(n in RUN_ENTRIES or n.endswith((".json", ".ckpt", ".pt")) for n in names)


def prepare_run_directory(out_dir: Path, resume: bool, overwrite: bool, what: str = "physdyn fit",
                          resumable: bool = True) -> None:
    """Refuse to reuse a run directory unless asked; only the first process of a run touches it.
    ``what`` (the command) and ``resumable`` (whether it has --resume) shape the advice in the errors."""
    if not is_global_zero_process():
        return
    if out_dir.exists() and any(out_dir.iterdir()):
        if overwrite:
            if not looks_like_a_run(out_dir):  # --overwrite replaces a run, never a folder of the user's
                example = sorted(p.name for p in out_dir.iterdir())[0]
                raise PhysdynError(
                    f"{out_dir} holds files that are not a physdyn run (e.g. {example}); --overwrite only replaces "
                    f"run directories: choose another name=... or out_dir=..."
                )
            shutil.rmtree(out_dir)
        elif not resume:
            if (out_dir / FINISHED).exists():
                raise PhysdynError(
                    f"{out_dir} holds a finished run; pass --overwrite to replace it, or choose another "
                    f"name=... or out_dir=..."
                )
            if not resumable:
                raise PhysdynError(f"{out_dir} holds an earlier {what} run; pass --overwrite to start over, or "
                                   f"choose another out_dir=...")
            raise PhysdynError(
                f"{out_dir} holds an interrupted run; pass --resume to continue it or --overwrite to start over"
            )
    out_dir.mkdir(parents=True, exist_ok=True)


# Keys a resumed run may change: how long it trains and how it reports, not what it learns.
RESUMABLE_KEYS = ("trainer.max_steps", "trainer.max_epochs", "trainer.val_check_interval", "progress_bar", "cpu_threads",
                  "data.num_workers", "ckpt_path", "out_dir")


def _flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for key, value in tree.items():
            out.update(_flatten(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: tree}


def check_resumed_config(cfg: Any, saved_yaml: Path) -> None:
    """Refuse to resume a run with a config that changes what it learns; names the keys that differ."""
    if not saved_yaml.is_file():
        return
    saved = _flatten(OmegaConf.to_container(OmegaConf.load(saved_yaml)))
    now = _flatten(to_dict(cfg))
    changed = sorted(k for k in set(saved) | set(now)
                     if saved.get(k) != now.get(k) and not k.startswith(RESUMABLE_KEYS))
    if changed:
        shown = ", ".join(f"{k} ({saved.get(k)!r} -> {now.get(k)!r})" for k in changed[:4])
        more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
        raise PhysdynError(
            f"--resume: the config differs from {saved_yaml} in {shown}{more}; resume with the run's own config "
            f"(only {', '.join(RESUMABLE_KEYS[:3])} and logging may change) or start a new run (name=...)"
        )


def _resumable_csv_logger(out_dir: Path, keep_until_step: int | None):
    """Lightning's CSV logger, except that a resumed run appends to its metrics.csv (Lightning's writer
    deletes the file on start): rows up to the checkpoint's step are kept, later ones (logged after the
    checkpoint, before the interruption) are dropped, as training repeats those steps."""
    import csv

    from lightning.pytorch.loggers import CSVLogger
    from lightning.pytorch.loggers.csv_logs import ExperimentWriter
    from lightning.pytorch.loggers.logger import rank_zero_experiment

    class AppendingWriter(ExperimentWriter):
        def _check_log_dir_exists(self) -> None:
            path = Path(self.metrics_file_path)
            if keep_until_step is None or not path.is_file():
                return super()._check_log_dir_exists()
            with path.open(newline="") as file:
                reader = csv.DictReader(file)
                header, rows = list(reader.fieldnames or []), list(reader)
            rows = [r for r in rows if not r.get("step") or float(r["step"]) <= keep_until_step]
            with path.open("w", newline="") as file:
                writer = csv.DictWriter(file, fieldnames=header)
                writer.writeheader()
                writer.writerows(rows)
            self.metrics_keys = sorted(header)

    class ResumableCSVLogger(CSVLogger):
        @property
        @rank_zero_experiment
        def experiment(self):
            if self._experiment is None:
                self._fs.makedirs(self.root_dir, exist_ok=True)
                self._experiment = AppendingWriter(log_dir=self.log_dir)
            return self._experiment

    return ResumableCSVLogger(out_dir, name="", version="csv")


def save_config_yaml(cfg: Any, path: Path) -> None:
    if is_global_zero_process():
        path.write_text(OmegaConf.to_yaml(OmegaConf.create(to_dict(cfg))))


def _read_checkpoint(path: Path) -> dict:
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:
        raise PhysdynError(f"cannot read checkpoint {path}: {type(exc).__name__}: {exc}") from None
    if not isinstance(ckpt, dict):
        raise PhysdynError(f"{path} is not a checkpoint of `physdyn fit`; pass a .ckpt it wrote")
    return ckpt


def _progress_bar(stream=None):
    """Lightning's bar on a terminal; elsewhere (a log file, CI) one plain line every ``PLAIN_EVERY_S``
    seconds and after each validation, instead of hundreds of carriage-return updates."""
    import sys

    from lightning.pytorch.callbacks import ProgressBar, TQDMProgressBar

    stream = stream or sys.stderr
    if hasattr(stream, "isatty") and stream.isatty():
        class TerminalBar(TQDMProgressBar):
            """Lightning's bar without the logger version ("v_num"), which means nothing for a named run."""

            def get_metrics(self, trainer, pl_module):
                metrics = super().get_metrics(trainer, pl_module)
                metrics.pop("v_num", None)
                return metrics

        return TerminalBar()

    class PlainLines(ProgressBar):
        def __init__(self):
            super().__init__()
            self._enabled, self._last, self._start, self._first = True, 0.0, 0.0, 0

        def disable(self):
            self._enabled = False

        def enable(self):
            self._enabled = True

        def on_train_start(self, trainer, pl_module):
            self._start = self._last = time.monotonic()
            self._first = trainer.global_step

        def _line(self, trainer, extra: str = "") -> None:
            if not self._enabled or trainer.sanity_checking:
                return
            step, total = trainer.global_step, trainer.max_steps
            rate = (step - self._first) / max(time.monotonic() - self._start, 1e-9)
            parts = [f"fit: step {step}" + (f"/{total} ({100 * step / total:.0f} %)" if total and total > 0 else "")]
            loss = trainer.callback_metrics.get("train/loss")
            if loss is not None:
                parts.append(f"train/loss {float(loss):.4g}")
            if extra:
                parts.append(extra)
            if rate > 0:
                parts.append(f"{rate:.2f} steps/s")
                if total and total > 0 and step < total:
                    parts.append(f"about {(total - step) / rate / 60:.1f} min left")
            print(", ".join(parts), file=stream, flush=True)
            self._last = time.monotonic()

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            if time.monotonic() - self._last >= PLAIN_EVERY_S:
                self._line(trainer)

        def on_validation_end(self, trainer, pl_module):
            val = trainer.callback_metrics.get("val/loss")
            self._line(trainer, "" if val is None else f"val/loss {float(val):.4g}")

        def on_train_end(self, trainer, pl_module):
            self._line(trainer, "done")

    return PlainLines()


PLAIN_EVERY_S = 30.0


# Lightning prints these on every run; over a 44-run `physdyn reproduce` log they bury the progress lines.
# Both are about Lightning itself (its cloud logger, its own use of a torch API), not about the user's run.
LIGHTNING_NOISE = ("litlogger", "`isinstance(treespec, LeafSpec)` is deprecated")


class _DropLightningNoise(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not any(text in record.getMessage() for text in LIGHTNING_NOISE)


def ignore_lightning_noise() -> None:
    """Inside ``warnings.catch_warnings()``: drop Lightning's per-run tip and torch deprecation warning."""
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*", category=FutureWarning)


def _drop_lightning_tips() -> None:
    # Lightning logs rank-zero messages through whichever of these loggers was imported last.
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
        target = logging.getLogger(name)
        if not any(isinstance(f, _DropLightningNoise) for f in target.filters):
            target.addFilter(_DropLightningNoise())


def build_trainer(cfg_trainer: dict[str, Any], out_dir: Path, callbacks: list, progress_bar: bool, loggers: bool = True,
                  resumed_step: int | None = None):
    from lightning import Trainer

    _drop_lightning_tips()
    from lightning.pytorch.loggers import TensorBoardLogger

    validate_trainer_args(cfg_trainer)
    kwargs = {"log_every_n_steps": 10, **cfg_trainer}
    callbacks = list(callbacks) + ([_progress_bar()] if progress_bar else [])
    logger: Any = False
    if loggers:
        logger = [_resumable_csv_logger(out_dir, resumed_step), TensorBoardLogger(out_dir, name="", version="tensorboard")]
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*tensorboardX.*")
            warnings.filterwarnings("ignore", message=".*exists and is not empty.*")
            return Trainer(
                default_root_dir=str(out_dir), callbacks=callbacks, logger=logger,
                enable_progress_bar=progress_bar, **kwargs,
            )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"config key 'trainer': {str(exc).splitlines()[0]}") from None
    except Exception as exc:  # Lightning's MisconfigurationException and friends
        if type(exc).__name__.endswith("Exception") or "Misconfiguration" in type(exc).__name__:
            raise ConfigError(f"config key 'trainer': {str(exc).splitlines()[0]}") from None
        raise


def fit(config: ExperimentConfig, resume: bool = False, overwrite: bool = False, store: StoreData | None = None) -> FitResult:
    """Train a DynamicsModel as ``config`` says; see the module docstring for the run directory.

    ``resume`` continues from ``<out_dir>/last.ckpt`` (``config.ckpt_path`` from that checkpoint instead);
    ``store`` skips reading ``config.data.store`` again (tests, notebooks).
    """
    import lightning
    from lightning.pytorch.callbacks import EarlyStopping, LearningRateMonitor, ModelCheckpoint

    from physdyn.data.datamodule import DynamicsDataModule
    from physdyn.models.dynamics_module import DynamicsModel

    cfg = validate_experiment_config(config)
    out_dir = run_directory(cfg)
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
        saved_ckpt = _read_checkpoint(ckpt_path)
        resumed_step = int(saved_ckpt.get("global_step", 0)) if resume else None
        saved = saved_ckpt.get("hyper_parameters", {}).get("normalization")
        if saved:
            from physdyn.data.normalization import Normalization

            normalization = Normalization.from_dict(saved)
    data_info = {
        "store": str(cfg.data.store),
        "rate_hz": datamodule.rate_hz,
        "window": cfg.data.window,
        "num_points": cfg.data.num_points,
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
    # Only now, with every input checked, is the run directory touched (created, or replaced on --overwrite).
    prepare_run_directory(out_dir, resume=resume or ckpt_path is not None, overwrite=overwrite and ckpt_path is None)
    out_dir.mkdir(parents=True, exist_ok=True)
    save_config_yaml(cfg, out_dir / "config.yaml")

    checkpoint = ModelCheckpoint(
        dirpath=out_dir, filename="best", monitor="val/loss", mode="min", save_top_k=1, save_last=True,
        auto_insert_metric_name=False, enable_version_counter=False,
    )
    callbacks: list = [checkpoint, LearningRateMonitor(logging_interval="step")]
    es = cfg.early_stopping
    if es.enabled:
        callbacks.append(EarlyStopping(monitor="val/loss", mode="min", patience=es.patience, min_delta=es.min_delta, check_on_train_epoch_end=False))
    trainer = build_trainer(cfg.trainer, out_dir, callbacks, cfg.progress_bar, resumed_step=resumed_step)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*exists and is not empty.*")
        warnings.filterwarnings("ignore", message=".*smaller than the logging interval.*")
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
    if checkpoint.best_model_score is not None:
        metrics["best_val_loss"] = float(checkpoint.best_model_score)
    best = out_dir / "best.ckpt"
    last = out_dir / "last.ckpt"
    if trainer.is_global_zero:
        (out_dir / FINISHED).write_text(json.dumps({"metrics": metrics, "global_step": trainer.global_step}, indent=2))
    return FitResult(best if best.is_file() else None, last if last.is_file() else None, out_dir, metrics)
