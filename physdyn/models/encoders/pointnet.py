"""PointNet without T-nets, as the paper's shape branch."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import torch
from torch import nn

from physdyn.models.encoders.base import ShapeEncoder
from physdyn.registry import ENCODERS


def _block(layer: nn.Module, width: int, batch_norm: bool, bn: type, momentum: float, eps: float) -> list[nn.Module]:
    parts = [layer]
    if batch_norm:
        parts.append(bn(width, momentum=momentum, eps=eps))
    parts.append(nn.ReLU(inplace=True))
    return parts


@ENCODERS.register("pointnet")
class PointNetEncoder(ShapeEncoder):
    """PointNet: shared per-point MLP, global max-pool, fully connected layers to a small shape feature."""

    @dataclass
    class Config:
        point_widths: List[int] = field(default_factory=lambda: [64, 64, 64, 128, 1024])  # shared per-point MLP
        fc_widths: List[int] = field(default_factory=lambda: [1024, 512, 128, 32])  # after the max-pool
        feature_size: int = 16  # the shape feature fed to the predictor at every step
        batch_norm: bool = True  # off in the paper's real-world model
        bn_momentum: float = 0.1  # TensorFlow's moving-average decay 0.9
        bn_eps: float = 1e-3  # TensorFlow's default

    def __init__(self, config: "PointNetEncoder.Config | None" = None):
        super().__init__()
        self.config = config = config or self.Config()
        if not config.point_widths:
            raise ValueError("pointnet: point_widths must list at least one layer width")
        bn_args = (config.batch_norm, config.bn_momentum, config.bn_eps)
        layers: list[nn.Module] = []
        width = 3
        for w in config.point_widths:  # a 1x1 convolution over points = a shared per-point linear layer
            layers += _block(nn.Conv1d(width, w, 1), w, config.batch_norm, nn.BatchNorm1d, *bn_args[1:])
            width = w
        self.point_mlp = nn.Sequential(*layers)
        layers = []
        for w in list(config.fc_widths) + [config.feature_size]:  # BN + ReLU after each, as in the paper
            layers += _block(nn.Linear(width, w), w, config.batch_norm, nn.BatchNorm1d, *bn_args[1:])
            width = w
        self.fc = nn.Sequential(*layers)
        self.out_dim = config.feature_size

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points: (B, N, 3) float32, world-oriented body frame, normalised -> (B, feature_size)."""
        per_point = self.point_mlp(points.transpose(1, 2))  # (B, C, N)
        return self.fc(per_point.max(dim=2).values)
