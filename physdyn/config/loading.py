"""YAML loading with ``defaults``, ``key=value`` overrides, and configs to and from plain dicts.

Configs are plain YAML merged onto a dataclass schema with OmegaConf, so an unknown key or a wrong type is a
one-line ``ConfigError`` naming the key. A YAML file may start with ``defaults: [other.yaml, ...]`` (paths
relative to the file) to compose presets from smaller files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, List, Type, TypeVar

import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from physdyn.config.rules import check_values
from physdyn.errors import ConfigError

S = TypeVar("S")


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
