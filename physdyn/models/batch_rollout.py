"""A batch's roll-out in torch: ``DynamicsNetwork.rollout_changes`` for B > 1, on a GPU, or with components
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
A model that is its prior alone (the ``none`` predictor and a zero residual: ``fast``, the planner's screen)
takes the prior's changes without the model's forward, with the same numbers
(``DynamicsNetwork.changes_are_the_prior``).
"""

from __future__ import annotations

from typing import Any

import torch

from physdyn.models.heads.base import NUM_CHANGES
from physdyn.models.predictors.lstm import LSTMPredictor
from physdyn.models.prior_rollout import prior_rollout
from physdyn.models.priors import RESIDUAL_MASKS
from physdyn.models.rotations import quat_multiply, rotvec_to_quat


# the prior alone on the CPU rolls out on numpy (physdyn.models.prior_rollout); the tests compare it with this loop
PRIOR_ON_NUMPY = True


def batch_rollout(model: Any, points: Any, linear_velocity0: Any, angular_velocity0: Any, steps: int, warm_linear: Any = None,
                  warm_angular: Any = None, spin_inertia: Any = None, topple: bool = True,
                  warm_turn: Any = None) -> dict[str, torch.Tensor | None]:
    """``DynamicsNetwork.rollout_changes`` for a batch, in torch (call it through that method, which sets eval
    and inference mode): the same arguments and results."""
    device, f64 = model.device, torch.float64
    points = torch.as_tensor(points, dtype=torch.float32, device=device)
    B = points.shape[0]
    # One encoding per distinct cloud: a batch of requests often pushes the same object in the same pose
    # (in eval mode every cloud is encoded on its own, so this changes no number).
    unique, inverse = torch.unique(points.reshape(B, -1), dim=0, return_inverse=True)
    code = model.with_spin_inertia(model.encode(unique.reshape(len(unique), *points.shape[1:]))[inverse], spin_inertia)
    v = torch.as_tensor(linear_velocity0, dtype=f64, device=device).reshape(B, 3)
    w = torch.as_tensor(angular_velocity0, dtype=f64, device=device).reshape(B, 3)
    K = 0 if warm_linear is None else int(warm_linear.shape[1])
    if K:
        warm_linear = torch.as_tensor(warm_linear, dtype=f64, device=device)
        warm_angular = torch.as_tensor(warm_angular, dtype=f64, device=device)
    if warm_turn is not None:
        warm_turn = torch.as_tensor(warm_turn, dtype=f64, device=device)
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
    # run every sequence at every step, through the model's forward.
    parts = model.network_codes(code)
    skip = not want_topple and all(type(m.predictor) is LSTMPredictor for m, _ in parts)
    if skip:  # each network with its own rows, queue and rest gate
        nets = [_Rows(m, m.split_code(c), B) for m, c in parts]
        # the two networks' contact priors are one computation when they read the same footprint
        shared = len(nets) > 1 and nets[1].same_prior(nets[0])
    # The prior alone (contact_prior_predictor(), `fast`): a step's changes are the prior's, so the forward's
    # network inputs, empty features and zero residual are skipped (the same numbers: adding the zero
    # residual changes no value, and the standardisation is done as the forward does it)
    alone = not skip and model.linear_channels is None and model.changes_are_the_prior()
    geometry = model.split_code(code)[1] if alone else None
    # a head's topple output is then its bias at every step: the forward's sigmoid of it, taken once (on one
    # element, as the forward's strided column is: torch's vectorised kernel can differ in the last bit)
    constant = (torch.sigmoid(model.head.linear.bias[NUM_CHANGES:NUM_CHANGES + 1]).to(f64)
                if alone and topple_out is not None else None)
    if alone and K == 0 and device.type == "cpu" and PRIOR_ON_NUMPY:
        # the prior on numpy: the same changes to float32 rounding, a tenth of the dispatch, ended at rest
        out = prior_rollout(geometry.double().numpy(), v.numpy(), w.numpy(), steps, model.prior_dt,
                            model.prior_friction, model.prior_gravity, model.config.model.contact_substeps)
        if topple_out is not None:
            topple_out[:] = constant
        return {"changes": torch.from_numpy(out["changes"]), "fed": torch.from_numpy(out["fed"]),
                "topple_probability": topple_out}
    state = None
    for t in range(steps):
        if 1 <= t <= K:
            v, w = warm_linear[:, t - 1], warm_angular[:, t - 1]
            if warm_turn is not None and turn is not None:
                turn = warm_turn[:, t - 1]
        fed[:, t, :3], fed[:, t, 3:] = v, w
        v32, w32 = v.float()[:, None], w.float()[:, None]
        q = None if turn is None else turn.float()[:, None]
        if turns is not None:
            turns[:, t] = q[:, 0]
        if alone:
            prior = model.analytic_prior(v32, w32, q, geometry)[:, 0]
            si = ((prior - model.change_shift) / model.change_scale).to(f64) * scale + shift
            if constant is not None:
                topple_out[:, t] = constant
        elif not skip:  # the model's forward: network, prior and rest gate
            out, logit, state = model(code, v32, w32, state, q)
            if topple_out is not None and logit is not None:
                topple_out[:, t] = torch.sigmoid(logit[:, 0]).to(f64)
            si = out[:, 0].to(f64) * scale + shift
        else:
            si, prior = nets[0].changes(t, v32, w32, q, fed, turns)
            if len(nets) > 1:  # velocity and position from the linear channels' network
                si = torch.where(LINEAR.to(device), nets[1].changes(t, v32, w32, q, fed, turns, prior if shared else None)[0], si)
        changes[:, t] = si
        if turn is not None:  # R_{t+1} R_0^T = Exp(dtheta_t) R_t R_0^T, as the pose is integrated
            turn = quat_multiply(rotvec_to_quat(si[:, 9:12]), turn)
            turn = turn / torch.linalg.vector_norm(turn, dim=-1, keepdim=True)
        v = v + si[:, 0:3]
        w = w + si[:, 3:6]
    return {"changes": changes, "fed": fed, "topple_probability": topple_out}


LINEAR = torch.tensor(RESIDUAL_MASKS["linear"]) > 0  # the changes a combined model takes from its second network


class _Rows:
    """One network's roll-out state by rows (the LSTM's h and c, and the steps each row has queued), so
    that the network runs only on the rows above its rest gate."""

    def __init__(self, model: Any, code: tuple[torch.Tensor, torch.Tensor | None], B: int):
        self.model = model
        self.feature, self.geometry = code
        L, H = model.predictor.config.num_layers, model.predictor.config.hidden
        self.h = torch.zeros(L, B, H, device=model.device)
        self.c = torch.zeros(L, B, H, device=model.device)
        self.queued_from = torch.full((B,), -1, dtype=torch.long, device=model.device)  # first step not yet taken, or -1
        self.scale, self.shift = model.change_scale.to(torch.float64), model.change_shift.to(torch.float64)

    def same_prior(self, other: "_Rows") -> bool:
        """Whether this network's prior computes the same changes as ``other``'s."""
        a, b = self.model, other.model
        same_geometry = (self.geometry is None and other.geometry is None) or (
            self.geometry is not None and other.geometry is not None and torch.equal(self.geometry, other.geometry))
        return same_geometry and (a.config.model.prior, a.prior_dt, a.prior_friction, a.prior_gravity,
                                  a.config.model.contact_substeps) == (
            b.config.model.prior, b.prior_dt, b.prior_friction, b.prior_gravity, b.config.model.contact_substeps)

    def changes(self, t: int, v32: torch.Tensor, w32: torch.Tensor, q: torch.Tensor | None, fed: torch.Tensor,
                turns: torch.Tensor | None, prior: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Step t's changes (B, 12) float64 SI, and the prior's (B, 1, 12) (given: not computed again)."""
        model = self.model
        if not model.uses_orientation:
            q, turns = None, None
        moving = model.rest_gate(v32, w32)
        B = v32.shape[0]
        need = torch.ones(B, dtype=torch.bool, device=v32.device) if moving is None else moving[:, 0]
        rows = need.nonzero()[:, 0]
        net = torch.zeros(B, 1, 12, device=v32.device)
        if len(rows):
            self._take_queued(rows, t, fed, turns)
            inputs = model.network_inputs(self.feature[rows], v32[rows], w32[rows], None if q is None else q[rows])
            features, (self.h[:, rows], self.c[:, rows]) = model.predictor(inputs, (self.h[:, rows], self.c[:, rows]))
            net[rows] = model.head(features)[0]
        self.queued_from = torch.where(~need & (self.queued_from < 0), t, self.queued_from)
        if prior is None:
            prior = model.analytic_prior(v32, w32, q, self.geometry)
        out = net if prior is None else model.with_residual(net, prior, moving)
        return out[:, 0].to(torch.float64) * self.scale + self.shift, prior

    def _take_queued(self, rows: torch.Tensor, t: int, fed: torch.Tensor, turns: torch.Tensor | None) -> None:
        """Run the LSTM of ``rows`` over the inputs they queued before step t (steps queued_from..t-1), in
        one call per first queued step, and mark their queues empty."""
        model, queued_from, h, c = self.model, self.queued_from, self.h, self.c
        behind = rows[queued_from[rows] >= 0]
        for first in torch.unique(queued_from[behind]).tolist():
            group = behind[queued_from[behind] == first]
            span = fed[group, first:t].float()
            q = None if turns is None else turns[group, first:t]
            inputs = model.network_inputs(self.feature[group], span[..., :3], span[..., 3:], q)
            state = (h[:, group], c[:, group])
            for k in range(inputs.shape[1]):  # step by step, as the steps that needed the network ran
                _, state = model.predictor(inputs[:, k : k + 1], state)
            h[:, group], c[:, group] = state
        queued_from[rows] = -1
