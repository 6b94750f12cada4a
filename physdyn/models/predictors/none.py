"""No network: the model's prior alone (``model.prior``, e.g. the contact prior), with nothing learned on top.

A model built with it rolls out its analytic prior exactly, at the prior's cost: the planner screens
thousands of candidate pushes with it (docs/plan.md), and benchmarks score the prior through the same path
as a trained model. Its features are empty, so a linear head on them outputs its bias, which a model with a
prior starts at zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from physdyn.models.predictors.base import StatePredictor
from physdyn.registry import PREDICTORS


@PREDICTORS.register("none")
class NoPredictor(StatePredictor):
    """No network: features of width 0, so the model rolls out its prior (model.prior) exactly."""

    @dataclass
    class Config:
        pass

    def __init__(self, config: "NoPredictor.Config | None" = None, input_dim: int = 22):
        super().__init__()
        self.config = config or self.Config()
        self.out_dim = 0

    def forward(self, inputs: torch.Tensor, state=None):
        return inputs.new_zeros(*inputs.shape[:-1], 0), None
