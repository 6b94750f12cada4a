"""The network: shape encoder + state predictor + head, and its analytic prior (its roll-outs:
``batch_rollout``, ``single_rollout``; its training loss: ``network_loss``).

Inputs and outputs of the public methods are in SI units; the network normalises with the scales it was
trained with (kept in its hyper-parameters with its config, so a checkpoint restores it:
``physdyn.eval.baselines.load_checkpoint``).

``DynamicsNetwork`` is plain torch: predicting, evaluating and fitting a correction or a classifier load a
checkpoint into it without importing Lightning, which took 5 of a fresh ``physdyn predict`` process's
11.6 s (docs/predict.md). ``physdyn.models.dynamics_module.DynamicsModel`` is the same network as the
LightningModule that ``physdyn fit`` trains.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, MutableMapping

import numpy as np
import torch

from physdyn.config import ExperimentConfig, config_from_dict, to_dict
from physdyn.data.normalization import Normalization
from physdyn.data.windows import DELTA_KEYS
from physdyn.models.batch_rollout import LINEAR, batch_rollout
from physdyn.models.encoder_weights import load_encoder_weights
from physdyn.models.heads.base import NUM_CHANGES
from physdyn.models.heads.topple import NoToppleHead, ToppleHead
from physdyn.models.linear_channels import check_combinable
from physdyn.models.network_loss import network_loss
from physdyn.models.predictors.none import NoPredictor
from physdyn.models.priors import RESIDUAL_MASKS, SHAPE_PRIORS, contact_changes, contact_geometry, prior_changes
from physdyn.models.rotations import rotation_6d
from physdyn.models.single_rollout import SingleRollout, single_rollout
from physdyn.registry import ENCODERS, HEADS, PREDICTORS


@dataclass
class DynamicsPrediction:
    """Predicted changes from step t to t+1, SI units, world frame.

    delta_linear_velocity, delta_angular_velocity, delta_position, delta_rotation: (B, T, 3) for
    ``predict_window`` or (B, 3) for ``step``; ``delta_rotation`` is world-frame axis-angle
    (R_{t+1} = Exp(delta_rotation) R_t). topple_probability: (B, T) or (B,), None without a topple head.
    state: the predictor's recurrent state after the last step (pass it to the next call).
    """

    delta_linear_velocity: torch.Tensor
    delta_angular_velocity: torch.Tensor
    delta_position: torch.Tensor
    delta_rotation: torch.Tensor
    topple_probability: torch.Tensor | None
    state: Any = None

    def to_numpy(self) -> dict[str, np.ndarray | None]:
        out: dict[str, np.ndarray | None] = {k: getattr(self, k).detach().cpu().numpy() for k in DELTA_KEYS}
        tp = self.topple_probability
        out["topple_probability"] = None if tp is None else tp.detach().cpu().numpy()
        return out


@contextlib.contextmanager
def _inference(module: torch.nn.Module):
    """Eval mode (batch norm uses its running statistics) and no gradients; restores the previous mode."""
    was_training = module.training
    if was_training:  # a roll-out calls this every step: leave an eval-mode module alone
        module.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        if was_training:
            module.train()


class DynamicsNetwork(torch.nn.Module):
    """Predicts per-step state changes and topple probabilities of a pushed rigid object.

    config: an ``ExperimentConfig`` or its dict; normalization: a ``Normalization`` or its dict (from the
    training split); data_info: facts about the training data evaluation code needs (``rate_hz``,
    ``window``, ``num_points``, ``category_names``, ``store``).
    """

    def __init__(self, config: dict | ExperimentConfig, normalization: dict | Normalization, data_info: dict | None = None):
        super().__init__()
        cfg = config if isinstance(config, ExperimentConfig) else config_from_dict(ExperimentConfig, config)
        norm = normalization if isinstance(normalization, Normalization) else Normalization.from_dict(normalization)
        self._keep_hyperparameters({"config": to_dict(cfg), "normalization": norm.to_dict(), "data_info": dict(data_info or {})})
        self.config = cfg
        self.normalization = norm
        m = cfg.model
        self.encoder = ENCODERS.build(m.encoder.name, m.encoder.params, "model.encoder.params")
        input_dim = 6 + (6 if m.orientation_input else 0) + int(self.encoder.out_dim)
        self.predictor = PREDICTORS.build(m.predictor.name, m.predictor.params, "model.predictor.params", input_dim=input_dim)
        self.head = HEADS.build(m.head.name, m.head.params, "model.head.params", in_dim=int(self.predictor.out_dim))
        if m.prior != "none" and isinstance(getattr(self.head, "linear", None), torch.nn.Linear):
            # A residual model starts as its prior (the residual layer at zero) and learns only what improves
            # on it; from random weights it starts as the prior plus noise that training must first remove.
            with torch.no_grad():
                self.head.linear.weight.zero_()
                self.head.linear.bias.zero_()
        f32 = lambda x: torch.tensor(x, dtype=torch.float32)  # noqa: E731
        self.register_buffer("change_scale", f32(norm.change_scales()))
        self.register_buffer("change_shift", f32(norm.change_shifts()))
        self.register_buffer("velocity_scale", f32(norm.input_scales()))
        self.register_buffer("velocity_shift", f32(norm.input_shifts()))
        self.register_buffer("point_scale", f32(norm.points))
        self.loss_config = cfg.loss
        info = dict(data_info or {})
        # The prior's step and friction are the training data's (a random-friction store: its median).
        self.prior_dt = 1.0 / float(info.get("rate_hz", 15.0))
        self.prior_friction = float(info.get("friction", 0.25))
        self.prior_gravity = float(info.get("gravity", 9.81))
        # The channels [dv, dw, dp, dtheta] the network's residual corrects (model.residual_channels); not
        # saved: the config rebuilds it.
        self.register_buffer("residual_mask", f32(RESIDUAL_MASKS[m.residual_channels]), persistent=False)
        # Another DynamicsNetwork whose velocity and position changes replace this one's, both networks fed
        # the same state (`python -m physdyn.models.export --linear-from`); None: this model alone.
        self.linear_channels = None

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        state = checkpoint.get("state_dict", {})  # from before per-channel normalisation: no shift buffers, shift zero
        for name in ("change_shift", "velocity_shift"):
            state.setdefault(name, torch.zeros_like(getattr(self, name)))
            if checkpoint.get("linear_channels"):
                state.setdefault(f"linear_channels.{name}", torch.zeros_like(getattr(self, name)))
        if checkpoint.get("linear_channels"):  # its weights are in the state dict, under linear_channels.
            self.attach_linear_channels(type(self)(**checkpoint["linear_channels"]["hyper_parameters"]))

    def on_save_checkpoint(self, checkpoint: dict) -> None:  # the other network's weights are in the state dict
        if self.linear_channels is not None:
            checkpoint["linear_channels"] = {"hyper_parameters": dict(self.linear_channels.hparams)}

    def attach_linear_channels(self, model: "DynamicsNetwork") -> None:
        """Take the velocity and position changes from ``model`` from now on (see ``linear_channels``); a
        one-line ``ConfigError`` where the two cannot be combined (``check_combinable``)."""
        check_combinable(self, model)
        self.linear_channels = model.to(self.device)

    def _keep_hyperparameters(self, values: dict) -> None:
        """Keep what rebuilds this network (``hparams``; a checkpoint's ``hyper_parameters``)."""
        self._hyperparameters = values

    @property
    def hparams(self) -> MutableMapping[str, Any]:
        """The config, normalisation and data facts it was built from (a checkpoint's ``hyper_parameters``)."""
        return self._hyperparameters

    @property
    def device(self) -> torch.device:
        return self.change_scale.device

    # ------------------------------------------------------------------ facts
    @property
    def predicts_topple(self) -> bool:
        return bool(self.head.predicts_topple)

    @property
    def uses_orientation(self) -> bool:
        """Whether ``forward``/``step`` need the orientation relative to step 0 (``model.orientation_input``)."""
        return bool(self.config.model.orientation_input)

    @property
    def data_info(self) -> dict:
        return dict(self.hparams.get("data_info", {}))

    @property
    def num_points(self) -> int | None:
        """Points per cloud the model was trained on (None: all of its store's)."""
        return self.config.data.num_points

    # ------------------------------------------------------------------ network
    @property
    def uses_shape_prior(self) -> bool:
        return self.config.model.prior in SHAPE_PRIORS

    def changes_are_the_prior(self) -> bool:
        """Whether this network's changes are its analytic prior's: no layer (the ``none`` predictor) and a
        linear head whose change outputs are zero (after its residual mask). Both roll-outs then skip the
        network (``contact_prior_predictor()``, ``fast``); a model with ``linear_channels`` asks each network."""
        if (type(self.predictor) is not NoPredictor or self.config.model.prior == "none"
                or type(self.head) not in (ToppleHead, NoToppleHead)):
            return False
        return self.head.linear.in_features == 0 and not bool((self.head.linear.bias[:NUM_CHANGES] * self.residual_mask).any())

    def encode(self, points: torch.Tensor, spin_inertia: torch.Tensor | None = None) -> torch.Tensor:
        """points: (B, N, 3) world-oriented body frame, metres -> (B, F') shape code: the encoder's feature,
        followed, for a prior that reads the shape (``model.prior=contact``), by its footprint geometry.
        spin_inertia: (B,) the body's I_zz / m about the world vertical, used by ``model.contact_inertia=body``
        instead of the cloud's estimate. Callers treat the code as opaque and hand it back to
        ``forward``/``step``."""
        if self.predictor.out_dim == 0:
            # No network reads the feature (``model.predictor: none``, the contact prior alone): zeros of its
            # width keep the code's layout, and a new mesh's prediction does not pay for the encoder.
            feature = points.new_zeros(len(points), int(self.encoder.out_dim))
        else:
            feature = self.encoder(points / self.point_scale)
        if self.uses_shape_prior:
            geometry = contact_geometry(points, footprint=self.config.model.contact_footprint)
            feature = self._with_spin_inertia(torch.cat([feature, geometry], dim=1), spin_inertia)
        if self.linear_channels is not None:  # then the other network's code
            feature = torch.cat([feature, self.linear_channels.encode(points, spin_inertia)], dim=1)
        return feature

    def with_spin_inertia(self, code: torch.Tensor, spin_inertia: Any) -> torch.Tensor:
        """A shape code from ``encode`` with the contact prior's spin inertia replaced by the body's (B,),
        where ``model.contact_inertia=body`` and the caller knows it; otherwise the code as it is."""
        if self.linear_channels is None:
            return self._with_spin_inertia(code, spin_inertia)
        (_, own), (other, theirs) = self.network_codes(code)
        return torch.cat([self._with_spin_inertia(own, spin_inertia), other.with_spin_inertia(theirs, spin_inertia)], dim=1)

    def network_codes(self, code: torch.Tensor) -> list[tuple["DynamicsNetwork", torch.Tensor]]:
        """A shape code from ``encode`` -> [(network, its part of the code)]: this model's, and for a model
        combining two (``linear_channels``) the other's after it."""
        other = self.linear_channels
        if other is None:
            return [(self, code)]
        widths = (int(self.encoder.out_dim), int(other.encoder.out_dim))
        shaped = (int(self.uses_shape_prior), int(other.uses_shape_prior))
        # each part: its encoder's feature, then the footprint geometry (one width for both: the same cloud)
        geometry = (code.shape[1] - sum(widths)) // max(sum(shaped), 1)
        width = widths[0] + geometry * shaped[0]
        return [(self, code[:, :width]), (other, code[:, width:])]

    def _with_spin_inertia(self, code: torch.Tensor, spin_inertia: Any) -> torch.Tensor:
        if spin_inertia is None or not self.uses_shape_prior or self.config.model.contact_inertia != "body":
            return code
        column = code.shape[1] - 2  # contact_geometry ends with I_zz / m and the height of the centre of mass
        value = torch.as_tensor(spin_inertia, dtype=code.dtype, device=code.device).reshape(-1, 1)
        estimate = code[:, column : column + 1]
        # a store or mesh without usable mass properties (NaN, zero) keeps the cloud's estimate
        value = torch.where(torch.isfinite(value) & (value > 0), value.clamp_min(1e-8), estimate)
        return torch.cat([code[:, :column], value, code[:, column + 1 :]], dim=1)

    def forward(self, feature: torch.Tensor, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, state: Any = None,
                orientation: torch.Tensor | None = None):
        """feature (B, F); velocities (B, T, 3) SI, world frame; orientation (B, T, 4) xyzw, the rotation since
        the point cloud's orientation (only with ``model.orientation_input``)
        -> (changes (B, T, 12) normalised [dv, dw, dp, dtheta], topple logit (B, T) or None, state)."""
        if self.linear_channels is not None:
            return self._combined(feature, linear_velocity, angular_velocity, state, orientation)
        return self._alone(feature, linear_velocity, angular_velocity, state, orientation)

    def _alone(self, code: torch.Tensor, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, state: Any,
               orientation: torch.Tensor | None):
        """``forward`` of this network alone: ``code`` its own part of the shape code."""
        feature, geometry = self.split_code(code)
        inputs = self.network_inputs(feature, linear_velocity, angular_velocity, orientation)
        features, state = self.predictor(inputs, state)
        changes, logit = self.head(features)
        prior = self.analytic_prior(linear_velocity, angular_velocity, orientation, geometry)
        if prior is not None:  # the network predicts the residual to the analytic prior
            changes = self.with_residual(changes, prior, self.rest_gate(linear_velocity, angular_velocity))
        return changes, logit, state

    def _combined(self, code: torch.Tensor, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, state: Any,
                  orientation: torch.Tensor | None):
        """``forward`` of a model with ``linear_channels``: both networks on the same state, each with its own
        recurrent state; velocity and position changes from the other, spin, rotation and topple from this."""
        (_, own), (other, other_code) = self.network_codes(code)
        own_state, other_state = (None, None) if state is None else state
        changes, logit, own_state = self._alone(own, linear_velocity, angular_velocity, own_state, orientation)
        theirs, _, other_state = other(other_code, linear_velocity, angular_velocity, other_state,
                                       orientation if other.uses_orientation else None)
        theirs = (theirs * other.change_scale + other.change_shift - self.change_shift) / self.change_scale
        changes = torch.where(LINEAR.to(changes.device), theirs, changes)
        return changes, logit, (own_state, other_state)

    def split_code(self, code: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """This network's part of a shape code (``network_codes``; of a model of one network, the whole code)
        -> (the encoder's feature, the contact prior's geometry or None)."""
        if not self.uses_shape_prior:
            return code, None
        width = int(self.encoder.out_dim)
        return code[:, :width], code[:, width:]

    def network_inputs(self, feature: torch.Tensor, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor,
                        orientation: torch.Tensor | None) -> torch.Tensor:
        """The predictor's input (B, T, D): normalised velocities, the orientation since step 0 (6D) for
        ``model.orientation_input``, the shape feature."""
        T = linear_velocity.shape[1]
        parts = [(torch.cat([linear_velocity, angular_velocity], dim=-1) - self.velocity_shift) / self.velocity_scale]
        if self.uses_orientation:
            if orientation is None:
                raise ValueError("this model takes the orientation relative to step 0 (model.orientation_input)")
            parts.append(rotation_6d(orientation))
        return torch.cat(parts + [feature[:, None, :].expand(-1, T, -1)], dim=-1)

    def analytic_prior(self, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor, orientation: torch.Tensor | None,
               geometry: torch.Tensor | None) -> torch.Tensor | None:
        """The analytic prior's changes (B, T, 12) SI, or None without a prior."""
        if geometry is not None:
            return contact_changes(linear_velocity, angular_velocity, orientation, geometry, self.prior_dt,
                                   self.prior_friction, self.prior_gravity, self.config.model.contact_substeps)
        return prior_changes(self.config.model.prior, linear_velocity, angular_velocity, self.prior_dt,
                             self.prior_friction, self.prior_gravity)

    def rest_gate(self, linear_velocity: torch.Tensor, angular_velocity: torch.Tensor) -> torch.Tensor | None:
        """(B, T) bool: above the residual's rest gate, where the network's changes count; None without a gate."""
        m = self.config.model
        if m.prior == "none" or (m.residual_gate_linear <= 0 and m.residual_gate_angular <= 0):
            return None
        return ((linear_velocity[..., :2].norm(dim=-1) > m.residual_gate_linear)
                | (angular_velocity.norm(dim=-1) > m.residual_gate_angular))

    def with_residual(self, changes: torch.Tensor, prior: torch.Tensor, moving: torch.Tensor | None) -> torch.Tensor:
        """The network's normalised changes as a residual on the prior's (SI): their sum, normalised.
        ``moving``: ``rest_gate`` of the velocities fed (None: no gate)."""
        if moving is not None:
            # Near rest the prior's stop is exact (below 0.1 m/s a slide ends within one 1/15 s step)
            # and the residual only adds drift: below both speeds the prediction is the prior's.
            changes = changes * moving.unsqueeze(-1).to(changes.dtype)
        if self.config.model.residual_channels != "all":
            changes = changes * self.residual_mask
        return changes + (prior - self.change_shift) / self.change_scale

    def _as_tensor(self, x: Any) -> torch.Tensor:
        return torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x, dtype=torch.float32, device=self.device)

    def _prediction(self, changes: torch.Tensor, logit: torch.Tensor | None, state: Any) -> DynamicsPrediction:
        si = changes * self.change_scale + self.change_shift
        return DynamicsPrediction(
            si[..., 0:3], si[..., 3:6], si[..., 6:9], si[..., 9:12],
            None if logit is None else torch.sigmoid(logit), state,
        )

    def predict_window(self, points: Any, linear_velocity: Any, angular_velocity: Any, state: Any = None,
                       orientation: Any = None, spin_inertia: Any = None) -> DynamicsPrediction:
        """Changes at every step given the true velocities at every step (teacher forcing).

        points: (B, N, 3) world-oriented body frame at the first step (see
        ``physdyn.data.windows.world_oriented_points``); velocities: (B, T, 3) SI, world frame; orientation:
        (B, T, 4) xyzw rotation since the first step (models with ``orientation_input`` only); spin_inertia
        (B,) as for ``encode``. Runs in eval mode without gradients; arrays or tensors in, tensors out.
        """
        with _inference(self):
            feature = self.encode(self._as_tensor(points), spin_inertia)
            q = None if orientation is None else self._as_tensor(orientation)
            changes, logit, state = self(feature, self._as_tensor(linear_velocity), self._as_tensor(angular_velocity), state, q)
            return self._prediction(changes, logit, state)

    def step(self, feature: torch.Tensor, linear_velocity: Any, angular_velocity: Any, state: Any = None,
             orientation: Any = None) -> DynamicsPrediction:
        """One roll-out step: feature (B, F) from ``encode``; velocities (B, 3) at step t; orientation (B, 4)
        the rotation since step 0 (``orientation_input`` models); state from the previous step (None at step 0)
        -> changes to step t+1, each (B, 3), and the new state."""
        with _inference(self):
            v = self._as_tensor(linear_velocity)[:, None, :]
            w = self._as_tensor(angular_velocity)[:, None, :]
            q = None if orientation is None else self._as_tensor(orientation)[:, None, :]
            changes, logit, state = self(self._as_tensor(feature), v, w, state, q)
            pred = self._prediction(changes[:, 0], None if logit is None else logit[:, 0], state)
            return pred

    def encode_points(self, points: Any, spin_inertia: Any = None) -> torch.Tensor:
        """``encode`` in eval mode without gradients, for roll-outs: (B, N, 3) -> (B, F)."""
        with _inference(self):
            return self.encode(self._as_tensor(points), spin_inertia)

    def rollout_changes(self, points: torch.Tensor, linear_velocity0: torch.Tensor, angular_velocity0: torch.Tensor,
                        steps: int, warm_linear: torch.Tensor | None = None,
                        warm_angular: torch.Tensor | None = None, spin_inertia: Any = None,
                        topple: bool = True, warm_turn: Any = None) -> dict[str, torch.Tensor | None]:
        """A whole roll-out in torch, in eval and inference mode: one shape encoding, then ``steps`` calls of
        the network on its own velocities, without numpy between steps (physdyn.models.batch_rollout).

        points (B, N, 3) world-oriented body frame of step 0; linear/angular_velocity0 (B, 3) SI; warm_*
        (B, K, 3): the true velocities of steps 1..K, fed instead of the model's own, and warm_turn (B, K, 4)
        optionally the rotations since step 0 at those steps (xyzw), fed instead of the integrated ones to a
        model fed its orientation (``model.sim_seconds``' simulated start); spin_inertia (B,) as for
        ``encode``; topple=False: the head's probabilities are not wanted (a topple classifier replaces
        them), so ``topple_probability`` is None. Velocities and the
        orientation since step 0 are carried in float64 (as ``physdyn.eval.rollout.rollout`` documents),
        fed in float32. Returns ``changes`` (B, S, 12) float64 SI [dv, dw, dp, dtheta], ``fed`` (B, S, 6) the
        velocities fed at each step, ``topple_probability`` (B, S) (the label of step t+1) or None.
        """
        was_training = self.training
        if was_training:  # eval() walks every submodule: leave an eval-mode model alone
            self.eval()
        try:
            with torch.inference_mode():
                args = (points, linear_velocity0, angular_velocity0, steps, warm_linear, warm_angular, spin_inertia)
                if len(points) == 1 and SingleRollout.supports(self):
                    return single_rollout(self, *args, topple=topple, warm_turn=warm_turn)
                return batch_rollout(self, *args, topple=topple, warm_turn=warm_turn)
        finally:
            if was_training:
                self.train()

    # ------------------------------------------------------------------ training and initialisation
    def compute_loss(self, batch: dict[str, torch.Tensor]):
        """The training loss of a batch of windows (``physdyn.models.network_loss``)."""
        return network_loss(self, batch)

    def load_encoder_weights(self, path: str | Path) -> int:
        """Copy the matching tensors of an encoder file from `physdyn pretrain` (``physdyn.models.encoder_weights``)."""
        return load_encoder_weights(self, path)
