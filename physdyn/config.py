"""Typed config schemas, YAML loading and ``key=value`` overrides.

Configs are plain YAML merged onto a dataclass schema with OmegaConf, so an unknown key or a wrong type is a
one-line ``ConfigError`` naming the key. A YAML file may start with ``defaults: [other.yaml, ...]`` (paths
relative to the file) to compose presets from smaller files.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Type, TypeVar

import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from physdyn.errors import ConfigError

S = TypeVar("S")


# --------------------------------------------------------------------------------------------------
# Dataset generation (`physdyn simulate`)
# --------------------------------------------------------------------------------------------------
@dataclass
class PhysicsConfig:
    """PyBullet settings. Defaults are the paper's where it says, see docs/conventions.md."""

    # 1/960 s (the conventions): at 1/240 s the contact chatters and non-toppling objects pick up a
    # spurious tilt spin while sliding (median 0.59 rad/s) that a model would have to learn as noise.
    time_step: float = 1.0 / 960.0
    gravity: float = -9.81
    lateral_friction_object: float = 0.5
    lateral_friction_ground: float = 0.5  # Bullet multiplies: effective Coulomb mu = 0.25
    rolling_friction_object: float = 0.01  # without it round shapes roll until the time cap
    rolling_friction_ground: float = 0.0
    spinning_friction: float = 0.0
    linear_damping: float = 0.0  # PyBullet's default 0.04 would slow free motion
    angular_damping: float = 0.0
    restitution: float = 0.0
    rest_linear_speed: float = 0.01  # m/s
    rest_angular_speed: float = 0.1  # rad/s
    rest_duration: float = 0.5  # s at rest before the simulation stops
    max_duration: float = 7.0  # s


@dataclass
class ImpulseConfig:
    """The push: a horizontal force over one physics step with impulse = mass x speed."""

    speed_min: float = 0.5  # m/s
    speed_max: float = 2.0  # m/s
    # The push point's height is drawn within +/- this fraction of the object's height around the
    # centre-of-mass height; its sideways offset within +/- this fraction of the half-width (spin).
    height_fraction: float = 0.25
    lateral_fraction: float = 0.5


@dataclass
class FrictionConfig:
    """Per-simulation random friction for the friction-generalisation experiment."""

    random: bool = False
    # Range of the *effective* Coulomb coefficient (object x ground lateral friction).
    min: float = 0.1
    max: float = 0.5


@dataclass
class MassConfig:
    method: str = "exact"  # exact | voxel (the paper's estimate)
    density: float = 10.0  # kg/m^3; the paper's public data use 10
    voxel_pitch: float = 0.025  # m; reduced to smallest extent / 40 for small objects


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
    shapes_per_block: int = 4  # unit of work and of resumption


# --------------------------------------------------------------------------------------------------
# Value rules: what the schema's types cannot say (ranges, finiteness, relations between keys)
# --------------------------------------------------------------------------------------------------
def _within(low: float | None = None, high: float | None = None, low_open: bool = False) -> Callable[[Any], bool]:
    def check(x: Any) -> bool:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            return False
        if low is not None and (x <= low if low_open else x < low):
            return False
        return high is None or x <= high
    return check


POSITIVE = (_within(0, low_open=True), "a positive finite number")
NON_NEGATIVE = (_within(0), "a finite number >= 0")
FRACTION = (_within(0, 1), "a fraction between 0 and 1")
COUNT = (_within(1), "a whole number >= 1")

# schema -> field -> (check, what is allowed). Walked by ``check_values`` after every load.
VALUE_RULES: dict[type, dict[str, tuple[Callable[[Any], bool], str]]] = {
    PhysicsConfig: {
        "time_step": (_within(1e-5, 0.1), "seconds per physics step, 1e-5 to 0.1 (the conventions: 1/960)"),
        "gravity": (_within(-100, -0.1), "negative m/s^2 (z is up), e.g. -9.81"),
        "lateral_friction_object": NON_NEGATIVE, "lateral_friction_ground": NON_NEGATIVE,
        "rolling_friction_object": NON_NEGATIVE, "rolling_friction_ground": NON_NEGATIVE,
        "spinning_friction": NON_NEGATIVE, "linear_damping": NON_NEGATIVE, "angular_damping": NON_NEGATIVE,
        "restitution": FRACTION, "rest_linear_speed": POSITIVE, "rest_angular_speed": POSITIVE,
        "rest_duration": NON_NEGATIVE, "max_duration": (_within(0, 600, low_open=True), "seconds, above 0 and at most 600"),
    },
    ImpulseConfig: {
        "speed_min": (_within(0, 20, low_open=True), "m/s, above 0 and at most 20 (a hard push is a few m/s)"),
        "speed_max": (_within(0, 20, low_open=True), "m/s, above 0 and at most 20 (a hard push is a few m/s)"),
        "height_fraction": FRACTION, "lateral_fraction": FRACTION,
    },
    FrictionConfig: {"min": POSITIVE, "max": POSITIVE},
    MassConfig: {"density": POSITIVE, "voxel_pitch": POSITIVE},
    FamilySpec: {"shapes": COUNT, "sims_per_shape": COUNT},
    MeshFolderConfig: {"scale": POSITIVE},
    SplitConfig: {"test_fraction": (_within(0, 0.9), "a fraction between 0 and 0.9"),
                  "val_fraction": (_within(0, 0.9), "a fraction between 0 and 0.9")},
    DataConfig: {"rate_hz": (_within(0, 1000, low_open=True), "recordings per second, above 0 and at most 1000"),
                 "num_points": (_within(16, 100_000), "points per cloud, 16 to 100000"),
                 "oversample": COUNT, "shapes_per_block": COUNT},
}


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


RELATION_RULES: dict[type, Callable[[Any], tuple[str, str] | None]] = {DataConfig: _data_relations}


def check_values(config: Any, prefix: str = "") -> None:
    """Apply ``VALUE_RULES`` and ``RELATION_RULES`` to a loaded config and its nested configs; the first
    broken rule is a one-line ConfigError naming the key, the value and what is allowed."""
    rules = VALUE_RULES.get(type(config), {})
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        key = f"{prefix}{f.name}"
        if f.name in rules:
            check, allowed = rules[f.name]
            if not check(value):
                raise ConfigError(f"config key '{key}': {value!r} is not allowed; expected {allowed}")
        if dataclasses.is_dataclass(value):
            check_values(value, f"{key}.")
        elif isinstance(value, dict):
            for name, item in value.items():
                if dataclasses.is_dataclass(item):
                    check_values(item, f"{key}.{name}.")
    relation = RELATION_RULES.get(type(config))
    broken = relation(config) if relation else None
    if broken:
        raise ConfigError(f"config key '{prefix}{broken[0]}': {broken[1]}")


# --------------------------------------------------------------------------------------------------
# Presets: the repository's configs/, shipped inside the package (physdyn/presets links to it), so
# `--config quickstart` and `configs/experiment/quickstart.yaml` work after a plain `pip install` too.
# --------------------------------------------------------------------------------------------------
PRESETS = Path(__file__).resolve().parent / "presets"
PRESET_KINDS = ("data", "experiment", "model", "trainer", "reproduce")


def list_presets(kind: str | None = None) -> dict[str, list[tuple[str, str]]]:
    """kind -> [(name, the file's first comment line)] of the shipped presets."""
    out: dict[str, list[tuple[str, str]]] = {}
    for k in PRESET_KINDS if kind is None else (kind,):
        entries = []
        for path in sorted((PRESETS / k).glob("*.yaml")):
            entries.append((path.stem, _summary(path)))
        out[k] = entries
    return out


def _summary(path: Path, width: int = 110) -> str:
    """The first sentence of the file's opening comment, cut to ``width`` characters."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    text = " ".join(lines)
    sentence = re.split(r"(?<=[.:;])\s", text, maxsplit=1)[0].rstrip(".:;")
    sentence += ")" * (sentence.count("(") - sentence.count(")"))  # a cut inside brackets
    return sentence if len(sentence) <= width else sentence[: width - 3].rstrip() + "..."


def preset_path(value: str | Path, kind: str) -> Path:
    """A config file the user named: an existing path, a preset name of ``kind`` (``quickstart``), or a
    ``configs/<kind>/<name>.yaml`` path of the source tree, found among the shipped presets."""
    path = Path(value).expanduser()
    if path.is_file():
        return path
    if not path.suffix and len(path.parts) == 1:
        named = PRESETS / kind / f"{value}.yaml"
        if named.is_file():
            return named
        names = ", ".join(name for name, _ in list_presets(kind)[kind])
        raise ConfigError(f"'{value}' is neither a config file nor a {kind} preset; presets: {names} (`physdyn configs`)")
    if "configs" in path.parts:
        shipped = PRESETS.joinpath(*path.parts[len(path.parts) - path.parts[::-1].index("configs"):])
        if shipped.is_file():
            return shipped
    return path  # missing: the loader's error names it


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------
def _read_yaml(path: Path, seen: tuple[Path, ...] = ()) -> DictConfig:
    path = path.expanduser()
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}; pass an existing YAML file to --config")
    if path.resolve() in seen:
        raise ConfigError(f"config {path}: 'defaults' includes itself in a cycle")
    try:
        raw = yaml.safe_load(path.read_text())
    except UnicodeDecodeError:
        raise ConfigError(f"config {path} is not a text file; pass a YAML file to --config") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"config {path}{where} is not valid YAML: {getattr(exc, 'problem', exc)}") from None
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"config {path} must be a mapping of keys to values, got {type(raw).__name__}")
    defaults = raw.pop("defaults", []) or []
    if isinstance(defaults, str):
        defaults = [defaults]
    parts = [_read_yaml(path.parent / d, seen + (path.resolve(),)) for d in defaults]
    return OmegaConf.merge(*parts, OmegaConf.create(raw)) if parts else OmegaConf.create(raw)


def load_config(schema: Type[S], path: str | Path | None = None, overrides: List[str] | None = None) -> S:
    """Merge ``schema`` defaults, the YAML at ``path`` and dotlist ``overrides``; return a typed object."""
    try:
        base = OmegaConf.structured(schema)
        layers = [base]
        if path is not None:
            layers.append(_read_yaml(Path(path)))
        merged = OmegaConf.merge(*layers)
        overrides = list(overrides or [])
        for item in overrides:
            if "=" not in item:
                raise ConfigError(f"override '{item}' is not key=value (e.g. seed=3)")
        _drop_params_of_switched_components(merged, overrides)
        if overrides:
            merged = OmegaConf.merge(merged, *[parse_override(item) for item in overrides])
        config = OmegaConf.to_object(merged)
    except OmegaConfBaseException as exc:
        raise ConfigError(omegaconf_message(exc)) from None
    check_values(config)
    return config  # type: ignore[return-value]


def parse_override(item: str) -> DictConfig:
    """One ``key=value`` override as a config tree; a value that is not valid YAML (``[`` alone) is a
    one-line ConfigError naming the override."""
    try:
        return OmegaConf.from_dotlist([item])
    except yaml.YAMLError as exc:
        problem = str(getattr(exc, "problem", None) or exc).splitlines()[0]
        raise ConfigError(f"override '{item}': the value is not valid YAML ({problem}); quote or fix it") from None


def _drop_params_of_switched_components(merged: DictConfig, overrides: List[str]) -> None:
    """``model.encoder.name=dgcnn`` switches a component: the preset's ``params`` belong to the old one
    (PointNet widths mean nothing to DGCNN), so they are dropped; params given in the overrides still apply."""
    for item in overrides:
        key, value = item.split("=", 1)
        if not key.endswith(".name"):
            continue
        parent = key[: -len(".name")]
        node = OmegaConf.select(merged, parent, default=None)
        if not isinstance(node, DictConfig) or "params" not in node or node.get("name") == value:
            continue
        node.params = {}


def to_dict(config: Any) -> dict:
    """A plain, JSON-serialisable dict of a config object (for store attributes and checkpoints)."""
    return OmegaConf.to_container(OmegaConf.structured(config), resolve=True)  # type: ignore[return-value]


def config_from_dict(schema: Type[S], data: dict, where: str = "") -> S:
    """``data`` checked against ``schema``; an unknown key or a wrong type is a ConfigError naming
    ``where.key``."""
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), data))  # type: ignore
    except OmegaConfBaseException as exc:
        raise ConfigError(omegaconf_message(exc, where)) from None


def omegaconf_message(exc: OmegaConfBaseException, where: str = "") -> str:
    key = getattr(exc, "full_key", None) or ""
    full = ".".join(k for k in (where, str(key)) if k)
    first_line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return f"config key '{full}': {first_line}" if full else f"config: {first_line}"


# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------
@dataclass
class ComponentConfig:
    """One registered component: its registry ``name`` and its ``params`` (checked against its ``Config``)."""

    name: str = ""
    params: Dict[str, Any] = field(default_factory=dict)


@dataclass
class TrainDataConfig:
    """Training windows drawn from a dataset store (`physdyn fit`)."""

    store: str = "data/quickstart.zarr"
    window: int = 15  # steps per training window (1 s at 15 Hz)
    num_points: Optional[int] = None  # subsample each cloud to this many points (None: all of the store's)
    categories: List[str] = field(default_factory=list)  # keep only these categories (empty: all)
    exclude_categories: List[str] = field(default_factory=list)  # leave these out (leave-one-out runs)
    batch_size: int = 64
    num_workers: int = 0  # arrays are in memory; workers only help for very large models of data
    val_windows_per_sim: int = 1
    val_seed: int = 12345  # validation windows are fixed by this seed
    # Scaling of inputs and targets: "max" (the paper's: one scale per quantity, its largest value) or "std"
    # (per channel: mean and standard deviation of the training split). Measured in docs/research/training-recipe.md.
    normalization: str = "max"
    # Share of training windows that start at step 0, as every roll-out does (the rest start at random).
    first_window_fraction: float = 0.0
    # Turn each training window about the vertical by a random angle (points, velocities, changes and
    # orientations alike): the physics does not depend on the heading, which the network otherwise has to
    # learn from the pushes the data happens to hold. Measured in docs/research/training-recipe.md (within the
    # seed spread).
    yaw_augment: bool = False


@dataclass
class ModelConfig:
    encoder: ComponentConfig = field(default_factory=lambda: ComponentConfig("pointnet"))
    predictor: ComponentConfig = field(default_factory=lambda: ComponentConfig("lstm"))
    head: ComponentConfig = field(default_factory=lambda: ComponentConfig("topple"))
    encoder_init: Optional[str] = None  # encoder weights from `physdyn pretrain` (encoder.pt)
    # An analytic prior the network corrects (it predicts the residual): "none" (the paper), "kinematic"
    # (dp = v dt, dtheta = w dt, constant velocities) or "coulomb" (kinematic, with the horizontal velocity
    # slowed by Coulomb friction mu g, mu the training data's median friction), "planar" (coulomb, spin
    # stopping with the slide, tilt damped) or "contact" (slide and spin integrated under friction over the
    # footprint read from the point cloud; needs orientation_input). See physdyn/models/priors.py and
    # docs/research/contact-prior.md.
    prior: str = "none"
    # With a prior: below both of these speeds (horizontal m/s, rad/s) the network's residual is switched off
    # and the prior alone predicts the step (0: never). Chosen on validation, docs/research/training-recipe.md.
    residual_gate_linear: float = 0.0
    residual_gate_angular: float = 0.0
    # Feed the object's current orientation relative to step 0 (6D rotation representation) at every step;
    # the paper feeds velocities only, so the predictor is never told how the object has turned.
    orientation_input: bool = False
    # The contact prior's spin inertia (I_zz / m): "points" estimates it from the cloud (0.8 x the points'
    # mean squared radius); "body" takes the body's mass properties where the caller knows them (a store's
    # shapes, a mesh given to `physdyn predict`) and the estimate elsewhere. docs/research/contact-prior.md.
    contact_inertia: str = "points"
    # How the contact prior picks its 4 footprint points among the cloud's lowest: "spread" (farthest-point
    # sampling, the presets') or "area" (the 4 spanning the largest area, as the simulator's contact manifold
    # keeps them: finds a box face's corners; better on the procedural shapes, worse on irregular blobs;
    # docs/research/contact-prior.md). Acts at inference too: `export --set` may change it.
    contact_footprint: str = "spread"
    # The contact prior's sub-steps per recorded step (16: 1/240 s at 15 Hz); fewer cost less and integrate
    # more coarsely (docs/research/fast-cost.md). Acts at inference too (`export --set`).
    contact_substeps: int = 16
    # With a prior: the channels the network's residual corrects. "all" (velocity, spin, position, rotation),
    # "linear" (velocity and position; spin and rotation are the prior's) or "angular" (spin and rotation).
    # A "linear" network gave the best positions measured; `python -m physdyn.models.export --linear-from`
    # combines one with a model whose spin and rotation are better (docs/research/network-residual.md).
    residual_channels: str = "all"
    # Seconds at the start of a roll-out taken from PyBullet run on the point cloud's convex hull (the
    # body's inertia where the caller knows it, the conventions' physics step), rounded to recorded steps
    # (at least one), before the networks continue from the simulated state, their recurrent state warmed
    # up on the simulated velocities and orientations. 0: the networks from step 0 (the paper). Acts at
    # inference only (`export --set`): the impact phase is where the networks missed most
    # (docs/research/simulated-start.md).
    sim_seconds: float = 0.0


@dataclass
class LossWeights:
    linear_velocity: float = 1.0
    angular_velocity: float = 1.0
    position: float = 1.0
    rotation: float = 1.0
    topple: float = 2.0
    # The window's accumulated position error (the roll-out's drift from the true path), not in the paper.
    position_drift: float = 0.0


@dataclass
class LossConfig:
    kind: str = "relative"  # relative (the paper's) | absolute (the real-world model's) | huber
    huber_delta: float = 0.05  # kind=huber: quadratic below this error norm (normalised units), linear above
    weights: LossWeights = field(default_factory=LossWeights)
    eps: float = 1e-6  # added to the relative loss's denominator
    rest_threshold: float = 1e-3  # true changes below this norm (normalised units) use the absolute error


@dataclass
class OptimConfig:
    lr: float = 1e-3
    lr_min: float = 1e-5
    schedule: str = "exponential"  # exponential (lr -> lr_min over the planned steps) | step | constant
    decay_rate: float = 0.75  # schedule=step: multiply by this every decay_samples sequences (the paper's)
    decay_samples: int = 300_000
    weight_decay: float = 0.0


@dataclass
class RolloutTrainingConfig:
    """How the velocities fed during training relate to the truth (evaluation feeds the model's own)."""

    # Probability per training window of feeding the model's own velocity predictions (detached) instead of
    # the true ones from step 1 on: 0 is teacher forcing (the paper), 1 a full roll-out.
    feedback: float = 0.0
    # Std of Gaussian noise added to the fed velocities, in normalised units (as learned simulators do);
    # the velocity targets are corrected so the model learns to return to the true trajectory.
    input_noise: float = 0.0


@dataclass
class EarlyStoppingConfig:
    enabled: bool = False
    patience: int = 20  # validation rounds without improvement
    min_delta: float = 0.0


@dataclass
class ExperimentConfig:
    """`physdyn fit`: a dynamics model trained on a store; see configs/experiment/."""

    name: str = "experiment"
    seed: int = 0
    out_dir: Optional[str] = None  # default runs/<name>
    ckpt_path: Optional[str] = None  # continue from this checkpoint (like --resume)
    data: TrainDataConfig = field(default_factory=TrainDataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    rollout: RolloutTrainingConfig = field(default_factory=RolloutTrainingConfig)
    trainer: Dict[str, Any] = field(default_factory=dict)  # passed to lightning.Trainer as is
    early_stopping: EarlyStoppingConfig = field(default_factory=EarlyStoppingConfig)
    progress_bar: bool = True
    # torch CPU threads for the run (0: torch's default, one per core). The contact prior's loop of small
    # tensor operations trains faster on one thread than on two (docs/training.md, "Throughput").
    cpu_threads: int = 0


VALUE_RULES[ExperimentConfig] = {"cpu_threads": (_within(0, 1024), "threads, 0 (torch's default) to 1024")}


@dataclass
class PretrainDataConfig:
    """Shapes for encoder pretraining: procedural families or a ModelNet40-layout folder."""

    families: Dict[str, int] = field(default_factory=dict)  # family -> shapes (empty: 40 of every family)
    modelnet_root: Optional[str] = None  # <root>/<class>/{train,test}/*.off; replaces families when set
    modelnet_scale: float = 1.0
    max_per_class: Optional[int] = None  # cap the files read per class and split
    num_points: int = 1024
    oversample: int = 3
    val_fraction: float = 0.2  # of procedural shapes (a ModelNet folder has its own test split)
    batch_size: int = 32
    num_workers: int = 0
    augment: bool = True  # random rotation about z, scaling and jitter


@dataclass
class PretrainConfig:
    """`physdyn pretrain`: the shape encoder trained on shape classification."""

    name: str = "pretrain"
    seed: int = 0
    out_dir: Optional[str] = None  # default runs/<name>
    data: PretrainDataConfig = field(default_factory=PretrainDataConfig)
    encoder: ComponentConfig = field(default_factory=lambda: ComponentConfig("pointnet"))
    optim: OptimConfig = field(default_factory=OptimConfig)
    trainer: Dict[str, Any] = field(default_factory=dict)
    progress_bar: bool = True
