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
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from physdyn.errors import ShapeError
from physdyn.geometry.hull import PointHull, hull_volume, point_hull
from physdyn.geometry.surface import face_areas, face_crosses

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
    hull_vertices: (H, 3) the vertices of ``mesh``'s convex hull (those of ``mesh.convex_hull``, same order)
        when the cleaning computed them, else None.
    """

    mesh: trimesh.Trimesh
    watertight: bool
    warnings: list[str] = field(default_factory=list)
    hull_vertices: np.ndarray | None = None


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
    check_surface(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64), name)


def check_surface(vertices: np.ndarray, faces: np.ndarray, name: str) -> PointHull | None:
    """``check_mesh`` on arrays: vertices (V, 3) float64, faces (F, 3) int64. Returns the convex hull of the
    vertices the faces use (indices into ``vertices``), which the check needs anyway and the collision hull
    reuses; None when qhull builds it only with its default options (rare precision cases)."""
    if len(faces) == 0 or len(vertices) == 0:
        raise ShapeError(f"mesh {name} has no faces; export it as a triangle surface mesh")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ShapeError(f"mesh {name} has faces that index missing vertices; re-export the mesh")
    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[faces.ravel()] = True
    all_used = bool(referenced.all())
    used = vertices if all_used else vertices[referenced]
    if not np.isfinite(used).all():
        bad = int((~np.isfinite(used)).any(axis=1).sum())
        raise ShapeError(
            f"mesh {name} has NaN or infinite coordinates (in {bad} of its vertices); repair or re-export it"
        )
    extent = float(np.ptp(used, axis=0).max())
    if extent == 0.0:
        raise ShapeError(f"mesh {name} has zero volume (all vertices coincide); it must be a solid")
    hull = point_hull(used)
    volume = hull.volume if hull is not None else hull_volume(used)
    if volume <= _FLAT_VOLUME_FRACTION * extent**3:
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
    if hull is None or all_used:
        return hull
    return PointHull(vertex_index=np.flatnonzero(referenced)[hull.vertex_index], volume=hull.volume)


def prepare_mesh(mesh: trimesh.Trimesh, name: str) -> PreparedMesh:
    """Clean ``mesh`` for simulation and report whether it is a closed volume.

    Merges duplicate vertices, drops degenerate and duplicate faces, makes winding consistent with outward
    normals, and tries trimesh's hole filling if the mesh is open. A non-manifold mesh is returned as is
    (``watertight=False``) rather than failing: its convex hull still gives usable mass properties.
    Raises ``ShapeError`` for a mesh with no volume. The input is not modified.
    """
    # Copies: the cleaned mesh never shares memory with the caller's, which may change it later.
    vertices = np.array(mesh.vertices, dtype=np.float64)
    faces = np.array(mesh.faces, dtype=np.int64)
    hull = check_surface(vertices, faces, name)
    out = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    if hull is not None and already_clean(vertices, faces):
        # Most meshes (every procedural one) arrive clean, and the repairs below would each be a no-op that
        # costs milliseconds; the hull of the check is then the hull of the cleaned mesh.
        return PreparedMesh(mesh=out, watertight=True, hull_vertices=vertices[hull.vertex_index])
    return _repair(out, name)


def _repair(out: trimesh.Trimesh, name: str) -> PreparedMesh:
    """``prepare_mesh``'s cleaning, in place on ``out`` (a fresh copy)."""
    notes: list[str] = []
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


def already_clean(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """True when ``_repair`` would leave the surface vertices (V, 3) float64 / faces (F, 3) int64 exactly as
    it is and call it a volume: every vertex used and none coincident (``merge_vertices`` keeps them all,
    in order), no degenerate face, every edge shared by exactly two faces running along it in opposite
    directions (watertight, consistent winding, so ``fix_winding`` and ``fill_holes`` do nothing) and
    each connected body of positive volume (``fix_normals`` flips nothing). No duplicate face survives
    these: a face and its copy would share directed edges, or, wound oppositely, make a body of their own
    with no volume."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    if not used.all() or not _distinct_vertices(vertices):
        return False
    crosses = face_crosses(vertices, faces)
    if not _nondegenerate(vertices, faces, face_areas(crosses)):
        return False
    neighbours = edge_neighbours(faces)
    return neighbours is not None and _bodies_have_volume(vertices, faces, crosses, neighbours)


def _nondegenerate(vertices: np.ndarray, faces: np.ndarray, areas: np.ndarray) -> bool:
    """True when no face is degenerate by trimesh's rule (``nondegenerate_faces``: both sides of its 2D
    bounding box longer than tol.merge); areas (F,) from ``face_areas``."""
    # A side is twice the area over an edge, and no edge is longer than the bounding box's diagonal: with
    # a factor 2 to spare for round-off, its area alone proves a face sound. trimesh's test runs on the rest.
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    small = np.flatnonzero(areas <= trimesh.tol.merge * diagonal)
    if len(small) == 0:
        return True
    return bool(trimesh.triangles.nondegenerate(np.take(vertices, faces[small], axis=0), areas=areas[small],
                                                height=trimesh.tol.merge).all())


def _distinct_vertices(vertices: np.ndarray) -> bool:
    """True when no two of ``vertices`` (V, 3) coincide at trimesh's merge precision. False may also mean a
    (rare) collision of the row hash: the caller then takes the slow path, which merges exactly."""
    digits = trimesh.util.decimal_to_digits(trimesh.tol.merge)
    rows = (vertices * (10**digits)).round().astype(np.int64)  # merge_vertices's rounding, to the bit
    # Equal rows give equal hashes, so distinct hashes prove distinct rows (int64 arrays wrap around).
    hashed = rows[:, 0] * np.int64(-7046029254386353131) + rows[:, 1] * np.int64(1099511628211) + rows[:, 2]
    ordered = np.sort(hashed)
    return bool((ordered[1:] != ordered[:-1]).all())


def edge_neighbours(faces: np.ndarray) -> np.ndarray | None:
    """(F, 3) int64: the face across edge j of each face (edge j runs from corner j to corner j + 1), or None
    unless every edge is shared by exactly two faces running along it in opposite directions (trimesh's
    ``is_watertight`` and ``is_winding_consistent`` together, from a single sort)."""
    start = faces.ravel()
    end = faces[:, [1, 2, 0]].ravel()
    if len(start) % 2:
        return None
    low, high = np.minimum(start, end), np.maximum(start, end)
    key = low * (int(high.max()) + 1) + high  # one integer per undirected edge
    order = np.argsort(key, kind="stable")  # timsort: a mesh's edge keys come in long sorted runs (4x faster)
    ordered = key[order]
    # Sorted, the keys must come in equal pairs, each pair different from the next.
    if not (ordered[0::2] == ordered[1::2]).all() or (ordered[2::2] == ordered[1:-1:2]).any():
        return None
    first, second = order[0::2], order[1::2]
    if not (start[first] == end[second]).all():  # the same direction twice: inconsistent winding
        return None
    neighbours = np.empty(len(start), dtype=np.int64)
    neighbours[first] = second // 3
    neighbours[second] = first // 3
    return neighbours.reshape(-1, 3)


def _bodies_have_volume(vertices: np.ndarray, faces: np.ndarray, crosses: np.ndarray, neighbours: np.ndarray) -> bool:
    """True when every edge-connected body of a closed surface encloses a clearly positive volume:
    vertices (V, 3), faces (F, 3), their edge cross products (F, 3), neighbours (F, 3) from
    ``edge_neighbours``. A body whose volume is within round-off of zero counts as not positive (the slow
    path decides it)."""
    count = len(neighbours)
    adjacency = csr_matrix((np.ones(3 * count, dtype=bool), neighbours.ravel(), np.arange(0, 3 * count + 1, 3)),
                           shape=(count, count))
    # The adjacency is symmetric, so strong components are the bodies (and need no transpose).
    bodies, label = connected_components(adjacency, directed=True, connection="strong")
    signed = _signed_volumes(vertices, faces, crosses)
    volume = np.bincount(label, weights=signed, minlength=bodies)
    scale = np.bincount(label, weights=np.abs(signed), minlength=bodies)
    return bool((volume > 1e-9 * scale).all())


def _signed_volumes(vertices: np.ndarray, faces: np.ndarray, crosses: np.ndarray) -> np.ndarray:
    """(F,) each face's share of its body's volume, times 6: the divergence theorem per face, as trimesh's
    mass_properties integrates the volume; crosses (F, 3) the faces' edge cross products."""
    x = vertices[:, 0]
    return crosses[:, 0] * (np.take(x, faces[:, 0]) + np.take(x, faces[:, 1]) + np.take(x, faces[:, 2]))


def _orient(mesh: trimesh.Trimesh) -> None:
    """Make winding consistent and normals point outwards (in place)."""
    try:
        trimesh.repair.fix_winding(mesh)
        _flip_inverted_bodies(mesh)
    except Exception:  # non-manifold face adjacency can defeat the graph traversal; leave it as it is
        return
    # The flip goes by each closed body's signed volume, which is meaningless for an open surface: only a
    # closed mesh is turned inside out as a whole.
    if mesh.is_watertight and mesh.volume < 0:
        mesh.invert()


def _flip_inverted_bodies(mesh: trimesh.Trimesh) -> None:
    """Turn inside out, in place, each body of ``mesh`` that is closed, consistently wound, of at least 4 faces
    and of negative volume: what ``trimesh.repair.fix_inversion(mesh, multibody=True)`` does, in the same
    face order, with one sort over all bodies instead of a loop over them. (That loop took 20-70 ms on
    meshes of a few thousand faces and many small bodies, most of their preparation.)"""
    faces = mesh.faces.view(np.ndarray)
    count = len(faces)
    adjacency = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
    graph = csr_matrix((np.ones(len(adjacency), dtype=bool), (adjacency[:, 0], adjacency[:, 1])), shape=(count, count))
    bodies, label = connected_components(graph, directed=False)
    start = faces.ravel()
    end = faces[:, [1, 2, 0]].ravel()
    low, high, body = np.minimum(start, end), np.maximum(start, end), np.repeat(label, 3)
    order = np.lexsort((high, low, body))
    edge = np.stack([body[order], low[order], high[order]])
    new_run = np.ones(len(order), dtype=bool)
    new_run[1:] = (edge[:, 1:] != edge[:, :-1]).any(axis=0)
    run_start = np.flatnonzero(new_run)
    run_length = np.diff(np.append(run_start, len(order)))
    run_body = body[order][run_start]
    # trimesh's is_watertight per body: every edge of the body twice, the two running opposite ways.
    pairs = run_start[run_length == 2]
    opposite = end[order][pairs] == start[order][pairs + 1]
    sound = np.bincount(label, minlength=bodies) >= 4
    sound &= np.bincount(run_body, weights=run_length != 2, minlength=bodies) == 0
    sound &= np.bincount(run_body[run_length == 2], weights=~opposite, minlength=bodies) == 0
    if not sound.any():
        return
    signed = _signed_volumes(mesh.vertices.view(np.ndarray), faces, mesh.triangles_cross)
    flip = (sound & (np.bincount(label, weights=signed, minlength=bodies) < 0.0))[label]
    if not flip.any():
        return
    normals = None
    if "face_normals" in mesh._cache:
        normals = mesh.face_normals.copy()
        normals[flip] *= -1.0
    mesh.faces[flip] = np.fliplr(mesh.faces[flip])
    if normals is not None:
        mesh.face_normals = normals
