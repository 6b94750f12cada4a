"""One registry per component kind, filled by decorators and by Python entry points.

Built-in components register when their module is imported; third-party packages add theirs through an
entry-point group (``physdyn.encoders``, ...). A plugin that fails to import warns and is skipped, so a
broken plugin never breaks ``physdyn --help``.
"""

from __future__ import annotations

import dataclasses
import importlib
import warnings
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Callable, Generic, TypeVar

from omegaconf import OmegaConf

from physdyn.config import config_from_dict
from physdyn.errors import ConfigError

T = TypeVar("T")


@dataclass(frozen=True)
class Entry:
    name: str
    cls: type
    source: str  # "built-in" or "plugin <distribution>"

    @property
    def config_class(self) -> type | None:
        """The component's typed config: a dataclass named ``Config`` on the class, if any."""
        cfg = getattr(self.cls, "Config", None)
        return cfg if cfg is not None and dataclasses.is_dataclass(cfg) else None


class Registry(Generic[T]):
    """Maps names to component classes of one kind.

    ``builtin_modules`` are imported before the first lookup so built-ins are always present;
    ``group`` is the entry-point group scanned for plugins (each entry point loads a module or a class
    whose import registers the component).
    """

    def __init__(self, kind: str, group: str, builtin_modules: tuple[str, ...] = ()):
        self.kind = kind
        self.group = group
        self._builtin_modules = builtin_modules
        self._entries: dict[str, Entry] = {}
        self._loaded = False
        self._loading_source = "built-in"

    def register(self, name: str) -> Callable[[type[T]], type[T]]:
        def decorator(cls: type[T]) -> type[T]:
            if name in self._entries and self._entries[name].cls is not cls:
                raise ValueError(
                    f"{self.kind} '{name}' is registered twice "
                    f"({self._entries[name].cls.__module__} and {cls.__module__}); rename one"
                )
            self._entries[name] = Entry(name, cls, self._loading_source)
            cls.registered_name = name  # type: ignore[attr-defined]
            return cls

        return decorator

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        for module in self._builtin_modules:
            importlib.import_module(module)
        for ep in entry_points(group=self.group):
            dist = ep.dist.name if ep.dist is not None else ep.value
            self._loading_source = f"plugin {dist}"
            try:
                ep.load()
            except Exception as exc:  # a broken plugin must not take the tool down
                warnings.warn(
                    f"physdyn: skipping {self.kind} plugin '{ep.name}' from {dist}: "
                    f"{type(exc).__name__}: {exc}",
                    stacklevel=2,
                )
            finally:
                self._loading_source = "built-in"

    def entries(self) -> list[Entry]:
        self._load()
        return sorted(self._entries.values(), key=lambda e: e.name)

    def names(self) -> list[str]:
        return [e.name for e in self.entries()]

    def get(self, name: str, name_key: str = "") -> type[T]:
        """The class registered as ``name``; an unknown name is a ConfigError naming the config key
        ``name_key`` (e.g. ``model.encoder.name``) when given."""
        self._load()
        if name not in self._entries:
            known = ", ".join(self.names()) or "none"
            prefix = f"config key '{name_key}': " if name_key else ""
            raise ConfigError(f"{prefix}unknown {self.kind} '{name}'; registered: {known}")
        return self._entries[name].cls

    def resolve_config(self, name: str, params: Any = None, where: str = "", name_key: str = "") -> Any:
        """Validate ``params`` (a mapping) against the component's ``Config`` and return a typed copy.

        Unknown keys and wrong types raise a one-line ``ConfigError`` naming ``where.key``; an unknown
        ``name`` one naming ``name_key``.
        """
        self.get(name, name_key)
        cfg_cls = self._entries[name].config_class
        params = {} if params is None else params
        if OmegaConf.is_config(params):
            params = OmegaConf.to_container(params, resolve=True)
        if cfg_cls is None:
            if params:
                raise ConfigError(f"{where or self.kind}: {self.kind} '{name}' takes no parameters")
            return None
        return config_from_dict(cfg_cls, params, where)

    def build(self, name: str, params: Any = None, where: str = "", **kwargs: Any) -> T:
        """Instantiate ``name`` with its validated config (first argument) and runtime ``kwargs``."""
        cls = self.get(name)
        config = self.resolve_config(name, params, where)
        return cls(config, **kwargs) if config is not None else cls(**kwargs)  # type: ignore[call-arg]


SHAPE_FAMILIES: Registry = Registry(
    "shape family", "physdyn.shape_families", ("physdyn.geometry.families",)
)
ENCODERS: Registry = Registry("encoder", "physdyn.encoders", ("physdyn.models.encoders",))
PREDICTORS: Registry = Registry("predictor", "physdyn.predictors", ("physdyn.models.predictors",))
HEADS: Registry = Registry("head", "physdyn.heads", ("physdyn.models.heads",))
# A predictor's stages (physdyn.pipeline.stages): what a predictor preset names (configs/predictor/)
MOTION_STAGES: Registry = Registry("motion stage", "physdyn.motion_stages", ("physdyn.pipeline.motion",))
TOPPLE_STAGES: Registry = Registry("topple stage", "physdyn.topple_stages", ("physdyn.pipeline.topple",))
CORRECTION_STAGES: Registry = Registry("correction stage", "physdyn.correction_stages", ("physdyn.pipeline.correction",))
DISTRIBUTION_STAGES: Registry = Registry("distribution stage", "physdyn.distribution_stages", ("physdyn.pipeline.spread",))

ALL_REGISTRIES: dict[str, Registry] = {
    "shape_families": SHAPE_FAMILIES,
    "encoders": ENCODERS,
    "predictors": PREDICTORS,
    "heads": HEADS,
    "motion_stages": MOTION_STAGES,
    "topple_stages": TOPPLE_STAGES,
    "correction_stages": CORRECTION_STAGES,
    "distribution_stages": DISTRIBUTION_STAGES,
}
