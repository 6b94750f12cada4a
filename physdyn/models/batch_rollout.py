"""A batch's roll-out in torch: ``DynamicsModel.rollout_changes`` for B > 1, on a GPU, or with components
the one-object roll-out (``physdyn.models.single_rollout``) does not cover.

One shape encoding per distinct cloud, then one network step per recorded step on the model's own
velocities, without numpy between steps (choosing the moving rows does read a few flags back from the
device each step; on a GPU that costs a synchronisation, not yet measured). Work is spent on the sequences still moving: below the rest gate the
network's changes are not used, so when no topple probabilities are wanted (a model with a topple
classifier) such a sequence only queues its LSTM input, taken before its next step that needs the network
(the same states in the same order, as ``SingleRollout`` does); and the contact prior of a body at rest is
the stop itself, without its sub-steps (``physdyn.models.priors.contact_changes`` without gradient). In a
3 s roll-out most pushes rest for most steps, which made a batch of 256 about 1.8x cheaper
(docs/performance.md).
"""

from __future__ import annotations

from typing import Any

import torch

from physdyn.models.predictors.lstm import LSTMPredictor
from physdyn.models.rotations import quat_multiply, rotvec_to_quat


def batch_rollout(model: Any, points: Any, linear_velocity0: Any, angular_velocity0: Any, steps: int, warm_linear: Any = None,
                  warm_angular: Any = None, spin_inertia: Any = None, topple: bool = True) -> dict[str, torch.Tensor | None]:
    """``DynamicsModel.rollout_changes`` for a batch, in torch (call it through that method, which sets eval
    and inference mode): the same arguments and results."""
    device, f64 = model.device, torch.float64
    points = torch.as_tensor(points, dtype=torch.float32, device=device)
    B = points.shape[0]
    # One encoding per distinct cloud: a batch of requests often pushes the same object in the same pose
    # (in eval mode every cloud is encoded on its own, so this changes no number).
    unique, inverse = torch.unique(points.reshape(B, -1), dim=0, return_inverse=True)
    code = model.with_spin_inertia(model.encode(unique.reshape(len(unique), *points.shape[1:]))[inverse], spin_inertia)
    feature, geometry = model.split_code(code)
    v = torch.as_tensor(linear_velocity0, dtype=f64, device=device).reshape(B, 3)
    w = torch.as_tensor(angular_velocity0, dtype=f64, device=device).reshape(B, 3)
    K = 0 if warm_linear is None else int(warm_linear.shape[1])
    if K:
        warm_linear = torch.as_tensor(warm_linear, dtype=f64, device=device)
        warm_angular = torch.as_tensor(warm_angular, dtype=f64, device=device)
    changes = torch.empty(B, steps, 12, dtype=f64, device=device)
    fed = torch.empty(B, steps, 6, dtype=f64, device=device)
    want_topple = topple and model.predicts_topple
    topple_out = torch.zeros(B, steps, dtype=f64, device=device) if want_topple else None
    turn = torch.zeros(B, 4, dtype=f64, device=device) if model.uses_orientation else None
    if turn is not None:
        turn[:, 3] = 1.0
    turns = torch.empty(B, steps, 4, dtype=torch.float32, device=device) if turn is not None else None
    scale, shift = model.change_scale.to(f64), model.change_shift.to(f64)
    # Rows of the recurrent state can be taken and put back only for the LSTM's (h, c); other predictors
    # run every sequence at every step.
    skip = not want_topple and type(model.predictor) is LSTMPredictor
    L, H = (model.predictor.config.num_layers, model.predictor.config.hidden) if skip else (0, 0)
    h = torch.zeros(L, B, H, device=device) if skip else None
    c = torch.zeros(L, B, H, device=device) if skip else None
    queued_from = torch.full((B,), -1, dtype=torch.long, device=device)  # first step not yet taken, or -1
    state = None
    for t in range(steps):
        if 1 <= t <= K:
            v, w = warm_linear[:, t - 1], warm_angular[:, t - 1]
        fed[:, t, :3], fed[:, t, 3:] = v, w
        v32, w32 = v.float()[:, None], w.float()[:, None]
        q = None if turn is None else turn.float()[:, None]
        if turns is not None:
            turns[:, t] = q[:, 0]
        moving = model.rest_gate(v32, w32)
        if not skip:
            inputs = model.network_inputs(feature, v32, w32, q)
            features, state = model.predictor(inputs, state)
            net, logit = model.head(features)
            if topple_out is not None and logit is not None:
                topple_out[:, t] = torch.sigmoid(logit[:, 0]).to(f64)
        else:
            need = torch.ones(B, dtype=torch.bool, device=device) if moving is None else moving[:, 0]
            rows = need.nonzero()[:, 0]
            net = torch.zeros(B, 1, 12, device=device)
            if len(rows):
                _take_queued(model, rows, t, queued_from, feature, fed, turns, h, c)
                inputs = model.network_inputs(feature[rows], v32[rows], w32[rows], None if q is None else q[rows])
                features, (h[:, rows], c[:, rows]) = model.predictor(inputs, (h[:, rows], c[:, rows]))
                net[rows] = model.head(features)[0]
            queued_from = torch.where(~need & (queued_from < 0), t, queued_from)
        prior = model.analytic_prior(v32, w32, q, geometry)
        out = net if prior is None else model.with_residual(net, prior, moving)
        si = out[:, 0].to(f64) * scale + shift
        changes[:, t] = si
        if turn is not None:  # R_{t+1} R_0^T = Exp(dtheta_t) R_t R_0^T, as the pose is integrated
            turn = quat_multiply(rotvec_to_quat(si[:, 9:12]), turn)
            turn = turn / torch.linalg.vector_norm(turn, dim=-1, keepdim=True)
        v = v + si[:, 0:3]
        w = w + si[:, 3:6]
    return {"changes": changes, "fed": fed, "topple_probability": topple_out}


def _take_queued(model: Any, rows: torch.Tensor, t: int, queued_from: torch.Tensor, feature: torch.Tensor,
                 fed: torch.Tensor, turns: torch.Tensor | None, h: torch.Tensor, c: torch.Tensor) -> None:
    """Run the LSTM of ``rows`` over the inputs they queued before step t (steps queued_from..t-1), in
    one call per first queued step, and mark their queues empty."""
    behind = rows[queued_from[rows] >= 0]
    for first in torch.unique(queued_from[behind]).tolist():
        group = behind[queued_from[behind] == first]
        span = fed[group, first:t].float()
        q = None if turns is None else turns[group, first:t]
        inputs = model.network_inputs(feature[group], span[..., :3], span[..., 3:], q)
        state = (h[:, group], c[:, group])
        for k in range(inputs.shape[1]):  # step by step, as the steps that needed the network ran
            _, state = model.predictor(inputs[:, k : k + 1], state)
        h[:, group], c[:, group] = state
    queued_from[rows] = -1
