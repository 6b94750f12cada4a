"""A shape turned into what the simulator needs: mass properties, principal frame and collision hull."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from physdyn.geometry.mass import MassProperties
from physdyn.geometry.rotations import matrix_to_quat


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
    def from_mesh(cls, mesh: trimesh.Trimesh, props: MassProperties) -> "RigidBodySpec":
        moments, axes = props.principal()
        hull = mesh.convex_hull
        return cls(
            mass=float(props.mass),
            inertia_diag=moments,
            principal_axes=axes,
            com_mesh=np.asarray(props.com, dtype=np.float64),
            hull_vertices=(hull.vertices - props.com) @ axes,
        )

    @property
    def principal_quat_xyzw(self) -> np.ndarray:
        """Orientation of the principal frame in the mesh frame (``shapes/inertia_orientation_xyzw``)."""
        return matrix_to_quat(self.principal_axes)

    def body_vertices(self) -> np.ndarray:
        """Hull vertices in the body frame (mesh axes, origin at the centre of mass)."""
        return self.hull_vertices @ self.principal_axes.T
