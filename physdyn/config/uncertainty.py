"""The uncertainty of a push: how well a user knows the velocities right after it and the friction.

Defined in docs/conventions.md ("Uncertainty of a push"): each member of an ensemble draws its own standard
normals N once and perturbs the push's post-push state by them. A preset is a name (``none``, ``low``,
``default``); anywhere a preset is accepted, a mapping of ``UncertaintyConfig``'s keys is too, its missing
keys taken from ``default``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from physdyn.config.loading import config_from_dict
from physdyn.config.rules import VALUE_RULES, check_values, within
from physdyn.errors import ConfigError


@dataclass
class UncertaintyConfig:
    """Standard deviations of a push's perturbation. The defaults are the ``default`` preset (the 3 % level)."""

    speed_rel: float = 0.03  # post-push speed x (1 + speed_rel N)
    direction_deg: float = 3.0  # post-push velocity turned by direction_deg N degrees about the vertical
    spin_rel: float = 0.03  # each axis of the angular velocity + spin_rel |w| N ...
    spin_abs: float = 0.3  # rad/s: ... + spin_abs N (a push that barely spins is not known to spin zero)
    friction_rel: float = 0.03  # the effective Coulomb coefficient x (1 + friction_rel N)

    @property
    def is_zero(self) -> bool:
        return not any(getattr(self, f.name) for f in dataclasses.fields(self))


def uncertainty_at_level(sigma: float) -> UncertaintyConfig:
    """The one-parameter family the presets come from (sigma = 0.03 is ``default``): relative spreads
    sigma, direction 100 sigma degrees, absolute spin 10 sigma rad/s."""
    return UncertaintyConfig(speed_rel=sigma, direction_deg=100.0 * sigma, spin_rel=sigma, spin_abs=10.0 * sigma,
                             friction_rel=sigma)


UNCERTAINTY_PRESETS: dict[str, UncertaintyConfig] = {
    "none": uncertainty_at_level(0.0),  # the push known exactly: every member is the unperturbed push
    "low": uncertainty_at_level(0.01),  # 1 %, 1 degree, 0.1 rad/s
    "default": uncertainty_at_level(0.03),  # 3 %, 3 degrees, 0.3 rad/s: what distributions are scored at
}

_RELATIVE = (within(0, 0.5), "a relative standard deviation from 0 to 0.5 (the default preset: 0.03)")
VALUE_RULES[UncertaintyConfig] = {
    "speed_rel": _RELATIVE,
    "direction_deg": (within(0, 45), "degrees from 0 to 45 (the default preset: 3)"),
    "spin_rel": _RELATIVE,
    "spin_abs": (within(0, 5), "rad/s from 0 to 5 (the default preset: 0.3)"),
    "friction_rel": _RELATIVE,
}


def resolve_uncertainty(value: Any, key: str = "uncertainty") -> UncertaintyConfig:
    """An uncertainty from a preset name, a mapping of ``UncertaintyConfig``'s keys (missing ones from
    ``default``) or an ``UncertaintyConfig``. A bad name, an unknown key, a negative, non-finite or absurd
    value is a one-line ConfigError naming ``key`` and the fix."""
    if isinstance(value, str):
        if value not in UNCERTAINTY_PRESETS:
            raise ConfigError(f"config key '{key}': '{value}' is not an uncertainty preset; use one of "
                              f"{', '.join(UNCERTAINTY_PRESETS)} or a mapping of speed_rel, direction_deg, spin_rel, "
                              f"spin_abs, friction_rel")
        return dataclasses.replace(UNCERTAINTY_PRESETS[value])
    if isinstance(value, UncertaintyConfig):
        config = dataclasses.replace(value)
    elif isinstance(value, Mapping):
        config = config_from_dict(UncertaintyConfig, dict(value), where=key)
    else:
        raise ConfigError(f"config key '{key}': {value!r} is not an uncertainty; use a preset name "
                          f"({', '.join(UNCERTAINTY_PRESETS)}) or a mapping such as {{speed_rel: 0.03}}")
    check_values(config, f"{key}.")
    return config
