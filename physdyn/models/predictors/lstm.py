"""Stacked LSTM: the paper's state branch (3 x 1,024 units)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from physdyn.models.predictors.base import StatePredictor
from physdyn.registry import PREDICTORS


@PREDICTORS.register("lstm")
class LSTMPredictor(StatePredictor):
    """Stacked LSTM with forget-gate bias 1; state = (h, c), each (num_layers, B, hidden)."""

    @dataclass
    class Config:
        num_layers: int = 3
        hidden: int = 1024
        forget_bias: float = 1.0  # TensorFlow's LSTM cell default, used by the reference code

    def __init__(self, config: "LSTMPredictor.Config | None" = None, input_dim: int = 22):
        super().__init__()
        self.config = config = config or self.Config()
        self.lstm = nn.LSTM(input_dim, config.hidden, num_layers=config.num_layers, batch_first=True)
        h = config.hidden
        with torch.no_grad():  # PyTorch gate order is (input, forget, cell, output); two biases add up
            for name, param in self.lstm.named_parameters():
                if name.startswith("bias_ih"):
                    param[h : 2 * h].fill_(config.forget_bias)
                elif name.startswith("bias_hh"):
                    param[h : 2 * h].zero_()
        self.out_dim = h

    def forward(self, inputs: torch.Tensor, state=None):
        out, state = self.lstm(inputs, state)
        return out, state
