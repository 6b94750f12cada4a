"""Speakers: boxes with sharp, rounded or bevelled edges; some on small feet, some with recessed driver
openings or a recessed front panel (on the -y face).

A rounded or bevelled cabinet is the convex hull of points placed so the hull's faces lie exactly on the
cabinet's faces, which keeps the front face flat for the recess cut.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict

import numpy as np
import trimesh

from physdyn.errors import ShapeError
from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.geometry.families.primitives import difference, finish, format_source, outward, union
from physdyn.registry import SHAPE_FAMILIES

EDGE_STYLES = ("sharp", "rounded", "rounded_vertical", "bevelled")
FRONT_STYLES = ("plain", "drivers", "panel")


def cabinet(extents: np.ndarray, edge: str, radius: float) -> trimesh.Trimesh:
    """Box of ``extents`` (3,) centred at the origin with its edges finished by ``edge`` of size ``radius``.

    rounded: every edge and corner a quarter circle; rounded_vertical: only the four vertical edges;
    bevelled: 45-degree chamfers on every edge.
    """
    if edge == "sharp":
        return trimesh.creation.box(extents=extents)
    half = np.asarray(extents, dtype=float) / 2.0
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    arc = np.linspace(0.0, np.pi / 2.0, 4)
    if edge == "rounded":
        # Octant of a sphere, including the three axis directions so the flat faces sit on the box.
        theta, phi = np.meshgrid(arc, arc)
        octant = np.column_stack(
            [
                (np.sin(theta) * np.cos(phi)).ravel(),
                (np.sin(theta) * np.sin(phi)).ravel(),
                np.cos(theta).ravel(),
            ]
        )
    elif edge == "rounded_vertical":
        # A quarter circle in xy; the corner sits at the top or bottom face (no z inset below).
        octant = np.column_stack([np.cos(arc), np.sin(arc), np.zeros_like(arc)])
    elif edge == "bevelled":
        octant = np.eye(3)
    else:
        raise ValueError(f"unknown edge style {edge}")
    inset = half - radius * np.array([1.0, 1.0, 0.0 if edge == "rounded_vertical" else 1.0])
    points = np.vstack([s * (inset + radius * octant) for s in signs])
    return outward(trimesh.convex.convex_hull(points))


@SHAPE_FAMILIES.register("speakers")
class Speakers(ShapeFamily):
    """Cabinets with sharp, rounded or bevelled edges, some on feet, some with front recesses."""

    @dataclass
    class Config:
        width_min: float = 0.1  # m, along x
        width_max: float = 0.3
        depth_min: float = 0.08  # m, along y
        depth_max: float = 0.3
        height_min: float = 0.1  # m, along z
        height_max: float = 0.45
        # Relative odds of each style. Overrides merge into these keys: set a style to 0 to drop it.
        edge_styles: Dict[str, float] = field(
            default_factory=lambda: {
                "sharp": 0.25,
                "rounded": 0.25,
                "rounded_vertical": 0.25,
                "bevelled": 0.25,
            }
        )
        front_styles: Dict[str, float] = field(
            default_factory=lambda: {"plain": 0.35, "drivers": 0.4, "panel": 0.25}
        )
        feet_probability: float = 0.4

    def __init__(self, config: "Speakers.Config | None" = None):
        super().__init__(config if config is not None else Speakers.Config())
        for key, allowed in (("edge_styles", EDGE_STYLES), ("front_styles", FRONT_STYLES)):
            odds = getattr(self.config, key)
            unknown = [k for k in odds if k not in allowed]
            if unknown or not odds or sum(odds.values()) <= 0 or min(odds.values()) < 0:
                raise ShapeError(
                    f"speakers.{key} must map some of {', '.join(allowed)} to non-negative odds with a "
                    f"positive sum, got {dict(odds)}"
                )

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        extents = np.array(
            [
                rng.uniform(cfg.width_min, cfg.width_max),
                rng.uniform(cfg.depth_min, cfg.depth_max),
                rng.uniform(cfg.height_min, cfg.height_max),
            ]
        )
        edge = _choose(cfg.edge_styles, rng)
        front = _choose(cfg.front_styles, rng)
        edge_size = 0.0 if edge == "sharp" else float(rng.uniform(0.004, min(0.03, 0.2 * extents.min())))
        width, depth, height = (float(v) for v in extents)
        params: dict = {"width": width, "depth": depth, "height": height, "edge": edge}
        if edge != "sharp":
            params["edge_size"] = edge_size

        body = cabinet(extents, edge, edge_size)
        # Flat region of the front face (the edge finish eats a band of edge_size around it).
        face_w = width - 2.0 * edge_size
        face_h = height - 2.0 * edge_size
        depth_cut = float(rng.uniform(0.003, min(0.015, 0.25 * depth)))
        cutters = []
        if front == "drivers":
            cutters, driver_params = _drivers(face_w, face_h, depth, depth_cut, rng)
            params.update(front=front, recess=depth_cut, **driver_params)
        elif front == "panel":
            margin = float(rng.uniform(0.005, 0.2 * min(face_w, face_h)))
            size = (face_w - 2 * margin, depth_cut + 0.02, face_h - 2 * margin)
            cutter = trimesh.creation.box(extents=size)
            cutter.apply_translation([0.0, -depth / 2.0 + depth_cut - size[1] / 2.0, 0.0])
            cutters = [cutter]
            params.update(front=front, recess=depth_cut, panel_margin=margin)
        else:
            params.update(front=front)
        if cutters:
            body = difference(body, cutters)

        if rng.uniform() < cfg.feet_probability:
            foot_r = float(rng.uniform(0.005, 0.015))
            foot_h = float(rng.uniform(0.004, 0.015))
            inset = edge_size + foot_r + float(rng.uniform(0.003, 0.02))
            # Feet overlap the cabinet by 2 mm so the union is one solid, not touching pieces.
            feet = []
            for sx in (-1, 1):
                for sy in (-1, 1):
                    foot = trimesh.creation.cylinder(radius=foot_r, height=foot_h + 0.002, sections=12)
                    foot.apply_translation(
                        [sx * (width / 2 - inset), sy * (depth / 2 - inset), -height / 2 - foot_h / 2 + 0.001]
                    )
                    feet.append(foot)
            body = union([body, *feet])
            params.update(foot_radius=foot_r, foot_height=foot_h, foot_inset=inset)
        return finish(body, self.category, format_source("speakers", **params))


def _choose(odds: Dict[str, float], rng: np.random.Generator) -> str:
    names = sorted(odds)  # sorted: the draw must not depend on YAML key order
    p = np.array([odds[n] for n in names], dtype=float)
    return names[int(rng.choice(len(names), p=p / p.sum()))]


def _drivers(
    face_w: float, face_h: float, depth: float, depth_cut: float, rng: np.random.Generator
) -> tuple[list, dict]:
    """Circular recesses on the front face: a woofer, plus a tweeter above it on a tall enough face."""

    def hole(radius: float, z_from_face_bottom: float) -> trimesh.Trimesh:
        length = depth_cut + 0.02  # pokes 2 cm out of the front so no face is coplanar with the cabinet
        cyl = trimesh.creation.cylinder(radius=radius, height=length, sections=24)
        cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        cyl.apply_translation([0.0, -depth / 2 + depth_cut - length / 2, -face_h / 2 + z_from_face_bottom])
        return cyl

    margin = 0.004
    if face_h > 1.4 * face_w:
        woofer = float(rng.uniform(0.5, 0.9)) * min(face_w / 2, 0.25 * face_h) - margin
        tweeter = float(rng.uniform(0.45, 0.8)) * min(face_w / 2, 0.2 * face_h) - margin
        cutters = [hole(woofer, 0.3 * face_h), hole(tweeter, 0.78 * face_h)]
        return cutters, {"woofer": woofer, "tweeter": tweeter}
    woofer = float(rng.uniform(0.5, 0.9)) * min(face_w, face_h) / 2 - margin
    return [hole(woofer, 0.5 * face_h)], {"woofer": woofer}
