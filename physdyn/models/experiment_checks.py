"""The checks of an experiment config that its schema cannot make: component params against their registries,
choices, ranges. Plain Python: a predictor that reads a preset checks it without importing Lightning
(`physdyn.models.training.validate_experiment_config` adds the trainer's keys, which need Lightning's)."""
from __future__ import annotations

import numpy as np

from physdyn.config import ExperimentConfig
from physdyn.data.normalization import NORMALIZATION_MODES
from physdyn.errors import ConfigError
from physdyn.models.losses import LOSS_KINDS
from physdyn.models.priors import CONTACT_INERTIA, FOOTPRINTS, PRIORS, RESIDUAL_CHANNELS, SHAPE_PRIORS
from physdyn.registry import ENCODERS, HEADS, PREDICTORS

MAX_SIM_SECONDS = 4.0  # model.sim_seconds: beyond that the prediction would be the simulator's alone
MAX_CONTACT_SUBSTEPS = 256  # model.contact_substeps: past that the prior's cost grows and its numbers do not move


def check_experiment_config(cfg: ExperimentConfig) -> ExperimentConfig:
    """Check what the schema cannot, all but the trainer's keys: component params against their registries,
    choices, ranges. Raises a one-line ConfigError."""
    m = cfg.model
    for section, registry, comp in (("encoder", ENCODERS, m.encoder), ("predictor", PREDICTORS, m.predictor), ("head", HEADS, m.head)):
        if not comp.name:
            raise ConfigError(f"config key 'model.{section}.name': missing; registered: {', '.join(registry.names())}")
        registry.resolve_config(comp.name, comp.params, f"model.{section}.params", name_key=f"model.{section}.name")
    choices = (("loss.kind", cfg.loss.kind, LOSS_KINDS), ("model.prior", m.prior, PRIORS),
               ("model.contact_inertia", m.contact_inertia, CONTACT_INERTIA),
               ("model.contact_footprint", m.contact_footprint, FOOTPRINTS),
               ("model.residual_channels", m.residual_channels, RESIDUAL_CHANNELS),
               ("data.normalization", cfg.data.normalization, NORMALIZATION_MODES))
    for key, value, allowed in choices:
        if value not in allowed:
            raise ConfigError(f"config key '{key}': '{value}' is not one of {', '.join(allowed)}")
    if not 0 <= m.sim_seconds <= MAX_SIM_SECONDS:
        raise ConfigError(f"config key 'model.sim_seconds': seconds simulated before the networks take over, "
                          f"0 to {MAX_SIM_SECONDS:g}, got {m.sim_seconds}")
    if not 1 <= m.contact_substeps <= MAX_CONTACT_SUBSTEPS:
        raise ConfigError(f"config key 'model.contact_substeps': the contact prior's sub-steps per recorded step, "
                          f"1 to {MAX_CONTACT_SUBSTEPS}, got {m.contact_substeps}")
    for key in ("residual_gate_linear", "residual_gate_angular"):
        value = getattr(m, key)
        if not (value >= 0 and np.isfinite(value)):
            raise ConfigError(f"config key 'model.{key}': a speed >= 0, got {value}")
    if m.residual_channels != "all" and m.prior == "none":
        raise ConfigError(f"config key 'model.residual_channels': '{m.residual_channels}' leaves channels to a prior; "
                          "set model.prior (e.g. contact) or residual_channels=all")
    if m.prior in SHAPE_PRIORS and not m.orientation_input:
        raise ConfigError(f"config key 'model.prior': '{m.prior}' turns the footprint with the object; set model.orientation_input=true")
    for key, value in (("rollout.feedback", cfg.rollout.feedback), ("data.first_window_fraction", cfg.data.first_window_fraction)):
        if not 0.0 <= value <= 1.0:
            raise ConfigError(f"config key '{key}': a probability between 0 and 1, got {value}")
    if not 0.0 <= cfg.rollout.input_noise < 1.0:
        raise ConfigError(f"config key 'rollout.input_noise': a std in normalised units in [0, 1), got {cfg.rollout.input_noise}")
    if not cfg.loss.huber_delta > 0:
        raise ConfigError(f"config key 'loss.huber_delta': must be positive, got {cfg.loss.huber_delta}")
    if cfg.optim.schedule not in ("exponential", "step", "constant"):
        raise ConfigError(f"config key 'optim.schedule': '{cfg.optim.schedule}' is not exponential, step or constant")
    if not 0 < cfg.optim.lr_min <= cfg.optim.lr:
        raise ConfigError(f"config key 'optim.lr_min': need 0 < lr_min <= lr, got lr_min={cfg.optim.lr_min}, lr={cfg.optim.lr}")
    for key in ("window", "batch_size", "val_windows_per_sim"):
        if getattr(cfg.data, key) < 1:
            raise ConfigError(f"config key 'data.{key}': must be at least 1, got {getattr(cfg.data, key)}")
    if cfg.data.num_workers < 0:
        raise ConfigError(f"config key 'data.num_workers': must be >= 0, got {cfg.data.num_workers}")
    return cfg
