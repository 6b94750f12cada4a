"""Value rules: what the schemas' types cannot say (ranges, finiteness, relations between keys).

Each schema module adds its rules to ``VALUE_RULES`` (schema -> field -> (check, what is allowed)) and
``RELATION_RULES`` (schema -> a function returning the first broken rule between keys); ``check_values``
walks a loaded config and its nested configs after every load.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

from physdyn.errors import ConfigError


def within(low: float | None = None, high: float | None = None, low_open: bool = False) -> Callable[[Any], bool]:
    """A check that a value is a finite number (not a bool) in [low, high], low excluded with ``low_open``."""

    def check(x: Any) -> bool:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            return False
        if low is not None and (x <= low if low_open else x < low):
            return False
        return high is None or x <= high
    return check


POSITIVE = (within(0, low_open=True), "a positive finite number")
NON_NEGATIVE = (within(0), "a finite number >= 0")
FRACTION = (within(0, 1), "a fraction between 0 and 1")
COUNT = (within(1), "a whole number >= 1")

# schema -> field -> (check, what is allowed). Walked by ``check_values`` after every load.
VALUE_RULES: dict[type, dict[str, tuple[Callable[[Any], bool], str]]] = {}

# schema -> the first broken rule between its keys, as (key, message), or None.
RELATION_RULES: dict[type, Callable[[Any], tuple[str, str] | None]] = {}


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
