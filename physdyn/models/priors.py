"""Analytic priors a model can correct instead of predicting each change from scratch (``model.prior``).

The network then outputs the residual between the true change and the prior's, in normalised units. The
priors are pure functions of the velocities fed at step t, so teacher forcing and roll-outs use them alike.

- ``kinematic``: constant velocities over the step: dv = 0, dw = 0, dp = v dt, dtheta = w dt. It ties the
  position and rotation changes to the velocities the model itself carries.
- ``coulomb``: as kinematic, but the horizontal velocity decelerates at mu g (Coulomb sliding of a point
  mass, the baseline of ``physdyn.eval.baselines``) and stops when it reaches zero within the step:
  with u = |v_xy| and tau = min(dt, u / (mu g)), dv_xy = -mu g tau u_hat, dp_xy = (u tau - mu g tau^2 / 2) u_hat.
- ``planar``: as coulomb for the horizontal velocity, and the spin about the vertical slows linearly to stop
  when the slide stops (under Coulomb friction a body sliding and spinning on a plane stops translating and
  rotating at the same moment: Goyal, Ruina & Papadopoulos, "Planar sliding with dry friction", 1991), while
  spin about horizontal axes (tilt, which the ground's contact damps at once unless the object topples) and
  vertical velocity are taken away within the step. With t_stop = u / (mu g): dw_z = -w_z tau / t_stop,
  dtheta_z = w_z tau - w_z tau^2 / (2 t_stop), dw_xy = -w_xy, dtheta_xy = 0, dv_z = -v_z, dp_z = 0.
"""

from __future__ import annotations

import torch

PRIORS = ("none", "kinematic", "coulomb", "planar")


def prior_changes(kind: str, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, dt: float,
                  friction: float, gravity: float = 9.81) -> torch.Tensor | None:
    """linear_velocity, angular_velocity: (..., 3) SI, world frame -> (..., 12) [dv, dw, dp, dtheta] SI,
    or None for ``kind="none"``."""
    if kind == "none":
        return None
    if kind not in PRIORS:
        raise ValueError(f"unknown prior '{kind}'; use one of {', '.join(PRIORS)}")
    v, w = linear_velocity, angular_velocity
    dv, dw, dp, dtheta = torch.zeros_like(v), torch.zeros_like(w), v * dt, w * dt
    if kind == "kinematic":
        return torch.cat([dv, dw, dp, dtheta], dim=-1)
    decel = max(abs(float(friction) * float(gravity)), 1e-9)
    u = v[..., :2]
    speed = torch.linalg.vector_norm(u, dim=-1, keepdim=True)
    direction = u / speed.clamp_min(1e-9)
    tau = torch.minimum(torch.full_like(speed, dt), speed / decel)  # sliding time within the step
    dv_xy = -decel * tau * direction
    dp_xy = (speed * tau - 0.5 * decel * tau * tau) * direction
    if kind == "coulomb":  # vertical motion and spin stay kinematic
        return torch.cat([dv_xy, dv[..., 2:], dw, dp_xy, dp[..., 2:], dtheta], dim=-1)
    t_stop = (speed / decel).clamp_min(1e-9)
    wz = w[..., 2:3]
    return torch.cat([dv_xy, -v[..., 2:3], -w[..., :2], -wz * tau / t_stop,
                      dp_xy, torch.zeros_like(speed), torch.zeros_like(u), wz * tau - wz * tau * tau / (2 * t_stop)], dim=-1)
