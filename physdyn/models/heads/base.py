"""The interface every output head implements (built-in or from a plugin)."""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch
from torch import nn

NUM_CHANGES = 12  # [dv (3), dw (3), dp (3), dtheta (3)], normalised


class PredictionHead(nn.Module, ABC):
    """Maps predictor features to the 12 normalised state changes and, optionally, a topple logit.

    Subclasses register with ``@HEADS.register("name")``, define a dataclass ``Config`` and take
    ``(config, in_dim)`` in ``__init__``. ``predicts_topple`` says whether the logit is produced.
    """

    predicts_topple: bool = False

    @abstractmethod
    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """features: (B, T, in_dim) -> (changes (B, T, 12), topple logit (B, T) or None)."""
