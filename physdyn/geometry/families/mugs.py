"""Mugs: an open cup (walls of some thickness, solid bottom) with a loop handle on the +x side.

Built as (outer solid + handle) - cavity, so the part of the handle loop that would poke into the cup is
cut away with the cavity and the result is one watertight volume of genus 1 (the handle's hole).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.geometry.families.primitives import (
    difference,
    finish,
    format_source,
    revolve_profile,
    tube_loop,
    union,
)
from physdyn.registry import SHAPE_FAMILIES


@SHAPE_FAMILIES.register("mugs")
class Mugs(ShapeFamily):
    """Open cups with a wall, a solid bottom and a handle, as one watertight body."""

    @dataclass
    class Config:
        height_min: float = 0.07  # m
        height_max: float = 0.13
        radius_min: float = 0.03  # m, outer radius at the base
        radius_max: float = 0.05
        taper_min: float = 0.9  # outer radius at the rim / at the base
        taper_max: float = 1.25
        wall_min: float = 0.003  # m
        wall_max: float = 0.007
        bottom_min: float = 0.005  # m, thickness of the base
        bottom_max: float = 0.012
        sections: int = 24

    def __init__(self, config: "Mugs.Config | None" = None):
        super().__init__(config if config is not None else Mugs.Config())

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        height = float(rng.uniform(cfg.height_min, cfg.height_max))
        radius = float(rng.uniform(cfg.radius_min, cfg.radius_max))
        rim_radius = radius * float(rng.uniform(cfg.taper_min, cfg.taper_max))
        wall = float(rng.uniform(cfg.wall_min, cfg.wall_max))
        bottom = float(rng.uniform(cfg.bottom_min, cfg.bottom_max))
        # Handle: a loop (superellipse path, round tube) centred on the outer wall.
        tube = float(rng.uniform(0.0035, 0.007))
        reach = float(rng.uniform(0.014, 0.03))  # how far the loop's centre line leaves the wall
        # Half the loop's height; the loop stays 4 mm clear of the rim and the base.
        span = min(float(rng.uniform(0.3, 0.42)) * height, height / 2.0 - tube - 0.004)
        centre_z = height / 2.0 + float(rng.uniform(-0.5, 0.5)) * (height / 2.0 - span - tube - 0.004)
        squareness = float(rng.uniform(2.0, 4.0))  # 2: elliptical loop, 4: D-shaped

        outer = revolve_profile(
            np.array([[0.0, 0.0], [radius, 0.0], [rim_radius, height], [0.0, height]]), cfg.sections
        )
        # The cavity pokes out above the rim so the difference leaves a clean opening, not a skin.
        slope = (rim_radius - radius) / height
        cavity_top = height + 0.01
        cavity = revolve_profile(
            np.array(
                [
                    [0.0, bottom],
                    [radius + slope * bottom - wall, bottom],
                    [radius + slope * cavity_top - wall, cavity_top],
                    [0.0, cavity_top],
                ]
            ),
            cfg.sections,
        )
        wall_x = radius + slope * centre_z  # outer wall at the handle's height
        angle = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
        cos, sin = np.cos(angle), np.sin(angle)
        exponent = 2.0 / squareness
        path = np.column_stack(
            [
                wall_x + reach * np.sign(cos) * np.abs(cos) ** exponent,
                np.zeros_like(angle),
                centre_z + span * np.sign(sin) * np.abs(sin) ** exponent,
            ]
        )
        handle = tube_loop(path, radius_in_plane=tube, radius_y=tube * 1.2, sections=10)
        mesh = difference(union([outer, handle]), [cavity])
        source = format_source(
            "mugs",
            height=height,
            radius=radius,
            rim_radius=rim_radius,
            wall=wall,
            bottom=bottom,
            handle_tube=tube,
            handle_reach=reach,
            handle_span=span,
            handle_z=centre_z,
            handle_squareness=squareness,
        )
        return finish(mesh, self.category, source)
