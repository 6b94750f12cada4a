"""Perturbed pushes: the uncertainty of a push (docs/conventions.md, "Uncertainty of a push") drawn for
the members of an ensemble. Pure numpy; world frame, z up, SI units."""

from __future__ import annotations

import numpy as np

from physdyn.config.uncertainty import UncertaintyConfig

# Standard normals per member, in this order: speed, direction, spin_rel (x, y, z), spin_abs (x, y, z),
# friction. Drawn as one (B, K, 9) block, so the first K members of a larger ensemble are the same pushes.
DRAWS_PER_MEMBER = 9


def perturb_pushes(lin_vel: np.ndarray, ang_vel: np.ndarray, friction: np.ndarray, uncertainty: UncertaintyConfig,
                   rng: np.random.Generator, members: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``members`` perturbed copies of each push, each member one draw of standard normals N:

    - the linear velocity scaled by (1 + speed_rel N) and turned by direction_deg N degrees about z;
    - each axis of the angular velocity + spin_rel |w| N + spin_abs N (independent N per term and axis);
    - the friction coefficient scaled by (1 + friction_rel N).

    A scale below zero (N < -1/sigma: only for spreads far above the default's) is taken as zero, so a
    perturbed push never reverses and friction stays physical.

    lin_vel: (B, 3) m/s, ang_vel: (B, 3) rad/s, friction: (B,) effective Coulomb coefficients.
    Returns lin_vel (B, K, 3), ang_vel (B, K, 3), friction (B, K), K = members. With zero uncertainty every
    member equals its push exactly.
    """
    lin_vel = np.asarray(lin_vel, dtype=np.float64).reshape(-1, 3)
    ang_vel = np.asarray(ang_vel, dtype=np.float64).reshape(-1, 3)
    friction = np.asarray(friction, dtype=np.float64).reshape(-1)
    n = rng.standard_normal((len(lin_vel), int(members), DRAWS_PER_MEMBER))
    speed_scale = np.maximum(1.0 + uncertainty.speed_rel * n[..., 0], 0.0)
    turn = np.deg2rad(uncertainty.direction_deg * n[..., 1])
    c, s = np.cos(turn), np.sin(turn)
    v = lin_vel[:, None, :]
    turned = np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1],
                       np.broadcast_to(v[..., 2], c.shape)], axis=-1)
    lin = turned * speed_scale[..., None]
    spin = np.linalg.norm(ang_vel, axis=1)[:, None, None]
    ang = ang_vel[:, None, :] + uncertainty.spin_rel * spin * n[..., 2:5] + uncertainty.spin_abs * n[..., 5:8]
    mu = friction[:, None] * np.maximum(1.0 + uncertainty.friction_rel * n[..., 8], 0.0)
    return lin, ang, mu
