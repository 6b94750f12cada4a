"""The Lightning trainer a run uses: its arguments checked, its loggers (a CSV log that survives resuming,
TensorBoard), a progress display for terminals and plain lines for logs, and Lightning's noise quietened."""

from __future__ import annotations

import csv
import inspect
import logging
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from lightning import Trainer
from lightning.pytorch.callbacks import ProgressBar, TQDMProgressBar
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger
from lightning.pytorch.loggers.csv_logs import ExperimentWriter
from lightning.pytorch.loggers.logger import rank_zero_experiment
from lightning.pytorch.plugins import TorchCheckpointIO

from physdyn.errors import ConfigError
from physdyn.files import atomic_output
from physdyn.models.checkpoint_file import read_torch_file, write_torch_file

# Trainer arguments physdyn sets itself from other config keys.
RESERVED_TRAINER_KEYS = {
    "callbacks": "checkpointing and early stopping are configured by physdyn (see early_stopping.*)",
    "logger": "physdyn writes CSV and TensorBoard logs into out_dir",
    "default_root_dir": "set out_dir instead",
    "enable_checkpointing": "physdyn always writes best.ckpt and last.ckpt",
    "enable_progress_bar": "set progress_bar instead",
    "plugins": "physdyn reads checkpoints with its own plugin (docs/security.md)",
}


def trainer_argument_names() -> set[str]:
    return set(inspect.signature(Trainer.__init__).parameters) - {"self"}


def validate_trainer_args(trainer: dict[str, Any], section: str = "trainer") -> None:
    allowed = trainer_argument_names()
    for key in trainer:
        if key in RESERVED_TRAINER_KEYS:
            raise ConfigError(f"config key '{section}.{key}': not settable here; {RESERVED_TRAINER_KEYS[key]}")
        if key not in allowed:
            raise ConfigError(f"config key '{section}.{key}': not an argument of lightning.Trainer")


def _resumable_csv_logger(out_dir: Path, keep_until_step: int | None):
    """Lightning's CSV logger, except that a resumed run appends to its metrics.csv (Lightning's writer
    deletes the file on start): rows up to the checkpoint's step are kept, later ones (logged after the
    checkpoint, before the interruption) are dropped, as training repeats those steps."""

    class AppendingWriter(ExperimentWriter):
        def _check_log_dir_exists(self) -> None:
            path = Path(self.metrics_file_path)
            if keep_until_step is None or not path.is_file():
                return super()._check_log_dir_exists()
            with path.open(newline="") as file:
                reader = csv.DictReader(file)
                header, rows = list(reader.fieldnames or []), list(reader)
            rows = [r for r in rows if not r.get("step") or float(r["step"]) <= keep_until_step]
            with atomic_output(path, suffix=".csv") as tmp, tmp.open("w", newline="") as file:
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


def _progress_bar(stream=None):
    """Lightning's bar on a terminal; elsewhere (a log file, CI) one plain line every ``PLAIN_EVERY_S``
    seconds and after each validation, instead of hundreds of carriage-return updates."""

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


class SafeCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint files, read through ``read_torch_file``: resuming runs no code a checkpoint
    carries, whatever the installed Lightning defaults to (before 2.6 it loads with weights_only=False).

    And written through ``atomic_output``: Lightning's own "atomic" save stages the file in the system's
    temporary folder and then copies it over the checkpoint, so a full disk or a kill during the copy left a
    truncated last.ckpt (and an error naming the temporary file). Here the file is written beside its final
    name, synced, then renamed over it: a crash leaves the previous checkpoint, never half of a new one."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path, storage_options: Any | None = None) -> None:
        if storage_options is not None:
            raise TypeError("physdyn's checkpoint writer takes no storage_options")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_torch_file(checkpoint, path)

    def load_checkpoint(self, path, map_location=None, weights_only=None) -> dict[str, Any]:
        return read_torch_file(path, "a .ckpt written by `physdyn fit`")


def build_trainer(cfg_trainer: dict[str, Any], out_dir: Path, callbacks: list, progress_bar: bool, loggers: bool = True,
                  resumed_step: int | None = None):
    _drop_lightning_tips()

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
                enable_progress_bar=progress_bar, plugins=[SafeCheckpointIO()], **kwargs,
            )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"config key 'trainer': {str(exc).splitlines()[0]}") from None
    except Exception as exc:  # Lightning's MisconfigurationException and friends
        if type(exc).__name__.endswith("Exception") or "Misconfiguration" in type(exc).__name__:
            raise ConfigError(f"config key 'trainer': {str(exc).splitlines()[0]}") from None
        raise
