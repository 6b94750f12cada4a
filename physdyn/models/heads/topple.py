"""Linear heads: state changes with a topple logit (the paper's), or without (the real-world model)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from physdyn.models.heads.base import NUM_CHANGES, PredictionHead
from physdyn.registry import HEADS


def _linear(in_dim: int, out_dim: int) -> nn.Linear:
    """nn.Linear; on the 0 features of the ``none`` predictor (no network) its weight is empty and the head
    outputs its bias, zero at the start, without torch's warning that initialising an empty tensor does nothing."""
    if in_dim:
        return nn.Linear(in_dim, out_dim)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Initializing zero-element tensors")
        layer = nn.Linear(in_dim, out_dim)
    nn.init.zeros_(layer.bias)  # with no prior either, a network-less model then predicts no change
    return layer


@HEADS.register("topple")
class ToppleHead(PredictionHead):
    """One linear layer to 12 state changes + 1 topple logit.

    ``detach_topple``: the topple logit's loss trains its own row of the layer only, not the predictor
    under it. The paper's head (False) lets the topple cross-entropy shape the shared features; its
    gradient dwarfs that of the small velocity residuals on top of a prior, and a residual model then
    learns nothing of what its prior misses (docs/research/network-residual.md). The numbers the head computes
    are the same either way; only what the topple loss trains differs."""

    predicts_topple = True

    @dataclass
    class Config:
        detach_topple: bool = False

    def __init__(self, config: "ToppleHead.Config | None" = None, in_dim: int = 1024):
        super().__init__()
        self.config = config or self.Config()
        self.linear = _linear(in_dim, NUM_CHANGES + 1)

    def forward(self, features: torch.Tensor):
        out = self.linear(features)
        if self.config.detach_topple and torch.is_grad_enabled():
            row = slice(NUM_CHANGES, NUM_CHANGES + 1)
            return out[..., :NUM_CHANGES], F.linear(features.detach(), self.linear.weight[row], self.linear.bias[row])[..., 0]
        return out[..., :NUM_CHANGES], out[..., NUM_CHANGES]


@HEADS.register("no_topple")
class NoToppleHead(PredictionHead):
    """One linear layer to 12 state changes; no topple output (the paper's real-world model)."""

    predicts_topple = False

    @dataclass
    class Config:
        pass

    def __init__(self, config: "NoToppleHead.Config | None" = None, in_dim: int = 1024):
        super().__init__()
        self.linear = _linear(in_dim, NUM_CHANGES)

    def forward(self, features: torch.Tensor):
        return self.linear(features), None
