"""Whether two networks can be combined into one model, the second giving the velocity and position changes
(``DynamicsNetwork.linear_channels``; `python -m physdyn.models.export --linear-from`)."""

from __future__ import annotations

from typing import Any

from physdyn.errors import ConfigError


def check_combinable(model: Any, linear: Any) -> None:
    """A one-line ``ConfigError`` where ``linear`` cannot give ``model`` its velocity and position changes: it
    combines two networks itself, it reads an orientation ``model`` does not track, or it runs at another rate."""
    if linear.linear_channels is not None:
        raise ConfigError("the model for the linear channels combines two networks itself; pass a plain one")
    if linear.uses_orientation and not model.uses_orientation:
        raise ConfigError("the model for the linear channels is fed its orientation since step 0 and this one does not "
                          "track it; combine it with a model trained with model.orientation_input=true")
    if abs(float(linear.data_info.get("rate_hz", 15.0)) - float(model.data_info.get("rate_hz", 15.0))) > 1e-9:
        raise ConfigError(f"the two models predict at different rates ({linear.data_info.get('rate_hz')} and "
                          f"{model.data_info.get('rate_hz')} Hz); pass models trained on stores of the same rate")
