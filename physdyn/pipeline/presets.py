"""Predictor presets and the one factory that builds any of them into a ``Pipeline``.

A preset (configs/predictor/NAME.yaml, shipped as ``physdyn/presets/predictor/``; `physdyn configs predictor`)
names its stage of each kind and the weights they read::

    name: fast
    weights: fast                 # a checkpoint: a path, or a shipped model's name (physdyn/assets/)
    motion: {name: contact_prior}
    topple: {name: pointnet}
    correction: {name: pointnet}

``load_pipeline`` takes a preset's name or file, or a checkpoint of `physdyn fit` (with whatever `fit-topple` and
`fit-outcome` added), whose preset is read off its contents (``checkpoint_preset``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from physdyn.errors import CheckpointError, ConfigError, PhysdynError
from physdyn.pipeline import correction as _corrections
from physdyn.pipeline import topple as _topples
from physdyn.pipeline.engine import Pipeline
from physdyn.registry import CORRECTION_STAGES, DISTRIBUTION_STAGES, MOTION_STAGES, TOPPLE_STAGES

KINDS = {"motion": MOTION_STAGES, "topple": TOPPLE_STAGES, "correction": CORRECTION_STAGES,
         "distribution": DISTRIBUTION_STAGES}


@dataclass
class StageConfig:
    """One stage of a preset: its registered ``name`` and its ``params`` (the stage's own ``Config``)."""

    name: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class PredictorPreset:
    """A complete predictor: one stage of each kind and the weights they read (None: no stage reads any)."""

    name: str
    motion: StageConfig
    topple: StageConfig = field(default_factory=lambda: StageConfig("head"))
    correction: StageConfig = field(default_factory=lambda: StageConfig("none"))
    weights: str | None = None
    distribution: StageConfig = field(default_factory=lambda: StageConfig("sampled_pushes"))


def preset_file(name: str) -> Path:
    """The shipped preset called ``name`` (configs/predictor/NAME.yaml)."""
    from physdyn.config import PRESETS

    return PRESETS / "predictor" / f"{name}.yaml"


def shipped_presets() -> list[str]:
    return sorted(p.stem for p in preset_file("x").parent.glob("*.yaml"))


def read_preset(path: str | Path) -> PredictorPreset:
    """A preset from its YAML file; a one-line ``ConfigError`` naming the key for anything else in it."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: not a predictor preset ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a predictor preset is a mapping of name, weights, motion, topple and correction")
    unknown = sorted(set(data) - {"name", "weights", "recipe", *KINDS})
    if unknown:
        raise ConfigError(f"{path}: unknown key '{unknown[0]}'; a predictor preset has name, weights, {', '.join(KINDS)}")
    if "motion" not in data:
        raise ConfigError(f"{path}: key 'motion' is missing; name a motion stage ({', '.join(MOTION_STAGES.names())})")
    stages = {kind: _stage_config(data[kind], f"{path}: key '{kind}'") for kind in KINDS if kind in data}
    weights = data.get("weights")
    if weights is not None and not Path(str(weights)).is_absolute() and (path.parent / str(weights)).is_file():
        weights = str(path.parent / str(weights))  # a file beside the preset
    return PredictorPreset(name=str(data.get("name") or path.stem), weights=None if weights is None else str(weights), **stages)


def preset_recipe(spec: str | Path) -> list:
    """The recipe of a shipped preset's name or a preset file: the commands that train its stages
    (``physdyn.pipeline.recipe``); a one-line ``ConfigError`` for a preset without one."""
    import yaml

    from physdyn.pipeline.recipe import read_recipe

    path = Path(spec)
    if not path.is_file():
        path = preset_file(str(spec))
    if not path.is_file():
        raise ConfigError(f"no predictor preset '{spec}'; the shipped ones: {', '.join(shipped_presets())}")
    read_preset(path)  # the preset itself must be well formed
    recipe = (yaml.safe_load(path.read_text()) or {}).get("recipe")
    if recipe is None:
        raise ConfigError(f"{path}: this preset has no recipe: nothing of it is trained (a preset with one: fast, bundled)")
    return read_recipe(recipe, str(path))


def _stage_config(value: Any, where: str) -> StageConfig:
    if isinstance(value, str):
        return StageConfig(value)
    if not isinstance(value, dict) or "name" not in value or set(value) - {"name", "params"}:
        raise ConfigError(f"{where}: expected a stage name, or a mapping of name and params")
    return StageConfig(str(value["name"]), dict(value.get("params") or {}))


class StageSource:
    """What stages are built from: the preset's weights (a checkpoint's dict, None for a preset without) and
    the physics a stage without weights takes its friction from."""

    def __init__(self, checkpoint: dict | None, physics: Any = None, where: str = "the weights"):
        self.checkpoint, self.physics, self.where = checkpoint, physics, where
        self._network: Any = None

    def network(self) -> Any:
        """The checkpoint's ``DynamicsNetwork``, built once for every stage that reads it."""
        if self._network is None:
            if self.checkpoint is None:
                raise ConfigError("this stage reads a network: give the preset weights (a checkpoint of `physdyn fit`)")
            self._network = network_from_checkpoint(self.checkpoint, self.where)
        return self._network

    def part(self, key: str, kind: str) -> dict[str, Any]:
        """The checkpoint's entry ``key`` that a ``kind`` stage reads."""
        entry = None if self.checkpoint is None else self.checkpoint.get(key)
        if not entry:
            raise ConfigError(f"the {kind} stage reads the weights' '{key}', and {self.where} holds none; fit one "
                              f"(`physdyn fit-{'topple' if kind == 'topple' else 'outcome'}`) or name another stage")
        return entry

    @property
    def rate_hz(self) -> float:
        info = {} if self.checkpoint is None else self.checkpoint["hyper_parameters"].get("data_info") or {}
        return float(info.get("rate_hz") or 15.0)


def network_from_checkpoint(raw: dict, where: str = "the checkpoint") -> Any:
    """The ``DynamicsNetwork`` of a checkpoint's dict (``read_checkpoint``) in eval mode; a one-line
    ``CheckpointError`` where it does not build."""
    from physdyn.models.dynamics_network import DynamicsNetwork

    try:
        # Built as Lightning's load_from_checkpoint builds it, but from the dict read without running code:
        # that one reads the file again, and before Lightning 2.6 with weights_only=False.
        model = DynamicsNetwork(**raw["hyper_parameters"])
        model.on_load_checkpoint(raw)
        model.load_state_dict(raw["state_dict"])
    except PhysdynError:
        raise
    except Exception as exc:
        raise CheckpointError(f"cannot load {where} as a physdyn model: {type(exc).__name__}: "
                              f"{str(exc).splitlines()[0] if str(exc) else ''}") from None
    return model.eval()


def checkpoint_preset(raw: dict, weights: str) -> PredictorPreset:
    """The preset of a checkpoint of `physdyn fit`: its network (after a simulated start where its
    ``model.sim_seconds`` says so), the topple classifier `fit-topple` added (else the head) and the
    correction `fit-outcome` added (else none)."""
    model = raw["hyper_parameters"]["config"].get("model", {})
    seconds = float(model.get("sim_seconds") or 0.0)
    # no network steps the motion of a contact prior written as a checkpoint (`physdyn recipe fast`'s first step)
    prior_alone = (model.get("predictor") or {}).get("name") == "none" and model.get("prior") == "contact"
    motion = "simulated_start" if seconds > 0 else "contact_prior" if prior_alone else "network"
    return PredictorPreset(name=str(weights), weights=str(weights), motion=StageConfig(motion),
                           topple=StageConfig(_topples.stage_name(raw.get(_topples.CHECKPOINT_KEY))),
                           correction=StageConfig(_corrections.stage_name(raw.get(_corrections.CHECKPOINT_KEY))))


def build_pipeline(preset: PredictorPreset, physics: Any = None, checkpoint: dict | None = None) -> Pipeline:
    """The ``Pipeline`` of ``preset``: each stage looked up in its registry, its params checked against its
    ``Config``, and built from the preset's weights (``checkpoint``: their dict, where already read)."""
    from physdyn.models.checkpoint_file import read_checkpoint

    if checkpoint is None and preset.weights is not None:
        checkpoint = read_checkpoint(preset.weights)
    source = StageSource(checkpoint, physics, str(preset.weights))
    stages = {}
    for kind, registry in KINDS.items():
        stage = getattr(preset, kind)
        cls = registry.get(stage.name, f"{preset.name}: {kind}.name")
        config = registry.resolve_config(stage.name, stage.params, f"{preset.name}: {kind}.params")
        stages[kind] = cls.build(config, source)
    return Pipeline(**stages, name=preset.name)


def load_pipeline(spec: str | Path, physics: Any = None) -> Pipeline:
    """The one factory: a shipped preset's name ("fast", "bundled", "contact_prior"), a preset file (.yaml), or
    a checkpoint of `physdyn fit` (a path; its stages from its contents) -> its ``Pipeline``."""
    from physdyn.models.checkpoint_file import read_checkpoint

    path = Path(spec)
    if path.suffix in (".yaml", ".yml") and path.is_file():
        return build_pipeline(read_preset(path), physics)
    if not path.is_file() and preset_file(str(spec)).is_file() and path.suffix == "":
        return build_pipeline(read_preset(preset_file(str(spec))), physics)
    raw = read_checkpoint(path)
    return build_pipeline(checkpoint_preset(raw, str(spec)), physics, raw)
