"""Scales that bring network inputs and targets to about unit size (as the paper's reference code scales them).

``mode="max"`` (the paper's): v and w (and their changes) by their largest absolute component, dp by the
largest per-step displacement, dtheta by the largest per-step angle. ``mode="std"``: each of the 6 velocity
inputs and 12 changes by its own mean and standard deviation. ``mode="std_inputs"``: the inputs so, the
changes by max scaling (the loss then sees the changes as with "max"). Points are always scaled by the largest point
norm. Everything is computed on the TRAINING simulations only (the reference code also looked at validation
and test data). The scales travel with a model in its checkpoint, so a model always de-normalises with the
numbers it was trained with.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from physdyn.data.windows import FrameTargets, frame_targets

if TYPE_CHECKING:  # annotations only: reading a store (zarr) is not needed to predict
    from physdyn.data.store import StoreData


@dataclass(frozen=True)
class Normalization:
    """Divide by these to normalise; multiply to get SI units back."""

    linear_velocity: float = 1.0  # m/s; also scales delta_linear_velocity
    angular_velocity: float = 1.0  # rad/s; also scales delta_angular_velocity
    position: float = 1.0  # m, scales delta_position
    rotation: float = 1.0  # rad, scales delta_rotation
    points: float = 1.0  # m
    mode: str = "max"
    # mode "std" only: per-channel statistics of the inputs [v, w] (6) and the changes [dv, dw, dp, dtheta] (12)
    input_mean: tuple = ()
    input_std: tuple = ()
    change_mean: tuple = ()
    change_std: tuple = ()

    def to_dict(self) -> dict:
        out: dict = {}
        for k, v in asdict(self).items():
            out[k] = v if k == "mode" else [float(x) for x in v] if isinstance(v, (tuple, list)) else float(v)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "Normalization":
        # Checkpoints from before the "std" mode hold the five scalars only.
        out = {}
        for k, v in data.items():
            out[k] = str(v) if k == "mode" else tuple(float(x) for x in v) if isinstance(v, (tuple, list)) else float(v)
        return cls(**out)

    def change_scales(self) -> np.ndarray:
        """(12,) scales of the stacked changes [dv, dw, dp, dtheta], in that order ("std_inputs": max scaling)."""
        if self.mode == "std":
            return np.asarray(self.change_std, dtype=np.float64)
        return np.repeat([self.linear_velocity, self.angular_velocity, self.position, self.rotation], 3)

    def change_shifts(self) -> np.ndarray:
        """(12,) subtracted from the changes before scaling (zero in "max" mode)."""
        return np.asarray(self.change_mean, dtype=np.float64) if self.mode == "std" else np.zeros(12)

    def input_scales(self) -> np.ndarray:
        """(6,) scales of the fed velocities [v, w]."""
        if self.mode in ("std", "std_inputs"):
            return np.asarray(self.input_std, dtype=np.float64)
        return np.repeat([self.linear_velocity, self.angular_velocity], 3)

    def input_shifts(self) -> np.ndarray:
        return np.asarray(self.input_mean, dtype=np.float64) if self.mode in ("std", "std_inputs") else np.zeros(6)


def _positive(value: float) -> float:
    # A quantity that never moves in the training data (e.g. no spin at all) keeps scale 1, not 0.
    value = float(value)
    return value if np.isfinite(value) and value > 0 else 1.0


NORMALIZATION_MODES = ("max", "std", "std_inputs")


def _std(x: np.ndarray) -> tuple:
    # A channel that never changes in the training data keeps scale 1, not 0.
    return tuple(_positive(s) for s in x.std(axis=0))


def compute_normalization(store: StoreData, sims: np.ndarray, targets: FrameTargets | None = None,
                          mode: str = "max") -> Normalization:
    """Scales from the frames of ``sims`` (the training simulations) and the shapes they use."""
    if mode not in NORMALIZATION_MODES:
        raise ValueError(f"normalization mode must be one of {', '.join(NORMALIZATION_MODES)}, got '{mode}'")
    sims = np.asarray(sims, dtype=np.int64)
    if len(sims) == 0:
        raise ValueError("no training simulations to compute normalisation statistics from")
    targets = targets if targets is not None else frame_targets(store)
    frames = np.concatenate([np.arange(store.start[i], store.start[i + 1]) for i in sims])
    shapes = np.unique(store.shape_id[sims])
    per_channel = {}
    if mode in ("std", "std_inputs"):
        inputs = np.concatenate([store.linear_velocity[frames], store.angular_velocity[frames]], axis=1)
        changes = np.concatenate([targets.delta_linear_velocity[frames], targets.delta_angular_velocity[frames],
                                  targets.delta_position[frames], targets.delta_rotation[frames]], axis=1)
        per_channel = dict(mode=mode, input_mean=tuple(inputs.mean(axis=0)), input_std=_std(inputs),
                           change_mean=tuple(changes.mean(axis=0)), change_std=_std(changes))
    return Normalization(
        **per_channel,
        linear_velocity=_positive(np.abs(store.linear_velocity[frames]).max()),
        angular_velocity=_positive(np.abs(store.angular_velocity[frames]).max()),
        position=_positive(np.linalg.norm(targets.delta_position[frames], axis=-1).max()),
        rotation=_positive(np.linalg.norm(targets.delta_rotation[frames], axis=-1).max()),
        points=_positive(np.linalg.norm(store.points[shapes], axis=-1).max()),
    )
