"""Output heads, registered in ``physdyn.registry.HEADS``. Importing this package registers the built-ins."""

from physdyn.models.heads import topple  # noqa: F401  (registers "topple", "no_topple")
from physdyn.models.heads.base import NUM_CHANGES, PredictionHead

__all__ = ["NUM_CHANGES", "PredictionHead"]
