"""The optimiser and its learning-rate schedule, shared by dynamics training and encoder pretraining."""

from __future__ import annotations

import math
import warnings

import torch

from physdyn.config import OptimConfig
from physdyn.errors import ConfigError


def learning_rate_factor(
    schedule: str, step: int, total_steps: float, lr: float, lr_min: float, decay_rate: float = 0.75, decay_every_steps: float = 1.0
) -> float:
    """Multiplier of ``lr`` at optimiser step ``step``, never below ``lr_min / lr``.

    exponential: lr -> lr_min geometrically over ``total_steps`` (the planned steps);
    step: x ``decay_rate`` every ``decay_every_steps`` steps (the paper's 0.75 per 300,000 sequences);
    constant: 1.
    """
    floor = lr_min / lr
    if schedule == "exponential":
        return max(floor ** (min(step, total_steps) / total_steps), floor)
    if schedule == "step":
        return max(decay_rate ** math.floor(step / decay_every_steps), floor)
    return 1.0


def adam_with_schedule(parameters, o: OptimConfig, total_steps: float, samples_per_step: int):
    """Adam and its per-step learning-rate schedule (``learning_rate_factor``), for ``configure_optimizers``
    of the dynamics model and of encoder pretraining alike."""
    if o.lr <= 0 or o.lr_min <= 0 or o.lr_min > o.lr:
        raise ConfigError(f"config key 'optim.lr_min': need 0 < lr_min <= lr, got lr={o.lr}, lr_min={o.lr_min}")
    optimizer = torch.optim.Adam(parameters, lr=o.lr, weight_decay=o.weight_decay)
    if o.schedule not in ("exponential", "step", "constant"):
        raise ConfigError(f"config key 'optim.schedule': unknown '{o.schedule}'; use exponential, step or constant")
    if o.schedule == "constant":
        return optimizer
    if o.schedule == "exponential" and not (math.isfinite(total_steps) and total_steps > 0):
        warnings.warn("no planned step count (set trainer.max_steps or max_epochs); the learning rate stays constant", stacklevel=3)
        return optimizer
    factor = lambda step: learning_rate_factor(  # noqa: E731
        o.schedule, step, total_steps, o.lr, o.lr_min, o.decay_rate, o.decay_samples / samples_per_step)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, factor)
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
