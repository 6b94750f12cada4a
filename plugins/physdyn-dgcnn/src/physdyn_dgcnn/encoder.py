"""A DGCNN shape encoder (Wang et al., "Dynamic Graph CNN for Learning on Point Clouds", TOG 2019).

Each EdgeConv layer builds a k-nearest-neighbour graph on the *current* features (on xyz for the first
layer, so the graph changes from layer to layer: "dynamic"), forms the edge feature [x_i, x_j - x_i] for
every neighbour j of point i, applies a shared layer (linear, batch norm, LeakyReLU) and takes the max over
the neighbours. The outputs of all EdgeConv layers are concatenated, lifted by a per-point layer, pooled
over the points (max, and mean if asked) and mapped by a small MLP to ``feature_dim`` numbers: the shape
feature the state predictor reads, 16 by default like the paper's PointNet feature.

Memory is what limits DGCNN on a CPU, so two things are done differently from the reference code, with
the same result:
- the k-NN search runs in blocks of query points (``knn_chunk_size``) under ``no_grad`` (neighbour indices
  carry no gradient), so the (B, N, N) distance matrix is never held whole;
- the first layer is applied to x_i and x_j *before* gathering neighbours, using
  W [x_i, x_j - x_i] = (W_c - W_e) x_i + W_e x_j, so the (B, N, k, 2C) edge tensor is never built; only the
  (B, N, k, C_out) output is.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import torch
import torch.nn.functional as F
from torch import nn

from physdyn.errors import ConfigError
from physdyn.models.encoders.base import ShapeEncoder
from physdyn.registry import ENCODERS


def knn_indices(features: torch.Tensor, k: int, chunk_size: int = 256) -> torch.Tensor:
    """Indices of the k nearest neighbours of every point, itself included (distance 0), nearest first.

    features: (B, N, C) float -> (B, N, k) int64 indices into N. Distances are Euclidean in feature space.
    The distance matrix is built ``chunk_size`` query points at a time: peak memory B * chunk_size * N floats.
    """
    if features.dim() != 3:
        raise ValueError(f"knn_indices expects features of shape (B, N, C), got {tuple(features.shape)}")
    n = features.shape[1]
    if not 1 <= k <= n:
        raise ValueError(f"k must be between 1 and the number of points ({n}), got {k}")
    with torch.no_grad():
        x = features.detach()
        blocks = []
        for start in range(0, n, max(1, chunk_size)):
            dist = torch.cdist(x[:, start : start + chunk_size], x)  # (B, chunk, N)
            blocks.append(dist.topk(k, dim=-1, largest=False, sorted=True).indices)
        return torch.cat(blocks, dim=1)


def gather_neighbours(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """values: (B, N, C), idx: (B, N, k) indices into N -> (B, N, k, C), values[b, idx[b, i, j]]."""
    b, n, c = values.shape
    offset = torch.arange(b, device=values.device).view(b, 1, 1) * n
    return values.reshape(b * n, c)[idx + offset]


class EdgeConv(nn.Module):
    """One EdgeConv layer: max over j in kNN(i) of LeakyReLU(BN(W [x_i, x_j - x_i]))."""

    def __init__(self, in_dim: int, out_dim: int, batch_norm: bool = True, negative_slope: float = 0.2):
        super().__init__()
        self.in_dim = in_dim
        self.out_dim = out_dim
        self.negative_slope = negative_slope
        # Weight columns [:in_dim] act on x_i, [in_dim:] on x_j - x_i: the reference layout, so a checkpoint
        # of a Conv2d(2C, C_out, 1) maps onto it by a reshape.
        self.linear = nn.Linear(2 * in_dim, out_dim, bias=not batch_norm)
        # BatchNorm1d over (B*N*k, C_out) rows is the reference BatchNorm2d over (B, C_out, N, k).
        self.norm: nn.Module = nn.BatchNorm1d(out_dim) if batch_norm else nn.Identity()

    def edge_features(self, x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        """The edge features [x_i, x_j - x_i] built explicitly: x (B, N, C), idx (B, N, k) -> (B, N, k, 2C).

        Not used by ``forward`` (which never builds this tensor); kept to check it against the reference.
        """
        neighbours = gather_neighbours(x, idx)
        centre = x.unsqueeze(2).expand_as(neighbours)
        return torch.cat([centre, neighbours - centre], dim=-1)

    def forward(self, x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        """x: (B, N, C_in) per-point features, idx: (B, N, k) neighbours -> (B, N, C_out)."""
        b, n, _ = x.shape
        w_centre, w_edge = self.linear.weight.split(self.in_dim, dim=1)
        centre = F.linear(x, w_centre - w_edge, self.linear.bias)  # (B, N, C_out)
        neighbour = F.linear(x, w_edge)  # (B, N, C_out)
        h = gather_neighbours(neighbour, idx) + centre.unsqueeze(2)  # (B, N, k, C_out)
        k = idx.shape[-1]
        h = self.norm(h.reshape(b * n * k, self.out_dim)).reshape(b, n, k, self.out_dim)
        h = F.leaky_relu(h, self.negative_slope)
        return h.max(dim=2).values


@ENCODERS.register("dgcnn")
class DGCNNEncoder(ShapeEncoder):
    """DGCNN (Wang et al. 2019): EdgeConv on dynamic k-NN graphs, max(+mean) pooled (plugin example)."""

    @dataclass
    class Config:
        k: int = 20  # neighbours per point, the point itself included (the reference's default)
        # One EdgeConv layer per entry; the reference classifier uses [64, 64, 128, 256].
        edge_widths: List[int] = field(default_factory=lambda: [64, 64, 128])
        embedding_width: int = 512  # per-point layer after concatenating the EdgeConv outputs (ref.: 1024)
        mean_pool: bool = True  # pool max and mean over points (the reference) or max only
        head_widths: List[int] = field(default_factory=lambda: [128])  # hidden layers of the final MLP
        feature_dim: int = 16  # the shape feature's size; the paper's PointNet feature has 16
        batch_norm: bool = True
        negative_slope: float = 0.2  # LeakyReLU slope, the reference's
        knn_chunk_size: int = 256  # query points per distance block; peak B * chunk * N floats

    def __init__(self, config: "DGCNNEncoder.Config | None" = None):
        super().__init__()
        config = config if config is not None else self.Config()
        _check_config(config)
        self.config = config
        self.out_dim = config.feature_dim

        widths = list(config.edge_widths)
        self.edge_convs = nn.ModuleList(
            EdgeConv(c_in, c_out, config.batch_norm, config.negative_slope)
            for c_in, c_out in zip([3] + widths[:-1], widths)
        )
        self.embedding = nn.Linear(sum(widths), config.embedding_width, bias=not config.batch_norm)
        self.embedding_norm: nn.Module = (
            nn.BatchNorm1d(config.embedding_width) if config.batch_norm else nn.Identity()
        )
        # No batch norm in the head: it would fail on a batch of one shape during training.
        pooled = config.embedding_width * (2 if config.mean_pool else 1)
        layers: list[nn.Module] = []
        for width in config.head_widths:
            layers += [nn.Linear(pooled, width), nn.LeakyReLU(config.negative_slope)]
            pooled = width
        layers.append(nn.Linear(pooled, config.feature_dim))
        self.head = nn.Sequential(*layers)

    def point_features(self, points: torch.Tensor) -> torch.Tensor:
        """points: (B, N, 3) -> (B, N, embedding_width) per-point features before pooling."""
        if points.dim() != 3 or points.shape[-1] != 3:
            raise ValueError(f"DGCNNEncoder expects points of shape (B, N, 3), got {tuple(points.shape)}")
        b, n, _ = points.shape
        k = min(self.config.k, n)  # a cloud smaller than k: every point is every point's neighbour
        x = points
        outputs = []
        for conv in self.edge_convs:
            idx = knn_indices(x, k, self.config.knn_chunk_size)  # the graph is rebuilt on each layer's input
            x = conv(x, idx)
            outputs.append(x)
        h = self.embedding(torch.cat(outputs, dim=-1))  # (B, N, E)
        h = self.embedding_norm(h.reshape(b * n, -1)).reshape(b, n, -1)
        return F.leaky_relu(h, self.config.negative_slope)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points: (B, N, 3) float32, world-oriented body frame -> (B, feature_dim) shape feature.

        Invariant to the order of the points. Not invariant to translation: the first layer sees x_i
        itself, not only x_j - x_i, so the feature knows where the centre of mass sits in the cloud.
        """
        h = self.point_features(points)
        pooled = h.max(dim=1).values
        if self.config.mean_pool:
            pooled = torch.cat([pooled, h.mean(dim=1)], dim=-1)
        return self.head(pooled)


def _check_config(config: DGCNNEncoder.Config) -> None:
    where = "encoder 'dgcnn'"
    if config.k < 1:
        raise ConfigError(f"{where}: k must be >= 1, got {config.k}")
    if not config.edge_widths or any(w < 1 for w in config.edge_widths):
        raise ConfigError(
            f"{where}: edge_widths must be a non-empty list of positive widths, got {list(config.edge_widths)}"
        )
    for name in ("embedding_width", "feature_dim", "knn_chunk_size"):
        if getattr(config, name) < 1:
            raise ConfigError(f"{where}: {name} must be >= 1, got {getattr(config, name)}")
    if any(w < 1 for w in config.head_widths):
        raise ConfigError(f"{where}: head_widths must be positive, got {list(config.head_widths)}")
