"""A ``DynamicsNetwork``'s training loss on a batch of windows, in normalised units: fed the true velocities
(perturbed by ``rollout.input_noise``), or step by step on its own (``rollout.feedback``), against targets that
lead back to the true next velocities."""

from __future__ import annotations

from typing import Any

import torch

from physdyn.models.losses import dynamics_loss


def fed_velocities(network: Any, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Velocities fed at every step of a training window, and the targets (normalised) to match them.

    With ``rollout.input_noise`` the fed velocities are perturbed and the velocity targets corrected to
    lead back to the true next velocities (v_{t+1} - fed v_t), so the model learns to recover from its own
    drift. Returns (linear (B, T, 3), angular (B, T, 3), targets (B, T, 12))."""
    v, w = batch["linear_velocity"], batch["angular_velocity"]
    if network.training:
        v, w = perturbed(network, v, w)
    return v, w, corrected_targets(network, batch, v, w)


def perturbed(network: Any, v: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """v, w (..., 3) plus Gaussian noise of std ``rollout.input_noise`` in normalised units (or as given)."""
    sigma = network.config.rollout.input_noise
    if sigma <= 0:
        return v, w
    noise = torch.randn(*v.shape[:-1], 6, device=v.device, dtype=v.dtype) * sigma * network.velocity_scale
    return v + noise[..., :3], w + noise[..., 3:]


def corrected_targets(network: Any, batch: dict[str, torch.Tensor], v: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Normalised targets whose velocity changes lead from the fed v, w to the TRUE next velocities."""
    true_next_v = batch["linear_velocity"] + batch["delta_linear_velocity"]
    true_next_w = batch["angular_velocity"] + batch["delta_angular_velocity"]
    si = torch.cat([true_next_v - v, true_next_w - w, batch["delta_position"], batch["delta_rotation"]], dim=-1)
    return (si - network.change_shift) / network.change_scale


def closed_loop(network: Any, feature: torch.Tensor, batch: dict[str, torch.Tensor]):
    """A training window fed step by step, each window with probability ``rollout.feedback`` on the
    model's own (detached) velocity predictions from step 1 on, as a roll-out feeds them."""
    v_true, w_true = batch["linear_velocity"], batch["angular_velocity"]
    B, T = v_true.shape[:2]
    own = (torch.rand(B, 1, device=v_true.device) < network.config.rollout.feedback)
    orientation = batch.get("relative_orientation_xyzw") if network.uses_orientation else None
    v, w = v_true[:, 0], w_true[:, 0]
    fed_v, fed_w, changes, logits, state = [], [], [], [], None
    for t in range(T):
        v, w = perturbed(network, v, w)
        q = None if orientation is None else orientation[:, t : t + 1]
        c, logit, state = network(feature, v[:, None], w[:, None], state, q)
        fed_v.append(v)
        fed_w.append(w)
        changes.append(c)
        logits.append(logit)
        if t + 1 < T:
            si = (c[:, 0].detach() * network.change_scale + network.change_shift)
            v = torch.where(own, v + si[:, 0:3], v_true[:, t + 1])
            w = torch.where(own, w + si[:, 3:6], w_true[:, t + 1])
    v_fed, w_fed = torch.stack(fed_v, 1), torch.stack(fed_w, 1)
    logit = None if logits[0] is None else torch.cat(logits, dim=1)
    return torch.cat(changes, dim=1), logit, corrected_targets(network, batch, v_fed, w_fed)


def network_loss(network: Any, batch: dict[str, torch.Tensor]):
    """The loss (``physdyn.models.losses.dynamics_loss``) of ``network`` on a batch of training windows."""
    feature = network.encode(batch["points"], batch.get("spin_inertia"))
    if network.training and network.config.rollout.feedback > 0:
        changes, logit, targets = closed_loop(network, feature, batch)
    else:
        v, w, targets = fed_velocities(network, batch)
        orientation = batch.get("relative_orientation_xyzw") if network.uses_orientation else None
        changes, logit, _ = network(feature, v, w, None, orientation)
    lc = network.loss_config
    return dynamics_loss(
        changes, targets, logit, batch["topple_label"],
        kind=lc.kind, weights=dict(vars(lc.weights)), eps=lc.eps, rest_threshold=lc.rest_threshold,
        huber_delta=lc.huber_delta,
    )

