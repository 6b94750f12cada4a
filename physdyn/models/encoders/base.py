"""The interface every shape encoder implements (built-in or from a plugin)."""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch
from torch import nn


class ShapeEncoder(nn.Module, ABC):
    """Reads a point cloud once per sequence and returns a shape feature.

    Subclasses register with ``@ENCODERS.register("name")``, define a dataclass ``Config`` (their typed
    hyper-parameters) and take it as the first argument of ``__init__``. They must set ``self.out_dim``.
    """

    out_dim: int

    @abstractmethod
    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points: (B, N, 3) float32, world-oriented body frame (centred at the centre of mass)
        -> (B, out_dim) shape feature."""
