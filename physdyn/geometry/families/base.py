"""The interface every shape family implements."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass
class ShapeInstance:
    """One object drawn from a family.

    mesh: closed triangle mesh in its own (mesh) frame, metres, z up in its design pose.
    category: the family's category name (stored in ``shapes/category``'s attribute names).
    source: how to get it again: "bottles(height=0.231, radius=0.041, ...)" or a file path.
    """

    mesh: trimesh.Trimesh
    category: str
    source: str


class ShapeFamily(ABC):
    """A source of shapes. Subclasses register with ``@SHAPE_FAMILIES.register("name")`` and may define a
    dataclass ``Config`` with their parameters (size ranges, ...), passed to ``__init__``.

    ``make`` must be a pure function of ``(index, rng)``: the dataset is identical whatever the worker count,
    so a family keeps no state between calls.
    """

    category: str = ""

    def __init__(self, config=None):
        self.config = config
        if not self.category:
            self.category = getattr(type(self), "registered_name", type(self).__name__.lower())

    def num_shapes(self, requested: int) -> int:
        """How many instances this family yields for a request (a mesh folder yields its file count)."""
        return requested

    @abstractmethod
    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        """Instance ``index``, drawn with ``rng`` (seeded per instance by the caller).

        Raises ``physdyn.errors.ShapeError`` for an unusable shape; the generator skips and reports it.
        """
