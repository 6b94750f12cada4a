"""Irregular solids: a few random convex pieces fused into one, like pybullet_data's random_urdfs objects
(which are 5-8 overlapping convex polyhedra each). The procedural families are revolved or box-like and
mostly convex; these give training shapes with many facets, no symmetry and a footprint that changes as
they turn (docs/ablations.md, "A PointNet over the impact phase").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from physdyn.errors import ShapeError
from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.geometry.families.primitives import finish, format_source, outward, union
from physdyn.registry import SHAPE_FAMILIES


def convex_piece(rng: np.random.Generator, size: float, points: int) -> trimesh.Trimesh:
    """The hull of ``points`` random points in a box of random proportions, largest side ``size``."""
    box = size * rng.uniform(0.35, 1.0, size=3)
    box[rng.integers(3)] = size
    return outward(trimesh.convex.convex_hull(rng.uniform(-0.5, 0.5, size=(points, 3)) * box))


@SHAPE_FAMILIES.register("blobs")
class Blobs(ShapeFamily):
    """``pieces_min``-``pieces_max`` convex pieces, each added overlapping a random surface point of what is
    already there, fused (exact union); then scaled so the largest extent is in [size_min, size_max]."""

    @dataclass
    class Config:
        pieces_min: int = 3
        pieces_max: int = 8
        points_per_piece: int = 24  # random points whose hull is a piece (4 at least)
        size_min: float = 0.06  # m, largest extent of the whole solid
        size_max: float = 0.3

    def __init__(self, config: "Blobs.Config | None" = None):
        super().__init__(config if config is not None else Blobs.Config())
        c = self.config
        if not (1 <= c.pieces_min <= c.pieces_max) or c.points_per_piece < 4 or not (0 < c.size_min <= c.size_max):
            raise ShapeError("blobs needs 1 <= pieces_min <= pieces_max, points_per_piece >= 4 and "
                             "0 < size_min <= size_max; fix the blobs parameters in the data config")

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        count = int(rng.integers(cfg.pieces_min, cfg.pieces_max + 1))
        solid = convex_piece(rng, 1.0, cfg.points_per_piece)
        for _ in range(count - 1):
            piece = convex_piece(rng, float(rng.uniform(0.5, 1.0)), cfg.points_per_piece)
            # centred on a point of the surface so far, pushed a little inwards: the pieces always overlap
            anchor, face = trimesh.sample.sample_surface(solid, 1, seed=int(rng.integers(2**31)))
            piece.apply_transform(trimesh.transformations.random_rotation_matrix(rng.uniform(size=3)))
            piece.apply_translation(anchor[0] - 0.15 * solid.face_normals[face[0]])
            solid = union([solid, piece])
        size = float(rng.uniform(cfg.size_min, cfg.size_max))
        solid.apply_scale(size / float(solid.extents.max()))
        return finish(solid, self.category, format_source("blobs", pieces=count, size=size))
