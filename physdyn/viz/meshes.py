"""The mesh a picture draws: read from what the caller gave, and cut to a face budget.

Shared by the animations (``render.py``) and the viewer page (``viewer.py``): both draw the mesh in mesh
coordinates, posed by the trajectory, and both keep few enough faces to draw every frame quickly.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh

from physdyn.geometry.mesh_io import load_mesh


def decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3), (F, 3) -> a mesh of at most ``max_faces`` faces (quadric decimation; a face subset if that fails)."""
    if len(faces) <= max_faces:
        return vertices, faces
    try:
        import open3d as o3d  # heavy (~1.2 s): only for decimating large meshes

        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
                                      o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))
        small = m.simplify_quadric_decimation(target_number_of_triangles=max_faces)
        v, f = np.asarray(small.vertices), np.asarray(small.triangles)
        if 0 < len(f) <= max_faces:
            return v, f
    except Exception:  # an odd mesh can defeat the decimator; a face subset still shows the object
        pass
    keep = np.linspace(0, len(faces) - 1, max_faces).astype(int)
    return vertices, faces[keep]


def mesh_to_draw(mesh: Any, scale: float) -> trimesh.Trimesh:
    """The mesh of ``mesh``: a path (read at ``scale``), a ``trimesh.Trimesh`` (a scaled copy) or a
    ``PreparedBody`` (its mesh, already at the scale it was predicted at)."""
    if isinstance(mesh, trimesh.Trimesh):
        m = mesh.copy()
        if scale != 1.0:
            m.apply_scale(scale)
        return m
    if hasattr(mesh, "mesh") and hasattr(mesh, "spec"):  # a PreparedBody
        return mesh.mesh

    return load_mesh(mesh, scale)
