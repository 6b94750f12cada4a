"""A shape turned into what the simulator needs: mass properties, principal frame and collision hull.

``rigid_body`` is the one way a mesh becomes a body — for dataset generation, motion-capture trials and
prediction alike: the mesh cleaned, the mass properties of the solid it bounds (or of its convex hull when
it bounds none, with a note), the simulator's ``RigidBodySpec``, and surface points in the body frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from physdyn.geometry.mass import MassProperties, solid_mass_properties
from physdyn.geometry.mesh_io import prepare_mesh
from physdyn.geometry.rotations import matrix_to_quat
from physdyn.geometry.sampling import shape_points


@dataclass
class RigidBodySpec:
    """Everything the simulator needs to know about one object.

    hull_vertices: (V, 3) convex-hull vertices in the *principal* frame (origin at the centre of mass,
        axes along the principal axes of inertia), so the simulator's inertial frame is its base frame.
    principal_axes: (3, 3) principal axes as columns in mesh coordinates (det +1).
    com_mesh: (3,) centre of mass in mesh coordinates.
    """

    mass: float
    inertia_diag: np.ndarray
    principal_axes: np.ndarray
    com_mesh: np.ndarray
    hull_vertices: np.ndarray

    @classmethod
    def from_mesh(cls, mesh: trimesh.Trimesh, props: MassProperties,
                  hull_vertices: np.ndarray | None = None) -> "RigidBodySpec":
        """``hull_vertices``: (H, 3) those of ``mesh.convex_hull`` in mesh coordinates, when already known
        (``PreparedMesh.hull_vertices``); computed otherwise."""
        moments, axes = props.principal()
        hull = mesh.convex_hull.vertices if hull_vertices is None else hull_vertices
        return cls(
            mass=float(props.mass),
            inertia_diag=moments,
            principal_axes=axes,
            com_mesh=np.asarray(props.com, dtype=np.float64),
            hull_vertices=(hull - props.com) @ axes,
        )

    @property
    def principal_quat_xyzw(self) -> np.ndarray:
        """Orientation of the principal frame in the mesh frame (``shapes/inertia_orientation_xyzw``)."""
        return matrix_to_quat(self.principal_axes)

    def body_vertices(self) -> np.ndarray:
        """Hull vertices in the body frame (mesh axes, origin at the centre of mass)."""
        return self.hull_vertices @ self.principal_axes.T


@dataclass
class RigidBody:
    """A mesh made into a rigid body: ``mesh`` cleaned (mesh frame, metres), its mass ``props`` and
    simulator ``spec``; ``watertight``: whether the mass is the solid's (else its convex hull's); ``notes``:
    one-line warnings from cleaning (e.g. that the hull was used)."""

    mesh: trimesh.Trimesh
    props: MassProperties
    spec: RigidBodySpec
    watertight: bool
    notes: list[str] = field(default_factory=list)

    def surface_points(self, num_points: int, oversample: int, seed: int, method: str = "surface") -> np.ndarray:
        return body_surface_points(self.mesh, self.spec, num_points, oversample, seed, method)


def body_surface_points(mesh: trimesh.Trimesh, spec: RigidBodySpec, num_points: int, oversample: int,
                        seed: int, method: str = "surface") -> np.ndarray:
    """(num_points, 3) float32 points of ``mesh`` in the body frame (mesh axes, origin at the centre of
    mass), as the stores hold them, in the representation ``method`` (geometry/sampling.py)."""
    hull = spec.body_vertices() + spec.com_mesh  # the hull the simulator collides with, already computed
    points = shape_points(mesh, num_points, method, oversample, seed, hull_vertices=hull)
    return (points - spec.com_mesh).astype(np.float32)


def rigid_body(mesh: trimesh.Trimesh, name: str, density: float, method: str = "exact", voxel_pitch: float = 0.025,
               mass_name: str | None = None) -> RigidBody:
    """Clean ``mesh`` (``prepare_mesh``; ``name`` in its messages) and compute its mass properties at uniform
    ``density`` (``method`` exact or voxel; ``mass_name`` in their messages, default ``name``). Raises
    ``ShapeError`` for a mesh that is no usable solid."""
    prepared = prepare_mesh(mesh, name)
    props = solid_mass_properties(prepared.mesh, prepared.watertight, density, mass_name or name, method, voxel_pitch)
    spec = RigidBodySpec.from_mesh(prepared.mesh, props, prepared.hull_vertices)
    return RigidBody(prepared.mesh, props, spec, prepared.watertight, list(prepared.warnings))
