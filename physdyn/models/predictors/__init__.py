"""State predictors, registered in ``physdyn.registry.PREDICTORS``. Importing this package registers the built-ins."""

from physdyn.models.predictors import lstm, mlp, none  # noqa: F401  (registers "lstm", "mlp", "none")
from physdyn.models.predictors.base import StatePredictor

__all__ = ["StatePredictor"]
