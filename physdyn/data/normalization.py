"""Per-quantity scales that bring network inputs and targets to about unit size (method-notes section 4).

v and w (and their changes) by their largest absolute component, dp by the largest per-step
displacement, dtheta by the largest per-step angle, points by the largest point norm - computed on the
TRAINING simulations only (the reference code also looked at validation and test data). The scales travel
with a model in its checkpoint, so a model always de-normalises with the numbers it was trained with.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from physdyn.data.store import StoreData
from physdyn.data.windows import FrameTargets, frame_targets


@dataclass(frozen=True)
class Normalization:
    """Divide by these to normalise; multiply to get SI units back."""

    linear_velocity: float = 1.0  # m/s; also scales delta_linear_velocity
    angular_velocity: float = 1.0  # rad/s; also scales delta_angular_velocity
    position: float = 1.0  # m, scales delta_position
    rotation: float = 1.0  # rad, scales delta_rotation
    points: float = 1.0  # m

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> "Normalization":
        return cls(**{k: float(v) for k, v in data.items()})

    def change_scales(self) -> np.ndarray:
        """(12,) scales of the stacked changes [dv, dw, dp, dtheta], in that order."""
        return np.repeat([self.linear_velocity, self.angular_velocity, self.position, self.rotation], 3)


def _positive(value: float) -> float:
    # A quantity that never moves in the training data (e.g. no spin at all) keeps scale 1, not 0.
    value = float(value)
    return value if np.isfinite(value) and value > 0 else 1.0


def compute_normalization(store: StoreData, sims: np.ndarray, targets: FrameTargets | None = None) -> Normalization:
    """Scales from the frames of ``sims`` (the training simulations) and the shapes they use."""
    sims = np.asarray(sims, dtype=np.int64)
    if len(sims) == 0:
        raise ValueError("no training simulations to compute normalisation statistics from")
    targets = targets if targets is not None else frame_targets(store)
    frames = np.concatenate([np.arange(store.start[i], store.start[i + 1]) for i in sims])
    shapes = np.unique(store.shape_id[sims])
    return Normalization(
        linear_velocity=_positive(np.abs(store.linear_velocity[frames]).max()),
        angular_velocity=_positive(np.abs(store.angular_velocity[frames]).max()),
        position=_positive(np.linalg.norm(targets.delta_position[frames], axis=-1).max()),
        rotation=_positive(np.linalg.norm(targets.delta_rotation[frames], axis=-1).max()),
        points=_positive(np.linalg.norm(store.points[shapes], axis=-1).max()),
    )
