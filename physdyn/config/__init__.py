"""Typed config schemas, YAML loading and ``key=value`` overrides.

Configs are plain YAML merged onto a dataclass schema with OmegaConf, so an unknown key or a wrong type is a
one-line ``ConfigError`` naming the key. A YAML file may start with ``defaults: [other.yaml, ...]`` (paths
relative to the file) to compose presets from smaller files.

One module per concern, every name importable from here:

- ``physics``: the simulated world and the push (``PhysicsConfig``, ``ImpulseConfig``, ``FrictionConfig``,
  ``MassConfig``), shared by dataset generation and prediction;
- ``data``: dataset generation, ``physdyn simulate`` (``DataConfig`` and its parts, ``EnsembleConfig`` included);
- ``uncertainty``: the uncertainty of a push (``UncertaintyConfig``, its presets), for ensembles and distributions;
- ``model``: the dynamics model's components and prior (``ModelConfig``, ``ComponentConfig``);
- ``training``: ``physdyn fit`` and ``physdyn pretrain`` (``ExperimentConfig``, ``PretrainConfig`` and their parts);
- ``rules``: value rules the types cannot say (ranges, relations between keys), checked after every load;
- ``loading``: YAML with ``defaults``, overrides, configs to and from plain dicts;
- ``presets``: the shipped YAML presets, found by name (``physdyn configs``).
"""

from __future__ import annotations

from physdyn.config.data import DataConfig, EnsembleConfig, FamilySpec, MeshFolderConfig, SplitConfig
from physdyn.config.loading import config_from_dict, load_config, omegaconf_message, parse_override, to_dict
from physdyn.config.model import ComponentConfig, ModelConfig
from physdyn.config.physics import FrictionConfig, ImpulseConfig, MassConfig, PhysicsConfig
from physdyn.config.presets import PRESET_KINDS, PRESETS, list_presets, preset_path
from physdyn.config.rules import (COUNT, FRACTION, NON_NEGATIVE, POSITIVE, RELATION_RULES, VALUE_RULES, check_values,
                                  within)
from physdyn.config.training import (EarlyStoppingConfig, ExperimentConfig, LossConfig, LossWeights, OptimConfig,
                                     PretrainConfig, PretrainDataConfig, RolloutTrainingConfig, TrainDataConfig)
from physdyn.config.uncertainty import UNCERTAINTY_PRESETS, UncertaintyConfig, resolve_uncertainty, uncertainty_at_level

__all__ = [
    "COUNT", "FRACTION", "NON_NEGATIVE", "POSITIVE", "PRESETS", "PRESET_KINDS", "RELATION_RULES", "VALUE_RULES",
    "ComponentConfig", "DataConfig", "EarlyStoppingConfig", "EnsembleConfig", "ExperimentConfig", "FamilySpec", "FrictionConfig",
    "ImpulseConfig", "LossConfig", "LossWeights", "MassConfig", "MeshFolderConfig", "ModelConfig", "OptimConfig",
    "PhysicsConfig", "PretrainConfig", "PretrainDataConfig", "RolloutTrainingConfig", "SplitConfig",
    "TrainDataConfig", "UNCERTAINTY_PRESETS", "UncertaintyConfig", "check_values", "config_from_dict", "list_presets", "load_config", "omegaconf_message",
    "parse_override", "preset_path", "resolve_uncertainty", "to_dict", "uncertainty_at_level", "within",
]
