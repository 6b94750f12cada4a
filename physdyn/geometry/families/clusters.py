"""Irregular solids: a few random convex pieces fused into one, the way most of pybullet_data's random_urdfs
objects are made (overlapping convex polyhedra). The other families are revolved or box-like and mostly
convex; these give training shapes with many facets, no symmetry and a footprint that changes as they turn
(docs/research/learned-impact.md).
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
    """The hull of ``points`` random points in a box of random proportions (largest side ``size``), its
    centroid at the origin."""
    box = size * rng.uniform(0.35, 1.0, size=3)
    box[rng.integers(3)] = size
    piece = outward(trimesh.convex.convex_hull(rng.uniform(-0.5, 0.5, size=(points, 3)) * box))
    piece.apply_translation(-piece.center_mass)
    return piece


@SHAPE_FAMILIES.register("clusters")
class Clusters(ShapeFamily):
    """Irregular solids: random convex pieces fused into one, like pybullet_data's random_urdfs objects.

    ``pieces_min``-``pieces_max`` pieces, each centred on a vertex of an earlier one (so it always overlaps
    the solid so far), fused (exact union); then scaled so the largest extent is in [size_min, size_max]."""

    @dataclass
    class Config:
        pieces_min: int = 3
        pieces_max: int = 8
        points_per_piece: int = 24  # random points whose hull is a piece: fewer give slivers
        size_min: float = 0.06  # m, largest extent of the whole solid
        size_max: float = 0.3

    def __init__(self, config: "Clusters.Config | None" = None):
        super().__init__(config if config is not None else Clusters.Config())
        c = self.config
        if not 1 <= c.pieces_min <= c.pieces_max:
            raise ShapeError(f"clusters: pieces_min={c.pieces_min}, pieces_max={c.pieces_max}; "
                             "set 1 <= pieces_min <= pieces_max in the data config")
        if c.points_per_piece < 8:
            raise ShapeError(f"clusters: points_per_piece={c.points_per_piece}; set it to 8 or more in the data "
                             "config (fewer make flat slivers)")
        if not 0 < c.size_min <= c.size_max:
            raise ShapeError(f"clusters: size_min={c.size_min}, size_max={c.size_max}; set "
                             "0 < size_min <= size_max (metres) in the data config")

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        count = int(rng.integers(cfg.pieces_min, cfg.pieces_max + 1))
        size = float(rng.uniform(cfg.size_min, cfg.size_max))
        source = format_source("clusters", pieces=count, size=size)
        pieces = [convex_piece(rng, 1.0, cfg.points_per_piece)]
        solid = pieces[0]
        for _ in range(count - 1):
            piece = convex_piece(rng, float(rng.uniform(0.5, 1.0)), cfg.points_per_piece)
            piece.apply_transform(trimesh.transformations.random_rotation_matrix(rng.uniform(size=3)))
            # Centred on the outermost vertex of an earlier piece in a random direction: a point of the
            # solid, so the new piece (whose centroid is inside it) always shares volume with it. Chosen by
            # direction, not by index, so that no library's vertex or face order changes the shape.
            host = pieces[int(rng.integers(len(pieces)))]
            direction = rng.normal(size=3)
            piece.apply_translation(host.vertices[int(np.argmax(host.vertices @ direction))])
            pieces.append(piece)
            solid = union([solid, piece])
        # The union can enclose a tiny void (an inside-out shell, negative volume): filled, it changes the mass
        # by ppm. A second solid body would be a bug: the pieces always overlap.
        bodies = [b for b in solid.split(only_watertight=False) if b.volume > 1e-6 * solid.volume]
        if len(bodies) != 1:
            raise ShapeError(f"{source} fused into {len(bodies)} solids; this is a bug in the 'clusters' family")
        solid = bodies[0]
        solid.apply_scale(size / float(solid.extents.max()))
        return finish(solid, self.category, source)
