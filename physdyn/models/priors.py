"""Analytic priors a model can correct instead of predicting each change from scratch (``model.prior``).

The network then outputs the residual between the true change and the prior's, in normalised units. Both
priors are pure functions of the velocities fed at step t, so teacher forcing and roll-outs use them alike.

- ``kinematic``: constant velocities over the step: dv = 0, dw = 0, dp = v dt, dtheta = w dt. It ties the
  position and rotation changes to the velocities the model itself carries.
- ``coulomb``: as kinematic, but the horizontal velocity decelerates at mu g (Coulomb sliding of a point
  mass, the baseline of ``physdyn.eval.baselines``) and stops when it reaches zero within the step:
  with u = |v_xy| and tau = min(dt, u / (mu g)), dv_xy = -mu g tau u_hat, dp_xy = (u tau - mu g tau^2 / 2) u_hat.
"""

from __future__ import annotations

import torch

PRIORS = ("none", "kinematic", "coulomb")


def prior_changes(kind: str, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, dt: float,
                  friction: float, gravity: float = 9.81) -> torch.Tensor | None:
    """linear_velocity, angular_velocity: (..., 3) SI, world frame -> (..., 12) [dv, dw, dp, dtheta] SI,
    or None for ``kind="none"``."""
    if kind == "none":
        return None
    if kind not in PRIORS:
        raise ValueError(f"unknown prior '{kind}'; use one of {', '.join(PRIORS)}")
    v, w = linear_velocity, angular_velocity
    dv = torch.zeros_like(v)
    dp = v * dt
    if kind == "coulomb":
        decel = abs(float(friction) * float(gravity))
        u = v[..., :2]
        speed = torch.linalg.vector_norm(u, dim=-1, keepdim=True)
        direction = u / speed.clamp_min(1e-9)
        tau = torch.minimum(torch.full_like(speed, dt), speed / max(decel, 1e-9))
        dv = torch.cat([-decel * tau * direction, torch.zeros_like(speed)], dim=-1)
        dp = torch.cat([(speed * tau - 0.5 * decel * tau * tau) * direction, v[..., 2:3] * dt], dim=-1)
    return torch.cat([dv, torch.zeros_like(w), dp, w * dt], dim=-1)
