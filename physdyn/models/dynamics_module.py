"""The LightningModule that ``physdyn fit`` trains: ``DynamicsNetwork`` (``physdyn.models.dynamics_network``:
shape encoder + state predictor + head, its prior, roll-outs and loss) with Lightning's training, validation
and test steps, logging and optimiser.

Its checkpoints hold the network's config and normalisation in their hyper-parameters, so
``DynamicsModel.load_from_checkpoint(path)`` restores it for training; prediction and evaluation load them into
the plain ``DynamicsNetwork`` (``physdyn.eval.baselines.load_checkpoint``), without importing Lightning.
"""

from __future__ import annotations

import math

import torch
from lightning import LightningModule

from physdyn.errors import ConfigError
from physdyn.models.dynamics_network import DynamicsNetwork, DynamicsPrediction  # noqa: F401 - DynamicsPrediction's old home
from physdyn.models.optimizer import adam_with_schedule


class DynamicsModel(DynamicsNetwork, LightningModule):
    """A ``DynamicsNetwork`` trained by Lightning (the arguments are the network's)."""

    # Lightning's own record and device, not the plain network's: its loggers, checkpoints and strategies use them
    hparams = LightningModule.hparams
    device = LightningModule.device

    def _keep_hyperparameters(self, values: dict) -> None:
        self.save_hyperparameters(values)

    def on_fit_start(self) -> None:
        if self.linear_channels is not None:
            raise ConfigError("this model combines two networks (export --linear-from) and is for predictions only; "
                              "train each of them on its own with `physdyn fit`")

    def _log_terms(self, prefix: str, out, batch_size: int, on_step: bool) -> None:
        sync = prefix != "train"
        self.log(f"{prefix}/loss", out.total, prog_bar=True, on_step=on_step, on_epoch=True, batch_size=batch_size, sync_dist=sync)
        for name, value in out.terms.items():
            self.log(f"{prefix}/{name}", value, on_step=False, on_epoch=True, batch_size=batch_size, sync_dist=sync)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        out = self.compute_loss(batch)
        self._log_terms("train", out, len(batch["sim"]), on_step=True)
        return out.total

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        self._log_terms("val", self.compute_loss(batch), len(batch["sim"]), on_step=False)

    def test_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        self._log_terms("test", self.compute_loss(batch), len(batch["sim"]), on_step=False)

    def configure_optimizers(self):
        total = float(self.trainer.estimated_stepping_batches) if self._trainer is not None else math.inf
        world = self.trainer.world_size if self._trainer is not None else 1
        return adam_with_schedule(self.parameters(), self.config.optim, total, self.config.data.batch_size * world)
