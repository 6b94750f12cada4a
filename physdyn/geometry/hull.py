"""The convex hull of a shape's points, computed once per mesh and shared: the check that a mesh has a
volume, the simulator's collision hull and the ``hull_surface`` point cloud all read the same one.

Qhull is the costliest step in preparing a new mesh (tens of milliseconds when thousands of vertices lie on
the hull, as on a finely tessellated sphere), so it runs once and with trimesh's options: the hull's
vertices are then exactly those of ``mesh.convex_hull``, which the stores made before were built from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

# trimesh.convex.QHULL_DEFAULT: the same qhull run as ``Trimesh.convex_hull``, so the same vertices.
QHULL_OPTIONS = "Qt QbB Pp"


@dataclass(frozen=True)
class PointHull:
    """vertex_index: (H,) int64 ascending indices of the hull's vertices into the points (trimesh's order);
    volume: of the hull, in the points' units cubed."""

    vertex_index: np.ndarray
    volume: float


def point_hull(points: np.ndarray) -> PointHull | None:
    """The convex hull of ``points`` (P, 3) float64, or None when qhull cannot build one with trimesh's
    options (fewer than 4 points, coplanar or collinear, or a precision failure)."""
    if len(points) < 4:
        return None
    try:
        hull = ConvexHull(points, qhull_options=QHULL_OPTIONS)
    except (QhullError, ValueError):
        return None
    # QbB makes qhull work in the unit cube, so its volume is in scaled units: undo the per-axis scaling.
    volume = float(hull.volume) * float(np.prod(np.ptp(points, axis=0)))
    return PointHull(vertex_index=np.sort(hull.vertices).astype(np.int64), volume=volume)


def hull_volume(points: np.ndarray) -> float:
    """Volume of the convex hull of ``points`` (P, 3) with qhull's default options; 0 for flat or too few
    points. The fallback for a set that ``point_hull`` refuses (qhull's defaults handle near-degenerate
    input differently)."""
    if len(points) < 4:
        return 0.0
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):  # Qhull refuses coplanar/collinear input
        return 0.0
