"""The paper's relative loss, by hand, including the zero-change guard."""

from __future__ import annotations

import math

import pytest
import torch

from physdyn.models.optimizer import learning_rate_factor
from physdyn.models.losses import dynamics_loss, relative_error


def _example():
    # B = 1, T = 2; order of the 12 changes: dv, dw, dp, dtheta
    true = torch.zeros(1, 2, 12)
    pred = torch.zeros(1, 2, 12)
    true[0, 0, 0:3] = torch.tensor([3.0, 4.0, 0.0])  # |x| = 5, prediction 0 -> 5 / 5 = 1
    true[0, 1, 0:3] = torch.tensor([1.0, 0.0, 0.0])
    pred[0, 1, 0:3] = torch.tensor([2.0, 0.0, 0.0])  # 1 / (1 + 2) = 1/3
    true[0, 0, 3:6] = torch.tensor([0.0, 2.0, 0.0])
    pred[0, 0, 3:6] = torch.tensor([0.0, 2.0, 0.0])  # exact: 0
    true[0, 1, 3:6] = torch.tensor([0.0, 0.0, 1.0])
    pred[0, 1, 3:6] = torch.tensor([0.0, 0.0, -1.0])  # 2 / (1 + 1) = 1
    true[0, :, 6:9] = torch.tensor([0.0, 0.0, 0.0])  # resting: absolute error
    pred[0, 0, 6:9] = torch.tensor([0.0, 0.0, 0.0])  # 0
    pred[0, 1, 6:9] = torch.tensor([0.3, 0.0, 0.4])  # |.| = 0.5
    true[0, 0, 9:12] = torch.tensor([1.0, -1.0, 0.0])  # L1: |(0, 2, 0)|_1 / (2 + 2) = 0.5
    pred[0, 0, 9:12] = torch.tensor([1.0, 1.0, 0.0])
    true[0, 1, 9:12] = torch.tensor([0.0, 0.0, 2.0])
    pred[0, 1, 9:12] = torch.tensor([1.0, 0.0, 1.0])  # L1: |(1, 0, -1)|_1 / (2 + 2) = 0.5
    return pred, true


def test_relative_loss_matches_hand_computed_values():
    pred, true = _example()
    logit = torch.tensor([[0.0, 2.0]])
    label = torch.tensor([[1.0, 0.0]])
    out = dynamics_loss(pred, true, logit, label, eps=0.0, rest_threshold=1e-3)
    expected = {
        "linear_velocity": (1.0 + 1 / 3) / 2,
        "angular_velocity": (0.0 + 1.0) / 2,
        "position": (0.0 + 0.5) / 2,
        "rotation": (0.5 + 0.5) / 2,
        "topple": (math.log(2.0) + math.log(1 + math.exp(2.0))) / 2,
    }
    for key, value in expected.items():
        assert out.terms[key].item() == pytest.approx(value, rel=1e-6), key
    total = sum(expected[k] for k in ("linear_velocity", "angular_velocity", "position", "rotation")) + 2.0 * expected["topple"]
    assert out.total.item() == pytest.approx(total, rel=1e-6)


def test_weights_and_absolute_variant():
    pred, true = _example()
    out = dynamics_loss(pred, true, kind="absolute", weights={"position": 3.0})
    assert out.terms["linear_velocity"].item() == pytest.approx((5.0 + 1.0) / 2)
    assert out.terms["angular_velocity"].item() == pytest.approx((0.0 + 2.0) / 2)
    assert out.terms["position"].item() == pytest.approx(0.25)
    assert out.terms["rotation"].item() == pytest.approx((2.0 + 2.0) / 2)  # L1
    assert "topple" not in out.terms  # no topple head
    assert out.total.item() == pytest.approx(3.0 + 1.0 + 3 * 0.25 + 2.0)


def test_zero_change_guard_makes_resting_steps_learnable():
    zero = torch.zeros(4, 3)
    # the unguarded paper formula: 0/0 on a correctly predicted resting step
    assert torch.isnan(relative_error(zero.clone(), zero, eps=0.0, rest_threshold=0.0)).all()
    # guarded: a correct resting prediction costs 0 ...
    assert relative_error(zero.clone(), zero).abs().max().item() == 0.0
    # ... and a wrong one, small or large, costs its size with a unit gradient towards 0
    for size in (1e-2, 0.5, 20.0):
        pred = torch.tensor([[size, 0.0, 0.0]], requires_grad=True)
        err = relative_error(pred, torch.zeros(1, 3))
        assert err.item() == pytest.approx(size)
        err.sum().backward()
        assert pred.grad[0, 0].item() == pytest.approx(1.0)
    # the unguarded formula gives the constant 1 and no gradient there: nothing to learn
    pred = torch.tensor([[0.5, 0.0, 0.0]], requires_grad=True)
    err = relative_error(pred, torch.zeros(1, 3), eps=0.0, rest_threshold=0.0)
    err.sum().backward()
    assert err.item() == pytest.approx(1.0) and pred.grad.abs().max().item() == 0.0
    # a moving step keeps the paper's relative error, whatever the guard
    x = torch.tensor([[0.0, 0.2, 0.0]])
    assert relative_error(torch.tensor([[0.0, 0.1, 0.0]]), x).item() == pytest.approx(0.1 / 0.3, rel=1e-4)


def test_learning_rate_decays_to_lr_min_and_never_below():
    total = 1000
    factors = [learning_rate_factor("exponential", s, total, 1e-3, 1e-5) for s in range(0, 1500, 50)]
    assert factors[0] == 1.0
    assert learning_rate_factor("exponential", total, total, 1e-3, 1e-5) == pytest.approx(1e-2)
    assert min(factors) == pytest.approx(1e-2) and all(a >= b for a, b in zip(factors, factors[1:]))
    # the paper's: x0.75 every 300,000 sequences at batch 64
    every = 300_000 / 64
    assert learning_rate_factor("step", int(every) - 1, math.inf, 1e-3, 1e-5, 0.75, every) == 1.0
    assert learning_rate_factor("step", int(2 * every) + 1, math.inf, 1e-3, 1e-5, 0.75, every) == pytest.approx(0.75**2)
    assert learning_rate_factor("step", 10**9, math.inf, 1e-3, 1e-5, 0.75, every) == pytest.approx(1e-2)


def test_position_drift_sums_the_per_step_position_errors():
    targets = torch.zeros(1, 4, 12)
    changes = torch.zeros(1, 4, 12)
    changes[..., 6] = 0.01  # 1 cm too far in x every step: 1, 2, 3, 4 cm of drift
    changes[0, 2, 6] = -0.01  # ... except a step back: 1, 2, 1, 2
    out = dynamics_loss(changes, targets, kind="huber", weights={"position_drift": 3.0}, huber_delta=0.015)
    drift = torch.tensor([0.01, 0.02, 0.01, 0.02])
    huber = torch.where(drift < 0.015, 0.5 * drift**2 / 0.015, drift - 0.0075)
    assert out.terms["position_drift"].item() == pytest.approx(huber.mean().item(), rel=1e-6)
    plain = dynamics_loss(changes, targets, kind="huber", huber_delta=0.015)
    assert "position_drift" not in plain.terms  # the paper's loss by default
    assert out.total.item() == pytest.approx(plain.total.item() + 3.0 * huber.mean().item(), rel=1e-6)
