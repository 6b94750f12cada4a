"""Trash cans: open-topped bins with walls of some thickness, round or polygonal (square, hexagonal,
octagonal), straight or tapered wider at the top, some with a rolled rim.

The whole wall is one revolved cross-section, so no boolean is needed: revolving with 4 sections gives a
square bin with flat walls, with 24 a round one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict

import numpy as np

from physdyn.errors import ShapeError
from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.geometry.families.primitives import finish, format_source, revolve_profile
from physdyn.registry import SHAPE_FAMILIES

# Cross-section name -> revolution sections. A polygon's "radius" is to its corners.
CROSS_SECTIONS: Dict[str, int] = {"round": 24, "square": 4, "hexagonal": 6, "octagonal": 8}


@SHAPE_FAMILIES.register("trashcans")
class Trashcans(ShapeFamily):
    """Open-top bins: round, square or polygonal, straight or tapered, with a wall and an optional rim."""

    @dataclass
    class Config:
        # Relative odds of each cross-section. Overrides merge into these keys: set a shape to 0 to drop it.
        cross_sections: Dict[str, float] = field(
            default_factory=lambda: {"round": 0.45, "square": 0.35, "hexagonal": 0.1, "octagonal": 0.1}
        )
        height_min: float = 0.2  # m
        height_max: float = 0.45
        radius_min: float = 0.08  # m, at the base (to the corners for a polygon)
        radius_max: float = 0.15
        taper_probability: float = 0.5  # otherwise straight walls
        taper_max: float = 1.35  # rim radius / base radius of a tapered bin
        wall_min: float = 0.003  # m
        wall_max: float = 0.01
        bottom_min: float = 0.005  # m
        bottom_max: float = 0.015
        rim_probability: float = 0.4
        stretch_min: float = 0.7  # depth / width of a polygonal bin (1 = regular polygon)

    def __init__(self, config: "Trashcans.Config | None" = None):
        super().__init__(config if config is not None else Trashcans.Config())
        odds = self.config.cross_sections
        unknown = [k for k in odds if k not in CROSS_SECTIONS]
        if unknown or not odds or sum(odds.values()) <= 0 or min(odds.values()) < 0:
            raise ShapeError(
                f"trashcans.cross_sections must map some of {', '.join(CROSS_SECTIONS)} to non-negative "
                f"odds with a positive sum, got {dict(odds)}"
            )

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        names = sorted(cfg.cross_sections)  # sorted: the draw must not depend on YAML key order
        odds = np.array([cfg.cross_sections[n] for n in names], dtype=float)
        shape = names[int(rng.choice(len(names), p=odds / odds.sum()))]
        sections = CROSS_SECTIONS[shape]
        height = float(rng.uniform(cfg.height_min, cfg.height_max))
        radius = float(rng.uniform(cfg.radius_min, cfg.radius_max))
        tapered = bool(rng.uniform() < cfg.taper_probability)
        rim_radius = radius * (float(rng.uniform(1.05, cfg.taper_max)) if tapered else 1.0)
        wall = float(rng.uniform(cfg.wall_min, cfg.wall_max))
        bottom = float(rng.uniform(cfg.bottom_min, cfg.bottom_max))
        has_rim = bool(rng.uniform() < cfg.rim_probability)
        lip_width = float(rng.uniform(0.004, 0.012)) if has_rim else 0.0
        lip_height = float(rng.uniform(0.01, 0.03)) if has_rim else 0.0
        stretch = float(rng.uniform(cfg.stretch_min, 1.0)) if sections < 24 else 1.0

        # Wall cross-section, counter-clockwise from the axis under the base round to the axis on the
        # inside of the base: bottom face, outer wall (with the rolled lip), rim, inner wall.
        slope = (rim_radius - radius) / height
        lip_base = height - lip_height
        profile = [[0.0, 0.0], [radius, 0.0]]
        if has_rim:
            profile += [
                [radius + slope * lip_base, lip_base],
                [radius + slope * lip_base + lip_width, lip_base],
                [rim_radius + lip_width, height],
            ]
        else:
            profile += [[rim_radius, height]]
        profile += [
            [rim_radius - wall, height],
            [radius + slope * bottom - wall, bottom],
            [0.0, bottom],
        ]
        # A polygon's corner sits at angle 0; rotate so its flat sides face the axes (pi / sections).
        mesh = revolve_profile(np.array(profile), sections, angle_offset=np.pi / sections)
        if stretch != 1.0:
            mesh.apply_scale([1.0, stretch, 1.0])
        source = format_source(
            "trashcans",
            shape=shape,
            height=height,
            radius=radius,
            rim_radius=rim_radius,
            wall=wall,
            bottom=bottom,
            lip_width=lip_width,
            lip_height=lip_height,
            stretch=stretch,
        )
        return finish(mesh, self.category, source)
