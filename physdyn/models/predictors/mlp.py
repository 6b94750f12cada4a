"""The paper's MLP baseline: fully connected layers applied to every step on its own (no memory)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from physdyn.models.predictors.base import StatePredictor
from physdyn.registry import PREDICTORS


@PREDICTORS.register("mlp")
class MLPPredictor(StatePredictor):
    """Per-step MLP with tanh (supplement 4.4: 5 x 1,024, no batch norm); its state is always None."""

    @dataclass
    class Config:
        num_layers: int = 5
        hidden: int = 1024

    def __init__(self, config: "MLPPredictor.Config | None" = None, input_dim: int = 22):
        super().__init__()
        self.config = config = config or self.Config()
        layers: list[nn.Module] = []
        width = input_dim
        for _ in range(config.num_layers):
            layers += [nn.Linear(width, config.hidden), nn.Tanh()]
            width = config.hidden
        self.mlp = nn.Sequential(*layers)
        self.out_dim = width

    def forward(self, inputs: torch.Tensor, state=None):
        return self.mlp(inputs), None
