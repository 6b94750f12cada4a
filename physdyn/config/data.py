"""Dataset generation (`physdyn simulate`): which shapes, how many pushes, how they are recorded and split."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Optional

from physdyn.config.physics import FrictionConfig, ImpulseConfig, MassConfig, PhysicsConfig
from physdyn.config.rules import COUNT, POSITIVE, RELATION_RULES, VALUE_RULES, within
from physdyn.config.uncertainty import UncertaintyConfig, resolve_uncertainty


@dataclass
class FamilySpec:
    shapes: int = 100  # instances to draw (a mesh folder uses all its files)
    sims_per_shape: int = 65
    params: Dict[str, Any] = field(default_factory=dict)  # checked against the family's Config


@dataclass
class MeshFolderConfig:
    """Source of the `meshes` family: every mesh file in a folder."""

    dir: Optional[str] = None
    scale: float = 1.0  # multiply coordinates by this to get metres (0.01 for centimetre files)
    recursive: bool = True
    category: str = "meshes"


@dataclass
class SplitConfig:
    test_fraction: float = 0.2
    val_fraction: float = 0.1  # of the training shapes


@dataclass
class EnsembleConfig:
    """Reference distributions: every push re-simulated ``members`` times from its step-0 state, perturbed as
    ``uncertainty`` says (docs/conventions.md, "Uncertainty of a push"; arrays: docs/dataset-format.md)."""

    members: int = 0  # per push; 0: no ensemble
    uncertainty: Any = "default"  # a preset (none, low, default) or a mapping of UncertaintyConfig's keys
    seconds: Optional[float] = None  # recorded per member; None: physics.max_duration (rest is padded)

    def uncertainty_config(self) -> UncertaintyConfig:
        return resolve_uncertainty(self.uncertainty, "ensemble.uncertainty")


@dataclass
class DataConfig:
    seed: int = 0
    rate_hz: float = 15.0
    num_points: int = 1024
    oversample: int = 3
    # surface: the paper's (3x oversampling + farthest points); hull_surface: the convex hull's vertices, then
    # surface samples (physdyn/geometry/sampling.py: the cloud's hull is the mesh's, so contact is not lost)
    points_method: str = "surface"
    families: Dict[str, FamilySpec] = field(default_factory=dict)
    meshes: MeshFolderConfig = field(default_factory=MeshFolderConfig)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    impulse: ImpulseConfig = field(default_factory=ImpulseConfig)
    friction: FrictionConfig = field(default_factory=FrictionConfig)
    mass: MassConfig = field(default_factory=MassConfig)
    split: SplitConfig = field(default_factory=SplitConfig)
    ensemble: EnsembleConfig = field(default_factory=EnsembleConfig)
    shapes_per_block: int = 4  # unit of work and of resumption


VALUE_RULES[FamilySpec] = {"shapes": COUNT, "sims_per_shape": COUNT}
VALUE_RULES[MeshFolderConfig] = {"scale": POSITIVE}
VALUE_RULES[SplitConfig] = {"test_fraction": (within(0, 0.9), "a fraction between 0 and 0.9"),
                            "val_fraction": (within(0, 0.9), "a fraction between 0 and 0.9")}
VALUE_RULES[EnsembleConfig] = {
    "members": (within(0, 4096), "members per push, 0 (no ensemble) to 4096"),
    "seconds": (lambda x: x is None or within(0, 600, low_open=True)(x), "seconds, above 0 and at most 600, or null"),
}


def _ensemble_relations(cfg: "EnsembleConfig") -> None:
    """An uncertainty is a preset name or a mapping, which the types cannot check: resolving it raises the
    one-line ConfigError naming the key (it only ever sits at ``ensemble.uncertainty``)."""
    cfg.uncertainty_config()


RELATION_RULES[EnsembleConfig] = _ensemble_relations
VALUE_RULES[DataConfig] = {"rate_hz": (within(0, 1000, low_open=True), "recordings per second, above 0 and at most 1000"),
                           "num_points": (within(16, 100_000), "points per cloud, 16 to 100000"),
                           "oversample": COUNT, "shapes_per_block": COUNT}


def _data_relations(cfg: "DataConfig") -> tuple[str, str] | None:
    """Rules between keys of a data config: (key, message) of the first broken one."""
    steps = 1.0 / (cfg.rate_hz * cfg.physics.time_step)
    if abs(steps - round(steps)) > 1e-6 * steps or round(steps) < 1:
        return ("rate_hz", f"{cfg.rate_hz:g} Hz does not divide the physics rate {1 / cfg.physics.time_step:g} Hz "
                           f"(physics.time_step); use a divisor, e.g. 15, 30 or 60")
    if cfg.impulse.speed_min > cfg.impulse.speed_max:
        return ("impulse.speed_min", f"{cfg.impulse.speed_min:g} is above impulse.speed_max {cfg.impulse.speed_max:g}")
    if cfg.friction.min > cfg.friction.max:
        return ("friction.min", f"{cfg.friction.min:g} is above friction.max {cfg.friction.max:g}")
    if cfg.split.test_fraction + cfg.split.val_fraction >= 1.0:
        return ("split.val_fraction", "test_fraction + val_fraction must leave shapes to train on (sum below 1)")
    if cfg.points_method not in ("surface", "hull_surface"):
        return ("points_method", f"'{cfg.points_method}' is not a points method; use surface or hull_surface")
    return None


RELATION_RULES[DataConfig] = _data_relations
