"""A batch's roll-out of a model that is its contact prior alone (``fast``'s motion, the planner's screen) on
numpy: ``DynamicsNetwork.rollout_changes`` for B > 1 on the CPU, where the torch loop
(``physdyn.models.batch_rollout``) pays a few microseconds of dispatch for each of its ~300 tensor operations
a step whatever the batch: ~0.8 ms a step, ~35 ms for a 3 s roll-out of 32 sampled pushes. numpy's
operations on the same (B, 4) arrays cost about a microsecond each, and the loop ends at the step where
every sequence has come to rest (a stateless prior repeats itself from there), so the same roll-out costs a
few milliseconds.

The arithmetic is ``physdyn.models.priors.contact_changes``', operation for operation, in float64 as the
one-object roll-out (``physdyn.models.single_rollout``) does it: its numbers equal that roll-out's and the
torch loop's to float32 rounding (those feed the prior float32 velocities) (``tests/models/test_prior_rollout.py``). ``friction`` may
differ per sequence: a push's friction is an input of the prior, not a weight.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from physdyn.models.priors import AT_REST, PRESSURE_LEAN


def prior_rollout(geometry: np.ndarray, linear_velocity0: np.ndarray, angular_velocity0: np.ndarray, steps: int,
                  dt: float, friction: Any, gravity: float, substeps: int) -> dict[str, np.ndarray]:
    """geometry (B, G) from ``contact_geometry``; velocities (B, 3) SI; friction a coefficient or (B,) of them
    -> ``changes`` (B, steps, 12) float64 SI [dv, dw, dp, dtheta] and ``fed`` (B, steps, 6): the velocities
    fed at each step, as ``DynamicsNetwork.rollout_changes`` returns them."""
    g = np.asarray(geometry, dtype=np.float64)
    v = np.array(linear_velocity0, dtype=np.float64).reshape(-1, 3)
    w = np.array(angular_velocity0, dtype=np.float64).reshape(-1, 3)
    B = len(v)
    mu = np.broadcast_to(np.asarray(friction, dtype=np.float64), (B,)).copy()
    turn = np.zeros((B, 4))
    turn[:, 3] = 1.0
    changes = np.zeros((B, steps, 12))
    fed = np.zeros((B, steps, 6))
    for t in range(steps):
        fed[:, t, :3], fed[:, t, 3:] = v, w
        if not (v.any() or w.any()):
            break  # every sequence rests: each later step is zero changes fed zero velocities
        si = np.concatenate([-v, -w, np.zeros((B, 6))], axis=1)  # at rest, friction takes the motion away
        moving = (np.hypot(v[:, 0], v[:, 1]) >= AT_REST) | (np.abs(w[:, 2]) >= AT_REST)
        if moving.any():
            si[moving] = _substeps(g[moving], v[moving], w[moving], turn[moving], dt, mu[moving], gravity, substeps)
        changes[:, t] = si
        turn = _compose(si[:, 9:12], turn)
        v = v + si[:, 0:3]
        w = w + si[:, 3:6]
    return {"changes": changes, "fed": fed}


def _compose(rotvec: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Exp(rotvec) * q, normalised (rows)."""
    angle = np.linalg.norm(rotvec, axis=1, keepdims=True)
    small = angle < 1e-4
    s = np.where(small, 0.5 - angle * angle / 48.0, np.sin(0.5 * angle) / np.where(small, 1.0, angle))
    ax, ay, az = (rotvec * s).T
    aw = np.cos(0.5 * angle[:, 0])
    bx, by, bz, bw = q.T
    out = np.stack([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                    aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz], axis=1)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _substeps(geometry: np.ndarray, v: np.ndarray, w: np.ndarray, q: np.ndarray, dt: float, mu: np.ndarray,
              gravity: float, substeps: int) -> np.ndarray:
    """``contact_changes``' sub-steps for M moving sequences -> (M, 12)."""
    M = len(v)
    K = (geometry.shape[1] - 2) // 4
    support = geometry[:, : 3 * K].reshape(M, K, 3)
    base = geometry[:, 3 * K : 4 * K]
    spin_inertia = geometry[:, 4 * K : 4 * K + 1]
    height = geometry[:, 4 * K + 1 : 4 * K + 2]
    # rotate the support points by q: x + w t + u x t, t = 2 u x x
    u_ = np.broadcast_to(q[:, None, :3], support.shape)
    tt = 2.0 * np.cross(u_, support)
    footprint = support + q[:, None, 3:4] * tt + np.cross(u_, tt)
    r = footprint[..., 0] + 1j * footprint[..., 1]  # (M, K)
    centre = (base * r).sum(1, keepdims=True)
    decel = np.maximum(np.abs(mu * gravity), 1e-9)[:, None]  # (M, 1)
    h = dt / substeps
    slip_scale = decel * h
    lean = PRESSURE_LEAN * mu[:, None] * height
    u0 = (v[:, 0] + 1j * v[:, 1])[:, None]
    om0 = w[:, 2:3]
    offset = r - centre
    ox, oy = offset.real, offset.imag
    cxx = (base * ox * ox).sum(1, keepdims=True) + 1e-6
    cyy = (base * oy * oy).sum(1, keepdims=True) + 1e-6
    cxy = (base * ox * oy).sum(1, keepdims=True)
    det = cxx * cyy - cxy * cxy
    speed = np.abs(u0)
    moving = np.minimum(speed / slip_scale, 1.0)
    shift = moving * lean * (u0 / np.maximum(speed, 1e-9)) - centre
    ax = (cyy * shift.real - cxy * shift.imag) / det
    ay = (cxx * shift.imag - cxy * shift.real) / det
    weights = base * np.maximum(1.0 + ox * ax + oy * ay, 0.0)
    weights = weights / np.maximum(weights.sum(1, keepdims=True), 1e-12)
    stiffness = decel * h / spin_inertia
    stick = slip_scale * (1.0 + (weights * np.abs(r) ** 2).sum(1, keepdims=True) / spin_inertia)
    spun_r = 1j * r
    u, om = u0, om0
    u_sum, om_sum = np.zeros_like(u0), np.zeros_like(om0)
    for _ in range(substeps):
        rel = u + om * spun_r
        pull = rel * (weights / np.maximum(np.abs(rel), stick))
        u = u - decel * h * pull.sum(1, keepdims=True)
        spun = om - stiffness * (spun_r.conj() * pull).sum(1, keepdims=True).real
        om = np.where(spun * om < 0, 0.0, spun)  # friction stops a spin, never reverses it
        u_sum = u_sum + u
        om_sum = om_sum + om
        spun_r = spun_r * np.exp(1j * om * h)
    dp, yaw = u_sum * h, om_sum * h
    zeros = np.zeros((M, 1))
    du = u - u0
    return np.concatenate([du.real, du.imag, -v[:, 2:3], -w[:, :2], om - om0, dp.real, dp.imag,
                           zeros, zeros, zeros, yaw], axis=1)
