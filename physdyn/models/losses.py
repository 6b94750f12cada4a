"""The paper's training loss, computed in normalised units.

Per step and quantity, for x in {dv, dw, dp} with prediction x_hat:

    relative_error = ||x_hat - x||_2 / (||x||_2 + ||x_hat||_2 + eps)

and the same with L1 norms for dtheta. Averaged over the window's steps, then over the batch; plus
``weights.topple`` (2.0) x the per-step sigmoid cross-entropy of the topple logit.

Zero-change guard: the reference code has no epsilon, so a resting or padded step (true change 0) gives
0/0 when the prediction is also 0, and the constant 1 (no gradient) for any other prediction - nothing
teaches "stay at rest". Here, on steps whose true change is below ``rest_threshold`` in norm (normalised
units; padded steps are exactly 0), the term is the absolute error ||x_hat - x|| instead: 0 for a correct
prediction and a unit-size gradient towards 0 for any wrong one, whatever its size. ``eps`` only keeps the
relative form finite when ``rest_threshold`` is 0.

``kind="absolute"`` (the real-world model) keeps only the numerators ||x_hat - x|| on every step.
``kind="huber"`` applies the Huber function to that error norm (quadratic below ``huber_delta``): unlike the
relative loss it does not let the small changes of late, slow steps weigh as much as the large early ones.

``weights.position_drift`` (default 0: the paper's loss) adds the Huber function of the accumulated
position error at each step of the window, ||sum_{s<=t} (dp_hat_s - dp_s)||: the drift a roll-out builds up.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F

from physdyn.config import LossWeights

QUANTITIES = ("linear_velocity", "angular_velocity", "position", "rotation")  # order in the 12 changes
LOSS_KINDS = ("relative", "absolute", "huber")


@dataclass
class LossTerms:
    total: torch.Tensor
    terms: dict[str, torch.Tensor]  # per quantity (and "topple"), unweighted batch means


def relative_error(pred: torch.Tensor, true: torch.Tensor, p: int = 2, eps: float = 1e-6, rest_threshold: float = 1e-3) -> torch.Tensor:
    """pred, true: (..., 3) -> (...): ||pred - true||_p / (||true||_p + ||pred||_p + eps), or the absolute
    error ||pred - true||_p where ||true||_p < rest_threshold (the zero-change guard, see module doc)."""
    err = torch.linalg.vector_norm(pred - true, ord=p, dim=-1)
    true_norm = torch.linalg.vector_norm(true, ord=p, dim=-1)
    rel = err / (true_norm + torch.linalg.vector_norm(pred, ord=p, dim=-1) + eps)
    return torch.where(true_norm < rest_threshold, err, rel)


def absolute_error(pred: torch.Tensor, true: torch.Tensor, p: int = 2) -> torch.Tensor:
    return torch.linalg.vector_norm(pred - true, ord=p, dim=-1)


def dynamics_loss(
    changes: torch.Tensor,
    targets: torch.Tensor,
    topple_logit: torch.Tensor | None = None,
    topple_label: torch.Tensor | None = None,
    *,
    kind: str = "relative",
    weights: dict[str, float] | None = None,
    eps: float = 1e-6,
    rest_threshold: float = 1e-3,
    huber_delta: float = 0.05,
) -> LossTerms:
    """changes, targets: (B, T, 12) normalised [dv, dw, dp, dtheta]; topple_logit, topple_label: (B, T).

    ``weights`` maps each of QUANTITIES and "topple" to its weight (default: ``LossWeights``).
    """
    if kind not in LOSS_KINDS:
        raise ValueError(f"loss kind must be one of {', '.join(LOSS_KINDS)}, got '{kind}'")
    w = {**asdict(LossWeights()), **(weights or {})}  # the config's defaults, then the caller's
    terms: dict[str, torch.Tensor] = {}
    total = changes.new_zeros(())
    for i, name in enumerate(QUANTITIES):
        pred, true = changes[..., 3 * i : 3 * i + 3], targets[..., 3 * i : 3 * i + 3]
        p = 1 if name == "rotation" else 2  # the paper uses L1 norms for the rotation
        if kind == "relative":
            per_step = relative_error(pred, true, p, eps, rest_threshold)
        elif kind == "huber":
            err = absolute_error(pred, true, p)
            per_step = torch.where(err < huber_delta, 0.5 * err * err / huber_delta, err - 0.5 * huber_delta)
        else:
            per_step = absolute_error(pred, true, p)
        terms[name] = per_step.mean(dim=-1).mean()  # over steps, then over the batch
        total = total + w[name] * terms[name]
    if w.get("position_drift", 0.0) > 0:
        # Where the window's predicted positions have got to against the true ones: the summed per-step
        # position errors, which a roll-out accumulates and per-step terms do not see (Huber-shaped like
        # the huber kind, so one bad window does not dominate).
        drift = absolute_error(torch.cumsum(changes[..., 6:9], dim=-2), torch.cumsum(targets[..., 6:9], dim=-2))
        per_step = torch.where(drift < huber_delta, 0.5 * drift * drift / huber_delta, drift - 0.5 * huber_delta)
        terms["position_drift"] = per_step.mean(dim=-1).mean()
        total = total + w["position_drift"] * terms["position_drift"]
    if topple_logit is not None and topple_label is not None:
        bce = F.binary_cross_entropy_with_logits(topple_logit, topple_label.to(topple_logit.dtype), reduction="none")
        terms["topple"] = bce.mean(dim=-1).mean()
        total = total + w["topple"] * terms["topple"]
    return LossTerms(total, terms)
