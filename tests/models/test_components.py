"""Registered encoders, predictors and heads: shapes, the paper's sizes, and step-by-step use."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from physdyn.registry import ENCODERS, HEADS, PREDICTORS


def test_built_ins_are_registered():
    assert "pointnet" in ENCODERS.names()
    assert {"lstm", "mlp"} <= set(PREDICTORS.names())
    assert {"topple", "no_topple"} <= set(HEADS.names())


def test_paper_sized_model_has_the_papers_layers():
    enc = ENCODERS.build("pointnet", {})
    convs = [m for m in enc.point_mlp if isinstance(m, nn.Conv1d)]
    fcs = [m for m in enc.fc if isinstance(m, nn.Linear)]
    assert [c.out_channels for c in convs] == [64, 64, 64, 128, 1024]
    assert [f.out_features for f in fcs] == [1024, 512, 128, 32, 16]
    bns = [m for m in enc.modules() if isinstance(m, nn.BatchNorm1d)]
    assert len(bns) == 10 and all(b.momentum == 0.1 and b.eps == 1e-3 for b in bns)
    lstm = PREDICTORS.build("lstm", {}, input_dim=6 + enc.out_dim)
    head = HEADS.build("topple", {}, in_dim=lstm.out_dim)
    n = sum(p.numel() for m in (enc, lstm, head) for p in m.parameters())
    assert 22.5e6 < n < 23.3e6  # the paper's model: 22.9 M
    h = 1024
    for name, p in lstm.lstm.named_parameters():
        if name.startswith("bias"):
            total_forget = p[h : 2 * h]
            assert torch.all(total_forget == (1.0 if "ih" in name else 0.0))


def test_encoder_without_batch_norm_and_feature_shape():
    enc = ENCODERS.build("pointnet", {"point_widths": [8, 16], "fc_widths": [16], "feature_size": 5, "batch_norm": False})
    assert not any(isinstance(m, nn.BatchNorm1d) for m in enc.modules())
    pts = torch.randn(3, 40, 3)
    out = enc(pts)
    assert out.shape == (3, 5) and (out >= 0).all()  # ReLU after the last layer, as in the paper
    # a symmetric function of the points: their order does not matter
    assert torch.allclose(enc(pts[:, torch.randperm(40)]), out, atol=1e-6)


@pytest.mark.parametrize("name", ["lstm", "mlp"])
def test_predictor_whole_window_equals_step_by_step(name):
    torch.manual_seed(0)
    pred = PREDICTORS.build(name, {"num_layers": 2, "hidden": 16}, input_dim=7).eval()
    x = torch.randn(2, 6, 7)
    whole, _ = pred(x)
    state = None
    steps = []
    for t in range(6):
        out, state = pred(x[:, t : t + 1], state)
        steps.append(out)
    assert whole.shape == (2, 6, 16)
    assert torch.allclose(torch.cat(steps, dim=1), whole, atol=1e-6)


def test_lstm_remembers_and_mlp_does_not():
    torch.manual_seed(0)
    x = torch.randn(1, 5, 7)
    y = x.clone()
    y[:, 0] += 1.0  # change only the first step's input
    for name, memory in (("lstm", True), ("mlp", False)):
        pred = PREDICTORS.build(name, {"num_layers": 2, "hidden": 16}, input_dim=7)
        later_changed = not torch.allclose(pred(x)[0][:, 1:], pred(y)[0][:, 1:])
        assert later_changed == memory, name


def test_heads():
    f = torch.randn(2, 4, 16)
    changes, logit = HEADS.build("topple", {}, in_dim=16)(f)
    assert changes.shape == (2, 4, 12) and logit.shape == (2, 4)
    changes, logit = HEADS.build("no_topple", {}, in_dim=16)(f)
    assert changes.shape == (2, 4, 12) and logit is None
