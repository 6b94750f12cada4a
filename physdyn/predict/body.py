"""A user's mesh made into a rigid body for prediction: the cleaned mesh (mesh frame, metres), its mass
properties and collision hull (``RigidBodySpec``), the point cloud the model sees, and where it rests."""

from __future__ import annotations

import dataclasses
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from physdyn.config import DataConfig, MassConfig
from physdyn.errors import PredictionError, ShapeError
from physdyn.geometry.mesh_io import load_mesh
from physdyn.sim.body import body_surface_points, rigid_body
from physdyn.sim.trajectory import resting_com_position

MAX_FRICTION = 2.0  # an effective coefficient beyond this is a units or product-of-two-frictions mistake
POINTS_SEED = 0  # fixed: the same mesh always gets the same cloud, so predictions are reproducible
IN_MEMORY = "<in-memory>"


@dataclass
class PreparedBody:
    """A mesh made into a rigid body: cleaned mesh (mesh frame, metres), its ``RigidBodySpec`` and where it
    came from. ``notes``: one-line warnings (e.g. the convex hull was used for the mass properties)."""

    mesh: Any
    spec: Any
    name: str
    notes: list[str] = field(default_factory=list)
    scale: float = 1.0  # applied to the file's coordinates to get metres
    # the effective Coulomb coefficient of its contact with the ground (None: the model's own, what it was
    # trained at); a model whose motion takes friction (`fast`, `contact_prior`) slides it accordingly
    friction: float | None = None
    _points: dict[tuple[int, str], np.ndarray] = field(default_factory=dict, repr=False)

    def with_friction(self, friction: float | None) -> "PreparedBody":
        """This body on a ground of effective Coulomb coefficient ``friction`` (``check_friction``; None: the
        model's own); the preparation and the clouds are shared, not copied."""
        return dataclasses.replace(self, friction=check_friction(friction))

    def points_body(self, num_points: int, method: str = "surface") -> np.ndarray:
        """(num_points, 3) float32 points in the body frame (mesh axes, origin at the com), in the
        representation ``method`` the model was trained on (geometry/sampling.py)."""
        if (num_points, method) not in self._points:
            self._points[num_points, method] = body_surface_points(self.mesh, self.spec, num_points,
                                                                   DataConfig().oversample, POINTS_SEED, method)
        return self._points[num_points, method]

    def hull_count(self, num_points: int) -> int:
        """How many of the first points of its ``hull_surface`` cloud of ``num_points`` are the vertices of the
        mesh's convex hull (``hull_surface_points`` puts them first): what thinning that cloud takes as its
        hull, with no qhull (``thin_hull_surface``)."""
        return min(len(self.spec.hull_vertices), int(num_points))  # (body_vertices() would turn them all to count them)


def check_friction(friction: Any) -> float | None:
    """``friction`` as an effective Coulomb coefficient, 0 < mu <= MAX_FRICTION (None stays None); a one-line
    ``PredictionError`` naming the fix otherwise."""
    if friction is None:
        return None
    number = isinstance(friction, (int, float, np.floating, np.integer)) and not isinstance(friction, bool)
    mu = float(friction) if number else float("nan")
    if not 0.0 < mu <= MAX_FRICTION:
        raise PredictionError(f"friction must be an effective Coulomb coefficient above 0 and at most {MAX_FRICTION:g}, "
                              f"got {friction!r}; e.g. 0.25, the conventions' default")
    return mu


def prepare_body(mesh: Any, scale: float = 1.0, density: float | None = None) -> PreparedBody:
    """A mesh file path or ``trimesh.Trimesh`` -> ``PreparedBody``. Exact mass properties of the solid, or
    of its convex hull (with a note) when the mesh is not a closed volume. Raises ``ShapeError``."""

    if isinstance(mesh, PreparedBody):
        return mesh
    if isinstance(mesh, trimesh.Trimesh):
        if not np.isfinite(scale) or scale <= 0:
            raise ShapeError(f"mesh {IN_MEMORY}: scale must be a positive number, got {scale}")
        name = IN_MEMORY
        raw = mesh
        if scale != 1.0:
            # A copy of the geometry alone: ``mesh.copy()`` also deep-copies visuals and caches, milliseconds
            # for a large mesh. Unscaled, rigid_body checks and cleans a copy of its own.
            raw = trimesh.Trimesh(vertices=np.array(mesh.vertices), faces=np.array(mesh.faces), process=False)
            raw.apply_scale(scale)
    elif isinstance(mesh, (str, os.PathLike)):
        name = str(mesh)
        raw = load_mesh(mesh, scale)
    else:
        raise PredictionError(f"mesh must be a file path or a trimesh.Trimesh, got {type(mesh).__name__}")
    density = MassConfig().density if density is None else float(density)
    body = rigid_body(raw, name, density, mass_name=f"mesh {name}")
    return PreparedBody(mesh=body.mesh, spec=body.spec, name=name, notes=body.notes, scale=float(scale))


def preparation_key(mesh: Any, scale: float) -> tuple | None:
    """What a preparation of ``mesh`` at ``scale`` depends on, as a hashable key: for a ``trimesh.Trimesh``
    its content (a digest of the vertex and face arrays, so two equal objects share a key and a changed
    mesh gets a new one); for a file its resolved path, size and modification time. None when there is
    nothing to cache: a ``PreparedBody`` (already prepared), another type, or a path that cannot be read
    (``prepare_body`` then raises the error that names it)."""

    if isinstance(mesh, trimesh.Trimesh):
        digest = hashlib.sha256()
        for array in (mesh.vertices, mesh.faces):
            array = np.ascontiguousarray(array)
            digest.update(f"{array.dtype.str}{array.shape}".encode())
            digest.update(array)
        return ("mesh", digest.hexdigest(), float(scale))
    if isinstance(mesh, (str, os.PathLike)):
        try:
            path = Path(mesh).expanduser().resolve()
            stat = path.stat()
        except (OSError, RuntimeError):  # missing, unreadable, or a symlink loop
            return None
        return ("file", str(path), stat.st_size, stat.st_mtime_ns, float(scale))
    return None


def initial_pose(spec: Any, orientation_xyzw: np.ndarray) -> np.ndarray:
    """The centre of mass (3,) of the object at rest in this orientation: lowest point on z = 0, x = y = 0."""

    return resting_com_position(spec, orientation_xyzw)
