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
        if inputs.shape[1] == 1 and not torch.is_grad_enabled():
            return self._single_step(inputs, state)
        out, state = self.lstm(inputs, state)
        return out, state

    def _single_step(self, inputs: torch.Tensor, state=None):
        """One time step as explicit cell equations: the same numbers as ``nn.LSTM``, without its oneDNN
        set-up, which costs ~0.2 ms per layer per call on a CPU and dominated roll-outs one step at a time."""
        x = inputs[:, 0]
        L, H = self.config.num_layers, self.config.hidden
        if state is None:
            zeros = x.new_zeros(L, x.shape[0], H)
            state = (zeros, zeros)
        h_prev, c_prev = state
        hs, cs = [], []
        for layer in range(L):
            gates = torch.addmm(getattr(self.lstm, f"bias_ih_l{layer}"), x, getattr(self.lstm, f"weight_ih_l{layer}").t())
            gates = torch.addmm(gates, h_prev[layer], getattr(self.lstm, f"weight_hh_l{layer}").t())
            gates = gates + getattr(self.lstm, f"bias_hh_l{layer}")
            i, f, g, o = gates.chunk(4, dim=1)
            c = torch.sigmoid(f) * c_prev[layer] + torch.sigmoid(i) * torch.tanh(g)
            x = torch.sigmoid(o) * torch.tanh(c)
            hs.append(x)
            cs.append(c)
        return x[:, None], (torch.stack(hs), torch.stack(cs))
