"""Surface point clouds: oversample the surface, then keep well-spread points by farthest-point sampling."""

from __future__ import annotations

import numpy as np
import trimesh

from physdyn.errors import PhysdynError


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
    """points: (M, 3) -> (count, 3), greedy farthest-point order starting from points[0] (deterministic)."""
    if count >= len(points):
        return np.asarray(points, dtype=np.float32)
    o3d = open3d()

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    return np.asarray(cloud.farthest_point_down_sample(count).points, dtype=np.float32)


def sample_surface_points(mesh: trimesh.Trimesh, num_points: int = 1024, oversample: int = 3, seed: int = 0) -> np.ndarray:
    """(num_points, 3) float32 surface points in mesh coordinates, as the paper samples them (3x + FPS)."""
    candidates, _ = trimesh.sample.sample_surface(mesh, num_points * max(oversample, 1), seed=seed)
    return farthest_point_sample(candidates, num_points)
