"""One object's roll-out on numpy arrays and Python numbers: ``DynamicsNetwork.rollout_changes`` for B = 1.

A roll-out of one object calls the network once per recorded step on tensors of a few hundred numbers,
where each torch operation costs a few microseconds of dispatch, more than its arithmetic: ~150 of them
made a step cost ~0.6 ms, a 3 s prediction ~30 ms, about what simulating the object costs. Here the same
step is written out on numpy (the LSTM cells' matrix products, in float32 like the module) and on Python
numbers (velocities, orientation, the contact prior), a few tens of microseconds per step.

It covers the components the shipped models use, the ``lstm`` predictor (and ``none``: the contact prior
alone, ``contact_prior_predictor()``) and the ``topple`` / ``no_topple`` heads, with any encoder (the shape
is encoded once, in torch) and any prior, one network or two (a model with ``linear_channels``: each
network keeps its own state, the prior is shared); ``SingleRollout.supports``
says whether a model qualifies, and ``DynamicsNetwork.rollout_changes`` falls back to the torch loop when it
does not. Its numbers equal the torch loop's to float32 rounding (``tests/models/test_single_rollout.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from scipy.special import expit

from physdyn.models.heads.topple import NoToppleHead, ToppleHead
from physdyn.models.predictors.lstm import LSTMPredictor
from physdyn.models.predictors.none import NoPredictor
from physdyn.models.priors import RESIDUAL_MASKS, _contact_changes_one, prior_changes


LINEAR = np.array(RESIDUAL_MASKS["linear"]) > 0  # the changes a combined model takes from its second network


def _rotation_6d(x: float, y: float, z: float, w: float) -> list[float]:
    """``physdyn.models.rotations.rotation_6d`` of one quaternion on Python numbers."""
    n = max(math.sqrt(x * x + y * y + z * z + w * w), 1e-12)
    x, y, z, w = x / n, y / n, z / n, w / n
    return [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w),
            2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)]


def _compose(rx: float, ry: float, rz: float, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Exp(r) * q, normalised: ``quat_multiply(rotvec_to_quat(r), q)`` on Python numbers."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    s = 0.5 - angle * angle / 48.0 if angle < 1e-4 else math.sin(0.5 * angle) / angle
    ax, ay, az, aw = rx * s, ry * s, rz * s, math.cos(0.5 * angle)
    bx, by, bz, bw = q
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    w = aw * bw - ax * bx - ay * by - az * bz
    n = math.sqrt(x * x + y * y + z * z + w * w)
    return x / n, y / n, z / n, w / n


class _Network:
    """One network's weights as numpy arrays, and its part of a step: LSTM, head, prior, rest gate."""

    def __init__(self, model: Any):
        f = lambda t: t.detach().cpu().numpy().astype(np.float32)  # noqa: E731
        self.varying = 6 + (6 if model.uses_orientation else 0)  # inputs that change per step; then the shape
        # Per layer one matrix for [input, h] and one bias (b_ih + b_hh): one product and one sum per step.
        # The `none` predictor has no layer: its features are empty and the head outputs its bias.
        self.layers = []
        lstm = getattr(model.predictor, "lstm", None)
        for layer in range(0 if lstm is None else model.predictor.config.num_layers):
            w_ih, w_hh = f(getattr(lstm, f"weight_ih_l{layer}")), f(getattr(lstm, f"weight_hh_l{layer}"))
            bias = f(getattr(lstm, f"bias_ih_l{layer}")) + f(getattr(lstm, f"bias_hh_l{layer}"))
            self.layers.append((np.concatenate([w_ih.T, w_hh.T]), bias))
        self.head_weight = f(model.head.linear.weight).T.copy()
        self.head_bias = f(model.head.linear.bias)
        self.residual_mask = f(model.residual_mask)  # model.residual_channels
        self.hidden = 0 if lstm is None else int(model.predictor.config.hidden)
        self.velocity_shift = f(model.velocity_shift)
        self.velocity_scale = f(model.velocity_scale)
        self.change_scale32, self.change_shift32 = f(model.change_scale), f(model.change_shift)
        self.change_scale = model.change_scale.detach().cpu().numpy().astype(np.float64)
        self.change_shift = model.change_shift.detach().cpu().numpy().astype(np.float64)
        self.encoder_width = int(model.encoder.out_dim)
        m = model.config.model
        self.prior, self.gate_linear, self.gate_angular = m.prior, float(m.residual_gate_linear), float(m.residual_gate_angular)
        self.gated = self.prior != "none" and (self.gate_linear > 0 or self.gate_angular > 0)
        self.uses_shape_prior = model.uses_shape_prior
        self.predicts_topple = model.predicts_topple
        self.prior_args = (model.prior_dt, model.prior_friction, model.prior_gravity)
        self.substeps = int(m.contact_substeps)
        # With no layer the head reads empty features: its output is its bias at every step, computed once
        # as a step computes it (the prior alone: nothing fed to a network, nothing queued)
        self.bias_out = None if self.layers else np.zeros(0, np.float32) @ self.head_weight + self.head_bias
        self.bias_step = None if self.layers else self.bias_out[:12] * self.residual_mask
        # ... and where that output is zero and the changes are not scaled (contact_prior_predictor, `fast`), a
        # step's changes are the prior's, float32 as the sum would round them (zeros' signs apart)
        self.prior_only = (model.changes_are_the_prior()
                           and not self.change_shift.any() and (self.change_scale == 1.0).all()
                           and not self.change_shift32.any() and (self.change_scale32 == 1.0).all())

    def start(self, code: np.ndarray) -> None:
        """A roll-out of the shape ``code`` (this network's part of the shape code) begins."""
        shape, self.geometry = code[: self.encoder_width], code[self.encoder_width:].tolist()
        self.run_layers = []
        if self.layers:  # the shape's part of the first layer's input is the same at every step: multiply it once
            weight0, bias0 = self.layers[0]
            n, m = self.varying, self.varying + len(shape)
            self.run_layers = [(np.concatenate([weight0[:n], weight0[m:]]), shape @ weight0[n:m] + bias0)] + self.layers[1:]
        self.h = [np.zeros(self.hidden, np.float32) for _ in self.layers]
        self.c = [np.zeros(self.hidden, np.float32) for _ in self.layers]
        self.queued: list[np.ndarray] = []

    def prior_key(self) -> tuple:
        return (self.prior, self.uses_shape_prior, tuple(self.geometry), self.prior_args, self.substeps)

    def _lstm(self, x: np.ndarray) -> np.ndarray:
        if not self.run_layers:  # no network: empty features
            return np.zeros(0, np.float32)
        H, h, c = self.hidden, self.h, self.c
        for layer, (weight, bias) in enumerate(self.run_layers):
            gates = np.concatenate([x, h[layer]]) @ weight + bias
            s = expit(gates)
            c[layer] = s[H : 2 * H] * c[layer] + s[:H] * np.tanh(gates[2 * H : 3 * H])
            x = h[layer] = s[3 * H :] * np.tanh(c[layer])
        return x

    def step(self, vw32: np.ndarray, q32: list[float] | None, topple: bool,
             prior: np.ndarray | None = None) -> tuple[np.ndarray, float | None, np.ndarray | None]:
        """One step from the velocities fed (float32) and the orientation since step 0 -> (the changes SI
        (12,) float64, the head's topple probability or None, the prior's changes SI float32 or None).
        ``prior``: the prior's changes when another network computed the same ones."""
        v32, w32 = vw32[:3].tolist(), vw32[3:].tolist()
        moving = not self.gated or (math.hypot(v32[0], v32[1]) > self.gate_linear
                                    or math.sqrt(w32[0] ** 2 + w32[1] ** 2 + w32[2] ** 2) > self.gate_angular)
        probability = None
        if self.prior_only and not topple:
            prior = self._prior(v32, w32, q32) if prior is None else prior
            return prior.astype(np.float64), None, prior
        if self.bias_out is not None:  # no network to feed
            step = self.bias_step if moving else np.zeros(12, np.float32)
            if topple:
                probability = 1.0 / (1.0 + math.exp(-float(self.bias_out[12])))
        elif moving or topple:
            x = self._input(vw32, q32)
            for queued_x in self.queued:
                self._lstm(queued_x)
            self.queued.clear()
            out = self._lstm(x) @ self.head_weight + self.head_bias
            step = out[:12] * self.residual_mask if moving else np.zeros(12, np.float32)
            if topple:
                probability = 1.0 / (1.0 + math.exp(-float(out[12])))
        else:  # below the rest gate: the input waits for the next step that needs the network
            self.queued.append(self._input(vw32, q32))
            step = np.zeros(12, np.float32)
        if self.prior != "none":
            if prior is None:
                prior = self._prior(v32, w32, q32)
            step = step + (prior - self.change_shift32) / self.change_scale32
        return step.astype(np.float64) * self.change_scale + self.change_shift, probability, prior

    def _input(self, vw32: np.ndarray, q32: list[float] | None) -> np.ndarray:
        """The network's input at a step: the velocities fed, standardised, and the orientation's 6D form."""
        x = (vw32 - self.velocity_shift) / self.velocity_scale
        if self.varying > 6:
            x = np.concatenate([x, np.array(_rotation_6d(*q32), np.float32)])
        return x

    def _prior(self, v32: list[float], w32: list[float], q32: list[float] | None) -> np.ndarray:
        if self.uses_shape_prior:
            return np.array(_contact_changes_one(v32, w32, q32, self.geometry, *self.prior_args, self.substeps), np.float32)
        out = prior_changes(self.prior, torch.tensor(v32), torch.tensor(w32), *self.prior_args)
        return out.numpy()


class SingleRollout:
    """The weights of a ``DynamicsNetwork`` as numpy arrays, and its roll-out for one object; of a model
    combining two networks (``linear_channels``), both, the velocity and position changes from the second.

    Build it with ``SingleRollout.of(model)``, once per roll-out."""

    def __init__(self, model: Any):
        self.model = model
        self.nets = [_Network(model)] + ([] if model.linear_channels is None else [_Network(model.linear_channels)])
        self.predicts_topple = model.predicts_topple

    @staticmethod
    def supports(model: Any) -> bool:
        """Whether this roll-out reproduces ``model``'s: LSTM predictors (or none: the prior alone), linear
        heads, on the CPU."""
        parts = [model] + ([] if model.linear_channels is None else [model.linear_channels])
        return all(type(m.predictor) in (LSTMPredictor, NoPredictor) and type(m.head) in (ToppleHead, NoToppleHead)
                   and m.device.type == "cpu" and (m.uses_orientation or not m.uses_shape_prior) for m in parts)

    @classmethod
    def of(cls, model: Any) -> "SingleRollout":
        # Built afresh for each roll-out (~0.2 ms of a ~5 ms prediction): a cache keyed on the tensors'
        # versions missed weights assigned through ``.data`` and the model's prior settings.
        return cls(model)

    def run(self, feature: torch.Tensor, v0: np.ndarray, w0: np.ndarray, steps: int,
            warm_v: np.ndarray | None, warm_w: np.ndarray | None, topple: bool = True,
            warm_turn: np.ndarray | None = None) -> dict[str, np.ndarray | None]:
        """feature (1, F) from ``DynamicsNetwork.encode``; v0, w0 (3,) float64; warm_* (K, 3) or None (warm_turn
        (K, 4): the rotations since step 0 at steps 1..K, fed with those velocities) ->
        the arrays of ``rollout_changes`` for one sequence: changes (1, S, 12), fed (1, S, 6), topple (1, S)
        (None with ``topple=False``, when the caller does not use the head's probabilities).

        Below the rest gate the network's changes are not used: without topple probabilities to report,
        such a step only queues its input, and the LSTM takes the queue before the next step that needs it
        (the same states, in the same order); a roll-out that ends at rest never runs it for its tail."""
        for net, (_, part) in zip(self.nets, self.model.network_codes(feature[0:1])):
            net.start(part[0].detach().cpu().numpy().astype(np.float32))
        shared = len(self.nets) > 1 and self.nets[0].prior_key() == self.nets[1].prior_key()
        v, w = [float(x) for x in v0], [float(x) for x in w0]
        turn = (0.0, 0.0, 0.0, 1.0)
        K = 0 if warm_v is None else len(warm_v)
        changes = np.empty((steps, 12))
        fed = np.empty((steps, 6))
        topple = np.empty(steps) if self.predicts_topple and topple else None
        tracks_turn = self.nets[0].varying > 6
        # With no recurrent state (the prior alone) a step is a function of the state it is fed: once that
        # repeats exactly (at rest, a quarter of the frontier's steps), every later step repeats it
        stateless = topple is None and not any(net.layers for net in self.nets)
        previous = None
        for t in range(steps):
            if 1 <= t <= K:
                v, w = [float(x) for x in warm_v[t - 1]], [float(x) for x in warm_w[t - 1]]
                if warm_turn is not None:
                    turn = tuple(float(x) for x in warm_turn[t - 1])
            if stateless and t > K:
                if (v, w, turn) == previous:
                    changes[t:], fed[t:] = changes[t - 1], fed[t - 1]
                    break
                previous = (v, w, turn)
            fed[t, :3], fed[t, 3:] = v, w
            vw32 = np.array(v + w, np.float32)  # the module is fed float32
            q32 = np.array(turn, np.float32).tolist() if tracks_turn else None
            si, probability, prior = self.nets[0].step(vw32, q32, topple is not None)
            if len(self.nets) > 1:  # velocity and position from the linear channels' network
                linear = self.nets[1].step(vw32, q32, False, prior if shared else None)[0]
                si[LINEAR] = linear[LINEAR]
            changes[t] = si
            if topple is not None:
                topple[t] = probability
            d = si.tolist()
            if tracks_turn:  # R_{t+1} R_0^T = Exp(dtheta_t) R_t R_0^T, as the pose is integrated
                turn = _compose(d[9], d[10], d[11], turn)
            v = [v[0] + d[0], v[1] + d[1], v[2] + d[2]]
            w = [w[0] + d[3], w[1] + d[4], w[2] + d[5]]
        return {"changes": changes[None], "fed": fed[None], "topple_probability": None if topple is None else topple[None]}


def single_rollout(model: Any, points: Any, linear_velocity0: Any, angular_velocity0: Any, steps: int, warm_linear: Any = None,
                   warm_angular: Any = None, spin_inertia: Any = None, topple: bool = True,
                   warm_turn: Any = None) -> dict[str, torch.Tensor | None]:
    """``DynamicsNetwork.rollout_changes`` for one object (``SingleRollout.supports(model)``), through that
    method: the same arguments and results as ``physdyn.models.batch_rollout.batch_rollout``."""
    feature = model.encode(torch.as_tensor(points, dtype=torch.float32, device=model.device), spin_inertia)
    as64 = lambda x: None if x is None else np.asarray(torch.as_tensor(x).cpu(), np.float64)  # noqa: E731
    warm_v, warm_w = as64(warm_linear), as64(warm_angular)
    out = SingleRollout.of(model).run(feature, as64(linear_velocity0).reshape(3), as64(angular_velocity0).reshape(3),
                                      steps, None if warm_v is None else warm_v[0], None if warm_w is None else warm_w[0],
                                      topple, None if warm_turn is None else as64(warm_turn)[0])
    return {k: None if x is None else torch.from_numpy(x) for k, x in out.items()}
