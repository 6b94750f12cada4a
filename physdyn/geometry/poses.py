"""Stable resting orientations of a rigid body on a plane."""

from __future__ import annotations

import numpy as np
import trimesh


def stable_orientations(mesh: trimesh.Trimesh, com: np.ndarray, min_probability: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (K, 3, 3) that rest the mesh on a face of its convex hull, with their probabilities (K,).

    Probabilities are trimesh's estimate of how often a randomly dropped object lands in each pose; poses
    less likely than ``min_probability`` are dropped (they are balanced on a knife edge, e.g. an upright
    capsule) and the rest renormalised.
    """
    transforms, probs = trimesh.poses.compute_stable_poses(mesh, center_mass=com)
    probs = np.asarray(probs, dtype=np.float64)
    keep = probs >= min_probability
    if not keep.any():
        keep = probs == probs.max()
    rotations = np.asarray(transforms)[keep, :3, :3]
    probs = probs[keep]
    return rotations, probs / probs.sum()
