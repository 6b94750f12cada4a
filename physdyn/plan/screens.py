"""The fast models of a screened search, built from the presets: the contact prior (``contact_prior_screen``)
or a predictor's own networks with nothing simulated (``network_screen``); ``screen_predictor`` makes each
once per predictor."""

from __future__ import annotations

import weakref
from typing import Any

from physdyn.predict.predictor import Predictor, contact_prior_predictor

SCREENS = ("prior", "model")  # the fast model of a screened search (docs/plan.md)

# Each predictor's screens, made once: kept beside the predictors, not on them, and forgotten with them.
_screens: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def screen_predictor(predictor: Any, screen: Any) -> Any:
    """The fast model of a screened search: "prior", the contact prior; "model", ``predictor``'s networks
    with nothing simulated (``network_screen``); each made once per predictor. A ``Predictor`` given is
    used as it is."""
    if not isinstance(screen, str):
        return screen
    made = _screens.setdefault(predictor, {})
    if screen not in made:
        fast = contact_prior_screen(predictor) if screen == "prior" else network_screen(predictor)
        if fast is predictor:  # a value holding its own key would keep the predictor alive
            return fast
        made[screen] = fast
    return made[screen]


def contact_prior_screen(predictor: Any) -> Predictor:
    """The ``contact_prior`` preset (no network, nothing learned, never topples) at ``predictor``'s rate and
    friction: 0.1-0.2 ms a candidate."""
    return contact_prior_predictor(predictor.physics, predictor.rate_hz)


def network_screen(predictor: Any) -> Any:
    """``predictor``'s networks with nothing simulated at inference (``Pipeline.without_simulator``): no
    simulated start, and a topple classifier that simulates gives way to the network's head. The weights are
    shared and ``predictor`` is left as it was; ``predictor`` itself when it simulates nothing."""
    pipeline = predictor.model.without_simulator()
    if pipeline is predictor.model:
        return predictor
    return Predictor(pipeline, name=f"{predictor.name} without simulator", physics=predictor.physics,
                     device=_device_of(pipeline.network))


def _device_of(network: Any) -> str:
    """Where ``network``'s weights are, so the screen sharing them leaves them there."""
    parameters = getattr(network, "parameters", None)
    first = next(iter(parameters()), None) if callable(parameters) else None
    return "cpu" if first is None else str(first.device)
