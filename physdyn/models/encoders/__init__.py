"""Shape encoders, registered in ``physdyn.registry.ENCODERS``. Importing this package registers the built-ins."""

from physdyn.models.encoders import pointnet  # noqa: F401  (registers "pointnet")
from physdyn.models.encoders.base import ShapeEncoder

__all__ = ["ShapeEncoder"]
