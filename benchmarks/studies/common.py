"""Code the studies share: the travel frame of a push, the contact prior rolled out alone from a slide and a
spin, the footprint read from the cloud's convex-hull facet, and the PointNet studies' run specs.

The studies are run from the repository root as ``python -m benchmarks.studies.NAME``, so that they import
this module, and the frontier's mesh sets and measurement (``benchmarks.frontier``,
``benchmarks.frontier_sets``), by their package names.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

from physdyn.data.windows import relative_rotation
from physdyn.models.priors import SUPPORT_DEPTH, contact_changes
from physdyn.models.rotations import quat_multiply, rotvec_to_quat

RATE, STEPS, MU = 15.0, 5, 0.25  # prior_rollout's defaults: the conventions' 15 Hz, 1/3 s, a mid friction


def yaw_of(q: np.ndarray) -> np.ndarray:
    """q: (..., 4) xyzw -> (...,) its yaw (rad)."""
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def travel_frame(v0: np.ndarray) -> np.ndarray:
    """(B, 2) unit travel directions of the (B, 3) velocities ``v0`` (x where the push has no horizontal speed)."""
    d = v0[:, :2]
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n > 1e-9, d / np.maximum(n, 1e-12), np.array([1.0, 0.0]))


def in_travel_frame(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(B, 3) vectors in the frame of the (B, 2) travel directions ``u``: along, across, up."""
    return np.stack([(a[:, :2] * u).sum(1), u[:, 0] * a[:, 1] - u[:, 1] * a[:, 0], a[:, 2]], axis=1)


def travel_state(v, w, p, q, p0, q0, u) -> np.ndarray:
    """(B, 6): velocity along and across the travel ``u``, spin w_z, displacement from ``p0`` along and
    across, turn about the vertical since ``q0``. v, w, p, p0: (B, 3); q, q0: (B, 4) xyzw; u: (B, 2)."""
    vt, dp = in_travel_frame(v, u), in_travel_frame(p - p0, u)
    turn = yaw_of(relative_rotation(q0, q[:, None])[:, 0])
    return np.stack([vt[:, 0], vt[:, 1], w[:, 2], dp[:, 0], dp[:, 1], turn], axis=1)


def prior_rollout(geometry, v0, w0, rate=RATE, friction=MU):
    """The contact prior alone from a slide v0 along x and a spin w0: (w_z, horizontal speed) over STEPS steps,
    each (STEPS + 1,). geometry: the prior's (1, 18) footprint (``contact_geometry``)."""
    v = torch.tensor([[[v0, 0.0, 0.0]]]); w = torch.tensor([[[0.0, 0.0, w0]]]); q = torch.tensor([[[0.0, 0.0, 0.0, 1.0]]])
    spins, speeds = [w0], [abs(v0)]
    for _ in range(STEPS):
        with torch.no_grad():
            c = contact_changes(v, w, q, geometry, 1 / rate, friction)
        v, w = v + c[..., 0:3], w + c[..., 3:6]
        q = quat_multiply(rotvec_to_quat(c[..., 9:12]), q)
        spins.append(w[0, 0, 2].item()); speeds.append(v[0, 0, :2].norm().item())
    return np.array(spins), np.array(speeds)


def touching_mask(P: np.ndarray, tol: float, perimeter: bool = False) -> np.ndarray:
    """(N,) bool: the points of the cloud P (N, 3) within ``tol`` m of the convex-hull facet under the centre
    of mass (the face the simulator's hull collision shape rests on); ``perimeter``: that facet's outline's
    corners only. Falls back to the shipped band (within SUPPORT_DEPTH of the lowest point) where qhull fails."""
    z = P[:, 2]
    band = z <= z.min() + SUPPORT_DEPTH
    try:
        hull = ConvexHull(P)
    except QhullError:
        return band
    # The facet the downward vertical through the centre of mass (inside the hull) leaves it by: among the
    # facets facing down (n . (0, 0, -1) > 0), the nearest along the ray (the distance -c / that product).
    eq = hull.equations  # n . x + c <= 0 inside, n outward
    along = -eq[:, 2]
    if not (along > 1e-12).any():
        return band
    k = np.argmin(np.where(along > 1e-12, -eq[:, 3] / np.where(along > 1e-12, along, 1.0), np.inf))
    n, c = eq[k, :3], eq[k, 3]
    on = (P @ n + c) >= -tol
    if perimeter and on.sum() >= 3:  # only the corners of the facet's outline (where Bullet keeps its contacts)
        idx = np.flatnonzero(on)
        try:
            corners = idx[ConvexHull(P[idx, :2]).vertices]
        except QhullError:
            return on
        on = np.zeros_like(on)
        on[corners] = True
    return on


def parse_run(spec: str) -> tuple[list[int], int, bool]:
    """"STORES:SHAPES[:scalars]", e.g. "0:300" (300 training shapes of the first store), "0,1:all",
    "0,1:all:scalars" (no cloud: the control) -> (stores, shapes (0: all), use_cloud)."""
    parts = spec.split(":")
    stores = [int(x) for x in parts[0].split(",")]
    n = 0 if parts[1] == "all" else int(parts[1])
    return stores, n, not (len(parts) > 2 and parts[2] == "scalars")
