"""Bottles: solids of revolution of a random profile (rounded base, body, shoulder, neck, lip).

Bottles are solid (closed at the mouth): the paper simulates objects at uniform density, and a bottle's
mass is dominated by its body either way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.geometry.families.primitives import finish, format_source, revolve_profile
from physdyn.registry import SHAPE_FAMILIES


@SHAPE_FAMILIES.register("bottles")
class Bottles(ShapeFamily):
    """Solid revolved bottles: rounded base, optional taper, shoulder, neck and lip."""

    @dataclass
    class Config:
        height_min: float = 0.12  # m, overall
        height_max: float = 0.35
        radius_min: float = 0.025  # m, body radius at the base
        radius_max: float = 0.055
        body_fraction_min: float = 0.35  # straight body height / overall height
        body_fraction_max: float = 0.7
        taper_min: float = 0.85  # body radius at the shoulder / at the base
        taper_max: float = 1.1
        neck_ratio_min: float = 0.25  # neck radius / body radius
        neck_ratio_max: float = 0.5
        neck_fraction_min: float = 0.08  # neck length / overall height
        neck_fraction_max: float = 0.25
        sections: int = 24

    def __init__(self, config: "Bottles.Config | None" = None):
        super().__init__(config if config is not None else Bottles.Config())

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        height = float(rng.uniform(cfg.height_min, cfg.height_max))
        radius = float(rng.uniform(cfg.radius_min, cfg.radius_max))
        radius = min(radius, 0.4 * height)  # a squat "bottle" would be a jar
        body = float(rng.uniform(cfg.body_fraction_min, cfg.body_fraction_max)) * height
        shoulder_radius = radius * float(rng.uniform(cfg.taper_min, cfg.taper_max))
        neck_radius = max(0.006, radius * float(rng.uniform(cfg.neck_ratio_min, cfg.neck_ratio_max)))
        neck = float(rng.uniform(cfg.neck_fraction_min, cfg.neck_fraction_max)) * height
        lip_height = float(rng.uniform(0.003, 0.01))
        lip_radius = neck_radius * float(rng.uniform(1.05, 1.3))
        fillet = radius * float(rng.uniform(0.05, 0.3))
        # Superellipse exponent of the shoulder: 1 is a straight cone, 2 round, 4 almost square.
        shoulder_shape = float(rng.uniform(1.0, 4.0))
        shoulder_top = height - neck - lip_height
        if shoulder_top <= body + 0.005:  # keep some shoulder: shorten the body
            body = shoulder_top - 0.005

        profile = [[0.0, 0.0]]
        # Rounded base: a quarter circle from the bottom face into the side.
        theta = np.linspace(-np.pi / 2, 0.0, 5)
        profile += [[radius - fillet + fillet * np.cos(t), fillet + fillet * np.sin(t)] for t in theta]
        profile.append([shoulder_radius, body])
        t = np.linspace(0.0, 1.0, 8)[1:-1]
        r_shoulder = neck_radius + (shoulder_radius - neck_radius) * (1.0 - t**shoulder_shape) ** (
            1.0 / shoulder_shape
        )
        profile += [[r, body + (shoulder_top - body) * ti] for r, ti in zip(r_shoulder, t)]
        profile += [
            [neck_radius, shoulder_top],
            [neck_radius, height - lip_height],
            [lip_radius, height - lip_height],
            [lip_radius, height],
            [0.0, height],
        ]
        mesh = revolve_profile(np.array(profile), sections=cfg.sections)
        source = format_source(
            "bottles",
            height=height,
            radius=radius,
            body=body,
            shoulder_radius=shoulder_radius,
            shoulder_shape=shoulder_shape,
            neck=neck,
            neck_radius=neck_radius,
            lip_height=lip_height,
            lip_radius=lip_radius,
            fillet=fillet,
        )
        return finish(mesh, self.category, source)

