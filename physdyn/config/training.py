"""Training: `physdyn fit` (a dynamics model on a store) and `physdyn pretrain` (the shape encoder)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

from physdyn.config.model import ComponentConfig, ModelConfig
from physdyn.config.rules import VALUE_RULES, within


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


VALUE_RULES[ExperimentConfig] = {"cpu_threads": (within(0, 1024), "threads, 0 (torch's default) to 1024")}


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
