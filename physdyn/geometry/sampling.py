"""Point clouds of a shape, in two representations (``POINTS_METHODS``):

- ``surface``: the paper's — oversample the surface, keep well-spread points by farthest-point sampling.
  Uniform samples miss the hull's corners, and contact with the ground depends only on the hull: PyBullet
  itself, run on the hull of 256 such points, misses the true rotation by 27-29 deg.
- ``hull_surface``: every vertex of the mesh's convex hull first (thinned by farthest-point sampling only
  when there are more than ``num_points``), then uniform surface samples fill
  the rest. The set's hull is the mesh's hull whenever it has at most ``num_points`` vertices, so what
  decides contact reaches the model intact (docs/research/points-and-encoders.md).
  No farthest-point pass over the fill: it costs milliseconds per mesh at prediction time.
"""

from __future__ import annotations

import numpy as np
import trimesh

from physdyn.errors import PhysdynError
from physdyn.geometry.surface import face_areas, face_crosses


def open3d():
    """The open3d module, imported on first use (heavy; only point sampling and renders need it). A bare
    `pip install` on a machine without libusb-1.0 cannot load it: that becomes one line with the fix
    rather than every shape failing with a loader message."""
    try:
        import open3d as o3d
    except (ImportError, OSError) as exc:
        hint = ("install the system library: sudo apt-get install libusb-1.0-0" if "libusb" in str(exc)
                else "reinstall it: pip install open3d")
        raise PhysdynError(f"open3d cannot be loaded ({str(exc).splitlines()[0]}); {hint}") from None
    return o3d


def farthest_point_sample(points: np.ndarray, count: int) -> np.ndarray:
    """points: (M, 3) -> (count, 3): the points greedy farthest-point sampling picks, starting from points[0]
    (deterministic), in their order in ``points`` (open3d's), not the order they were picked in."""
    if count >= len(points):
        return np.asarray(points, dtype=np.float32)
    o3d = open3d()

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    return np.asarray(cloud.farthest_point_down_sample(count).points, dtype=np.float32)


POINTS_METHODS = ("surface", "hull_surface")


def sample_surface_points(mesh: trimesh.Trimesh, num_points: int = 1024, oversample: int = 3, seed: int = 0) -> np.ndarray:
    """(num_points, 3) float32 surface points in mesh coordinates, as the paper samples them (3x + FPS)."""
    candidates, _ = trimesh.sample.sample_surface(mesh, num_points * max(oversample, 1), seed=seed)
    return farthest_point_sample(candidates, num_points)


def hull_surface_points(mesh: trimesh.Trimesh, num_points: int, seed: int = 0,
                        hull_vertices: np.ndarray | None = None) -> np.ndarray:
    """(num_points, 3) float32 in mesh coordinates: the convex hull's vertices (``hull_vertices`` (H, 3) if
    the caller has them, else computed; farthest-point thinned from the lowest when H > num_points), then
    uniform surface samples."""
    hull = np.asarray(mesh.convex_hull.vertices if hull_vertices is None else hull_vertices, dtype=np.float64)
    # Start from the lowest vertex (deterministic whatever qhull's order) so the first points span the base.
    hull = np.roll(hull, -int(np.argmin(hull[:, 2])), axis=0)
    kept = farthest_point_sample(hull, min(len(hull), num_points)) if len(hull) > 1 else hull.astype(np.float32)
    fill = num_points - len(kept)
    if fill <= 0:
        return np.ascontiguousarray(kept[:num_points], dtype=np.float32)
    samples = uniform_surface_samples(mesh, fill, seed)
    return np.concatenate([kept, samples.astype(np.float32)])


THIN_QHULL_OPTIONS = "Qt QbB Pp C-1e-7"  # merges facets within 1e-7 of the unit cube: float32 samples on a face stay off the hull


def thin_hull_surface(points: np.ndarray, count: int, hull_count: int | None = None) -> np.ndarray:
    """``count`` points (float32, or the cloud as it is when it holds no more) of a ``hull_surface`` cloud
    (N, 3), as that representation builds a smaller one: the cloud's hull vertices first (farthest-point
    thinned from the lowest when there are more than ``count``), then its other points in their order
    (uniform surface samples). What a topple PointNet fitted with ``--num-points`` reads, made from the
    cloud the model already has (stores hold only clouds), the same at training and at prediction.

    The hull is qhull's with facets merged within 1e-7 (of the cloud's box): without it, float32 rounding
    lifts samples lying on a slanted face off it and qhull counts them as vertices (40-52 "vertices" for a
    turned box's 8 corners), so thinning dropped real corners. Merged, no sample counts on the frontier's
    meshes or turned boxes, and the few near-coplanar mesh vertices it drops lose under 1e-7 of the hull's
    volume. A flat cloud, which qhull refuses, is thinned whole.

    ``hull_count``: how many of the cloud's first points are its mesh's hull vertices, where the caller knows
    (a prediction's cloud: ``PreparedBody.hull_count``). Those are then taken as its hull, with no qhull
    (which took 0.8 ms of a 11 ms prediction of a new mesh). A store's clouds come without it and are thinned
    by qhull. The two thin 864 of 910 random_urdfs 000-999 clouds (256 points) alike; on the others qhull's
    merging drops or keeps a near-coplanar hull vertex (benchmarks/studies/thin_known_hull.py)."""
    points = np.asarray(points, dtype=np.float32)
    if count >= len(points):
        return points
    on_hull = np.zeros(len(points), dtype=bool)
    if hull_count is not None:
        on_hull[: int(hull_count)] = True
    else:
        from scipy.spatial import ConvexHull, QhullError

        try:
            on_hull[ConvexHull(points.astype(np.float64), qhull_options=THIN_QHULL_OPTIONS).vertices] = True
        except (QhullError, ValueError):
            on_hull[:] = True
    vertices = points[on_hull]
    vertices = np.roll(vertices, -int(np.argmin(vertices[:, 2])), axis=0)
    if len(vertices) >= count:
        return np.ascontiguousarray(farthest_point_sample(vertices, count), dtype=np.float32)
    return np.concatenate([vertices, points[~on_hull][: count - len(vertices)]])


def uniform_surface_samples(mesh: trimesh.Trimesh, count: int, seed: int) -> np.ndarray:
    """(count, 3) float64 points uniform over the surface of ``mesh``: the very draws and arithmetic of
    ``trimesh.sample.sample_surface(mesh, count, seed=seed)`` (the stores' clouds stay as they were), but
    with the edge vectors of the picked faces only, not of every face, and the areas from
    ``face_areas`` (together a millisecond less on 10k faces)."""
    vertices, faces = mesh.vertices.view(np.ndarray), mesh.faces.view(np.ndarray)
    weight = np.cumsum(face_areas(face_crosses(vertices, faces)))
    random = np.random.default_rng(seed).random
    face = np.searchsorted(weight, random(count) * weight[-1])
    corners = vertices[faces[face]]  # (count, 3, 3)
    origins = corners[:, 0]
    vectors = corners[:, 1:] - origins[:, None, :]
    # Two uniform lengths along the edges; a pair summing past 1 falls outside: fold it back inside.
    lengths = random((count, 2, 1))
    lengths[lengths.sum(axis=1).reshape(-1) > 1.0] -= 1.0
    lengths = np.abs(lengths)
    return (vectors * lengths).sum(axis=1) + origins


def shape_points(mesh: trimesh.Trimesh, num_points: int, method: str = "surface", oversample: int = 3, seed: int = 0,
                 hull_vertices: np.ndarray | None = None) -> np.ndarray:
    """(num_points, 3) float32 mesh-coordinate points of ``mesh`` in the representation ``method``."""
    if method == "surface":
        return sample_surface_points(mesh, num_points, oversample, seed)
    if method == "hull_surface":
        return hull_surface_points(mesh, num_points, seed, hull_vertices)
    raise PhysdynError(f"points method '{method}' is unknown; use one of {', '.join(POINTS_METHODS)}")
