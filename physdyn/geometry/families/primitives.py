"""Primitive solids with random non-uniform scale, and the small solid builders the other families share.

The builders (``revolve_profile``, ``tube_loop``, ``union``, ``difference``, ...) return closed, outward-wound
triangle meshes, so a family composed from them stays a watertight volume.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, List

import numpy as np
import trimesh

from physdyn.errors import ShapeError
from physdyn.geometry.families.base import ShapeFamily, ShapeInstance
from physdyn.registry import SHAPE_FAMILIES


# --------------------------------------------------------------------------------------------------
# Shared builders
# --------------------------------------------------------------------------------------------------
def format_source(family: str, **params: object) -> str:
    """``family(key=value,...)`` with floats to 4 significant digits: enough to tell instances apart."""
    parts = []
    for key, value in params.items():
        if isinstance(value, (float, np.floating)):
            parts.append(f"{key}={float(value):.4g}")
        else:
            parts.append(f"{key}={value}")
    return f"{family}({','.join(parts)})"


def revolve_profile(profile_rz: np.ndarray, sections: int, angle_offset: float = 0.0) -> trimesh.Trimesh:
    """Solid of revolution about z of a profile polyline.

    profile_rz: (P, 2) (radius, height) points, counter-clockwise in the (r, z) half-plane, starting and
        ending on the axis (r = 0). Ending on the axis is what closes the surface: revolving an open end
        would leave a hole.
    sections: points per revolution (4 gives a square cross-section, 24 a round one).
    angle_offset: rotation about z in radians (rotates a square section by 45 degrees to face the axes).
    """
    profile_rz = np.asarray(profile_rz, dtype=np.float64)
    if profile_rz[0, 0] != 0.0 or profile_rz[-1, 0] != 0.0:
        raise ValueError("profile must start and end on the axis (r = 0) to give a closed solid")
    # Consecutive points closer than 0.1 mm: revolve drops the near-zero-area faces between them, which
    # would leave a hole; keep the first of each such run.
    keep = np.ones(len(profile_rz), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(profile_rz, axis=0), axis=1) > 1e-4
    profile_rz = profile_rz[keep]
    transform = trimesh.transformations.rotation_matrix(angle_offset, [0, 0, 1]) if angle_offset else None
    # process=True merges the coincident vertices on the axis, which closes the poles.
    mesh = trimesh.creation.revolve(profile_rz, sections=sections, transform=transform, process=True)
    return outward(mesh)


def tube_loop(path: np.ndarray, radius_in_plane: float, radius_y: float, sections: int) -> trimesh.Trimesh:
    """Closed tube (a torus topologically) around a closed planar path in the xz plane.

    path: (K, 3) points of the loop with y = 0, in order, not repeating the first point.
    radius_in_plane / radius_y: semi-axes of the elliptical cross-section, in the xz plane and along y.
    """
    path = np.asarray(path, dtype=np.float64)
    k = len(path)
    tangent = np.roll(path, -1, axis=0) - np.roll(path, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    y_axis = np.array([0.0, 1.0, 0.0])
    normal = np.cross(tangent, y_axis)  # in the xz plane, perpendicular to the path
    phi = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    ring = (
        path[:, None, :]
        + radius_in_plane * np.cos(phi)[None, :, None] * normal[:, None, :]
        + radius_y * np.sin(phi)[None, :, None] * y_axis[None, None, :]
    ).reshape(-1, 3)
    i = np.arange(k)[:, None]
    j = np.arange(sections)[None, :]
    a = (i * sections + j).ravel()
    b = (((i + 1) % k) * sections + j).ravel()
    c = (((i + 1) % k) * sections + (j + 1) % sections).ravel()
    d = (i * sections + (j + 1) % sections).ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return outward(trimesh.Trimesh(ring, faces, process=False))


def outward(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Flip ``mesh`` in place if its faces wind inwards (negative signed volume); returns it."""
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def union(meshes: List[trimesh.Trimesh]) -> trimesh.Trimesh:
    # manifold is exact and fast (~1 ms here); check_volume is skipped because the builders guarantee it.
    return trimesh.boolean.union(meshes, engine="manifold", check_volume=False)


def difference(mesh: trimesh.Trimesh, cutters: List[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.difference([mesh, *cutters], engine="manifold", check_volume=False)


def place_on_ground(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Translate in place so the bounding box is centred on the z axis and its bottom is at z = 0."""
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    return mesh


def finish(mesh: trimesh.Trimesh, category: str, source: str) -> ShapeInstance:
    """Check the generated mesh is a closed volume, set it on the ground and wrap it.

    A generator bug (or a parameter corner case) must surface as a ShapeError the dataset builder can
    report and skip, not as a leaky mesh with meaningless mass properties.
    """
    if not mesh.is_volume:
        raise ShapeError(f"{source} is not a closed volume; this is a bug in the '{category}' family")
    return ShapeInstance(mesh=place_on_ground(mesh), category=category, source=source)


# --------------------------------------------------------------------------------------------------
# The primitives family
# --------------------------------------------------------------------------------------------------
def _unit_box(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    return trimesh.creation.box(extents=(1.0, 1.0, 1.0)), {}


def _unit_cylinder(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    return trimesh.creation.cylinder(radius=0.5, height=1.0, sections=24), {}


def _unit_cone(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    return trimesh.creation.cone(radius=0.5, height=1.0, sections=24), {}


def _unit_truncated_cone(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    ratio = float(rng.uniform(0.2, 0.8))  # small radius / large radius
    # Upside-down half the time: a wide top on a narrow base topples differently.
    top_ratio = 1.0 / ratio if rng.uniform() < 0.5 else ratio  # top radius / bottom radius
    bottom, top = (0.5 * ratio, 0.5) if top_ratio > 1.0 else (0.5, 0.5 * ratio)
    profile = np.array([[0.0, 0.0], [bottom, 0.0], [top, 1.0], [0.0, 1.0]])
    return revolve_profile(profile, sections=24), {"top_ratio": top_ratio}


def _unit_sphere(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    return trimesh.creation.icosphere(subdivisions=2, radius=0.5), {}


def _unit_capsule(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    radius = 0.5
    height = float(rng.uniform(0.2, 2.0))  # straight part, relative to the diameter
    mesh = trimesh.creation.capsule(height=height, radius=radius, count=[16, 16])
    return mesh, {"straight": height}


def _prism(sides: int) -> Callable[[np.random.Generator], tuple[trimesh.Trimesh, dict]]:
    def build(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
        return trimesh.creation.cylinder(radius=0.5, height=1.0, sections=sides), {}

    return build


def _unit_pyramid(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    mesh = trimesh.creation.cone(radius=0.5, height=1.0, sections=4)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, [0, 0, 1]))
    return mesh, {}


def _unit_octahedron(rng: np.random.Generator) -> tuple[trimesh.Trimesh, dict]:
    # Stands on a vertex: an unstable design pose the simulator's re-placement has to cope with.
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * 0.5
    return outward(trimesh.convex.convex_hull(v)), {}


# Each builder gives a unit-size solid (plus its own shape parameters); the family then scales it to random
# extents, so every kind gets a random non-uniform scale.
PRIMITIVE_BUILDERS: dict[str, Callable[[np.random.Generator], tuple[trimesh.Trimesh, dict]]] = {
    "box": _unit_box,
    "cylinder": _unit_cylinder,
    "cone": _unit_cone,
    "truncated_cone": _unit_truncated_cone,
    "sphere": _unit_sphere,
    "ellipsoid": _unit_sphere,
    "capsule": _unit_capsule,
    "triangular_prism": _prism(3),
    "pentagonal_prism": _prism(5),
    "hexagonal_prism": _prism(6),
    "pyramid": _unit_pyramid,
    "octahedron": _unit_octahedron,
}


@SHAPE_FAMILIES.register("primitives")
class Primitives(ShapeFamily):
    """Boxes, cylinders, cones, spheres, ellipsoids, capsules, prisms, ... with random extents.

    The kind cycles with the index (balanced kinds in any dataset); the extents are drawn: the largest in
    [size_min, size_max], the other two as random fractions of it (a sphere keeps equal extents).
    """

    @dataclass
    class Config:
        kinds: List[str] = field(default_factory=lambda: list(PRIMITIVE_BUILDERS))
        size_min: float = 0.06  # m, largest extent
        size_max: float = 0.3
        aspect_min: float = 0.3  # smallest extent / largest extent

    def __init__(self, config: "Primitives.Config | None" = None):
        super().__init__(config if config is not None else Primitives.Config())
        unknown = [k for k in self.config.kinds if k not in PRIMITIVE_BUILDERS]
        if unknown or not self.config.kinds:
            raise ShapeError(
                f"primitives.kinds has unknown kinds {unknown or '(empty list)'}; "
                f"choose from {', '.join(PRIMITIVE_BUILDERS)}"
            )

    def make(self, index: int, rng: np.random.Generator) -> ShapeInstance:
        cfg = self.config
        kind = cfg.kinds[index % len(cfg.kinds)]
        mesh, params = PRIMITIVE_BUILDERS[kind](rng)
        size = float(rng.uniform(cfg.size_min, cfg.size_max))
        if kind == "sphere":
            extents = np.full(3, size)
        else:
            extents = size * rng.uniform(cfg.aspect_min, 1.0, size=3)
            extents[rng.integers(3)] = size  # one axis (any: tall, wide or deep) sets the size
        mesh.apply_scale(extents / mesh.extents)
        source = format_source(
            "primitives", kind=kind, ex=extents[0], ey=extents[1], ez=extents[2], **params
        )
        return finish(mesh, self.category, source)
