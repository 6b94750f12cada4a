"""Linear heads: state changes with a topple logit (the paper's), or without (the real-world model)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from physdyn.models.heads.base import NUM_CHANGES, PredictionHead
from physdyn.registry import HEADS


@HEADS.register("topple")
class ToppleHead(PredictionHead):
    """One linear layer to 12 state changes + 1 topple logit."""

    predicts_topple = True

    @dataclass
    class Config:
        pass

    def __init__(self, config: "ToppleHead.Config | None" = None, in_dim: int = 1024):
        super().__init__()
        self.linear = nn.Linear(in_dim, NUM_CHANGES + 1)

    def forward(self, features: torch.Tensor):
        out = self.linear(features)
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
        self.linear = nn.Linear(in_dim, NUM_CHANGES)

    def forward(self, features: torch.Tensor):
        return self.linear(features), None
