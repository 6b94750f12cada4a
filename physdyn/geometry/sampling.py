"""Surface point clouds: oversample the surface, then keep well-spread points by farthest-point sampling."""

from __future__ import annotations

import numpy as np
import trimesh


def farthest_point_sample(points: np.ndarray, count: int) -> np.ndarray:
    """points: (M, 3) -> (count, 3), greedy farthest-point order starting from points[0] (deterministic)."""
    if count >= len(points):
        return np.asarray(points, dtype=np.float32)
    import open3d as o3d  # imported lazily: heavy, and only the dataset generator needs it

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    return np.asarray(cloud.farthest_point_down_sample(count).points, dtype=np.float32)


def sample_surface_points(mesh: trimesh.Trimesh, num_points: int = 1024, oversample: int = 3, seed: int = 0) -> np.ndarray:
    """(num_points, 3) float32 surface points in mesh coordinates, as the paper samples them (3x + FPS)."""
    candidates, _ = trimesh.sample.sample_surface(mesh, num_points * max(oversample, 1), seed=seed)
    return farthest_point_sample(candidates, num_points)
