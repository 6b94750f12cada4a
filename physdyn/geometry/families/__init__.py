"""Shape families, registered by name in ``physdyn.registry.SHAPE_FAMILIES``.

Importing this package registers the built-ins.
"""

from physdyn.geometry.families import (  # noqa: F401  (imported to register)
    bottles,
    clusters,
    meshes,
    mugs,
    primitives,
    speakers,
    trashcans,
)
from physdyn.geometry.families.base import ShapeFamily, ShapeInstance

__all__ = ["ShapeFamily", "ShapeInstance"]
