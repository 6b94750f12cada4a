"""State predictors, registered in ``physdyn.registry.PREDICTORS``. Importing this package registers the built-ins."""

from physdyn.models.predictors import lstm, mlp  # noqa: F401  (registers "lstm", "mlp")
from physdyn.models.predictors.base import StatePredictor

__all__ = ["StatePredictor"]
