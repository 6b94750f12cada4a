"""The interface every state predictor implements (built-in or from a plugin)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import torch
from torch import nn


class StatePredictor(nn.Module, ABC):
    """Maps per-step inputs [v, w, shape feature] to per-step features, carrying a recurrent state.

    Subclasses register with ``@PREDICTORS.register("name")``, define a dataclass ``Config`` and take
    ``(config, input_dim)`` in ``__init__``; they must set ``self.out_dim``. The same ``forward`` serves a
    whole window and a step-by-step roll-out: feeding a window at once, or its steps one at a time with the
    returned state passed back in, gives the same features.
    """

    out_dim: int

    @abstractmethod
    def forward(self, inputs: torch.Tensor, state: Any = None) -> tuple[torch.Tensor, Any]:
        """inputs: (B, T, input_dim); state: from the previous call, or None to start from zero
        -> (features (B, T, out_dim), new state)."""
