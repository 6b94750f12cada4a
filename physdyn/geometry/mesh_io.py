"""Reading mesh files and making them usable as rigid bodies.

``load_mesh`` is where a user's mesh enters physdyn, so every check that can name the file and the fix
happens here; ``prepare_mesh`` cleans a mesh (from a file or a generator) and says whether its exact mass
properties can be trusted.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from physdyn.errors import ShapeError

MESH_EXTENSIONS: tuple[str, ...] = (".obj", ".stl", ".ply", ".off", ".glb")

# Largest extent a mesh may have once scaled, in metres. Outside this the file is almost surely in other
# units (millimetres, centimetres) and the physics would be nonsense, so we ask for a scale instead.
MIN_EXTENT = 1e-3
MAX_EXTENT = 10.0

# A convex hull whose volume is below this fraction of the cube of the largest extent is treated as flat
# (a sheet, a line): it has no usable mass or inertia. 1e-6 rejects a 10 cm sheet thinner than ~0.1 um
# (float noise from an exporter) while a 0.8 mm card of 8.5 cm is 6e-3.
_FLAT_VOLUME_FRACTION = 1e-6


@dataclass
class PreparedMesh:
    """A cleaned mesh and what the cleaning found.

    mesh: the cleaned mesh (V, 3) vertices / (F, 3) faces, same frame and units as the input.
    watertight: True if ``mesh`` is a closed, consistently wound volume, so its exact mass properties are
        valid; False means a caller should use the convex hull's mass properties instead.
    warnings: one-line messages naming the mesh, for the user.
    """

    mesh: trimesh.Trimesh
    watertight: bool
    warnings: list[str] = field(default_factory=list)


def load_mesh(path: str | Path, scale: float = 1.0) -> trimesh.Trimesh:
    """Read a mesh file, multiply its coordinates by ``scale`` and check it can be a rigid body.

    A multi-part file (a glTF scene, say) is baked into one mesh with its node transforms applied.
    Returns the mesh with coincident vertices merged and nothing else changed (``prepare_mesh`` cleans).
    Raises ``ShapeError`` naming the file, the problem and the fix.
    """
    path = Path(path).expanduser()
    if not np.isfinite(scale) or scale <= 0:
        raise ShapeError(f"mesh {path}: scale must be a positive number, got {scale}")
    if not path.exists():
        raise ShapeError(f"mesh file not found: {path}; check the path (and meshes.dir)")
    if not path.is_file():
        raise ShapeError(f"mesh {path} is not a file; pass a mesh file ({', '.join(MESH_EXTENSIONS)})")
    ext = path.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise ShapeError(
            f"mesh {path}: unsupported format '{ext or '(no extension)'}'; "
            f"convert it to one of {', '.join(MESH_EXTENSIONS)}"
        )
    if path.stat().st_size == 0:
        raise ShapeError(f"mesh {path} is an empty file; re-export the mesh")

    mesh = _read(path)
    if scale != 1.0:
        mesh.apply_scale(scale)
    check_mesh(mesh, str(path))
    # Merge coincident vertices now the checks are done: STL stores three private vertices per triangle,
    # and an unmerged surface reads as open everywhere.
    mesh.merge_vertices()
    return mesh


def _read(path: Path) -> trimesh.Trimesh:
    try:
        # process=False: merging vertices would hide NaN coordinates and mis-shaped faces from our checks.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = trimesh.load_scene(str(path), process=False)
            parts = [g for g in scene.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    except Exception as exc:  # parsers raise anything from ValueError to struct.error on garbage
        first = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise ShapeError(
            f"mesh {path} could not be read as {path.suffix.lower()} ({first}); "
            "check the file is a valid mesh, e.g. by opening it in a mesh viewer"
        ) from None
    if not parts:
        raise ShapeError(
            f"mesh {path} has no triangles (corrupt, or only points and lines); "
            "export it as a triangle surface mesh"
        )
    mesh = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
    # A fresh Trimesh drops the visuals (textures, colours): physdyn needs geometry only.
    return trimesh.Trimesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        faces=np.asarray(mesh.faces, dtype=np.int64),
        process=False,
    )


def check_mesh(mesh: trimesh.Trimesh, name: str) -> None:
    """Raise ``ShapeError`` (naming ``name``) if ``mesh`` cannot be a rigid body: no faces, non-finite
    vertices, zero volume or an absurd size. Non-manifold or open meshes pass: ``prepare_mesh`` deals with
    those."""
    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces)
    if len(faces) == 0 or len(vertices) == 0:
        raise ShapeError(f"mesh {name} has no faces; export it as a triangle surface mesh")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ShapeError(f"mesh {name} has faces that index missing vertices; re-export the mesh")
    used = vertices[np.unique(faces)]
    if not np.isfinite(used).all():
        bad = int((~np.isfinite(used)).any(axis=1).sum())
        raise ShapeError(
            f"mesh {name} has NaN or infinite coordinates (in {bad} of its vertices); repair or re-export it"
        )
    extent = float(np.ptp(used, axis=0).max())
    if extent == 0.0:
        raise ShapeError(f"mesh {name} has zero volume (all vertices coincide); it must be a solid")
    if _hull_volume(used) <= _FLAT_VOLUME_FRACTION * extent**3:
        raise ShapeError(
            f"mesh {name} has zero volume (its points are coplanar or collinear); it must be a solid, "
            "not a flat sheet or a line"
        )
    if not MIN_EXTENT <= extent <= MAX_EXTENT:
        raise ShapeError(
            f"mesh {name} is {extent:.4g} m across, outside {MIN_EXTENT:g}-{MAX_EXTENT:g} m; "
            "it is probably in other units: pass a scale "
            "(e.g. meshes.scale=0.001 for millimetres, 0.01 for centimetres)"
        )


def _hull_volume(points: np.ndarray) -> float:
    """Volume of the convex hull of ``points`` (P, 3); 0 for flat or too few points."""
    if len(points) < 4:
        return 0.0
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):  # Qhull refuses coplanar/collinear input
        return 0.0


def prepare_mesh(mesh: trimesh.Trimesh, name: str) -> PreparedMesh:
    """Clean ``mesh`` for simulation and report whether it is a closed volume.

    Merges duplicate vertices, drops degenerate and duplicate faces, makes winding consistent with outward
    normals, and tries trimesh's hole filling if the mesh is open. A non-manifold mesh is returned as is
    (``watertight=False``) rather than failing: its convex hull still gives usable mass properties.
    Raises ``ShapeError`` for a mesh with no volume. The input is not modified.
    """
    check_mesh(mesh, name)
    notes: list[str] = []
    out = trimesh.Trimesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        faces=np.asarray(mesh.faces, dtype=np.int64),
        process=False,
    )
    n_faces = len(out.faces)
    out.merge_vertices()
    out.update_faces(out.nondegenerate_faces())
    out.update_faces(out.unique_faces())
    out.remove_unreferenced_vertices()
    if len(out.faces) == 0:
        raise ShapeError(f"mesh {name} has only degenerate faces; it must be a solid")
    if len(out.faces) < n_faces:
        notes.append(f"mesh {name}: removed {n_faces - len(out.faces)} degenerate or duplicate faces")

    _orient(out)
    if not out.is_watertight:
        # fill_holes closes only triangle and quad holes (fanning bigger ones can fold over non-convex
        # holes), and nothing around non-manifold edges: such meshes stay open and take the hull fallback.
        trimesh.repair.fill_holes(out)
        _orient(out)
        if out.is_watertight:
            notes.append(f"mesh {name}: filled holes to close the surface")
    watertight = bool(out.is_volume)
    if not watertight:
        problem = "is not watertight" if not out.is_watertight else "has inconsistent face winding"
        notes.append(
            f"mesh {name} {problem}; using its convex hull for mass properties "
            "(repair the mesh for exact ones)"
        )
    return PreparedMesh(mesh=out, watertight=watertight, warnings=notes)


def _orient(mesh: trimesh.Trimesh) -> None:
    """Make winding consistent and normals point outwards (in place)."""
    try:
        trimesh.repair.fix_winding(mesh)
        trimesh.repair.fix_normals(mesh, multibody=True)
    except Exception:  # non-manifold face adjacency can defeat the graph traversal; leave it as it is
        return
    # fix_normals flips by the sign of the signed volume, which is meaningless for an open surface.
    if mesh.is_watertight and mesh.volume < 0:
        mesh.invert()
