"""A batch of the prior alone on numpy (``physdyn.models.prior_rollout``) gives the one-object roll-out's numbers
and the torch loop's to float32 rounding, ends at rest, and takes a friction per sequence."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from physdyn.data.normalization import compute_normalization
from physdyn.data.store import load_store
from physdyn.data.windows import world_oriented_points
from physdyn.eval.evaluate import gather_truth, select_sequences
from physdyn.models import batch_rollout as batch_rollout_module
from physdyn.models import prior_rollout as prior_rollout_module
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.prior_rollout import prior_rollout

STEPS = 60


@pytest.fixture(scope="module")
def store(tiny_store):
    return load_store(tiny_store)


@pytest.fixture
def prior_model(quickstart_config, store):
    # `fast`'s motion: the contact prior alone, 8 sub-steps a step, no residual
    model = DynamicsModel(quickstart_config("model.predictor.name=none", "model.head.name=no_topple", "model.prior=contact",
                                            "model.orientation_input=true", "model.contact_substeps=8"),
                          compute_normalization(store, np.arange(store.num_sims)), {"rate_hz": store.rate_hz, "friction": 0.25}).eval()
    with torch.no_grad():
        model.head.linear.weight.zero_()
        model.head.linear.bias.zero_()
    assert model.changes_are_the_prior()
    return model


@pytest.fixture(scope="module")
def starts(store):
    sims = select_sequences(store, "test")[:8]
    truth = gather_truth(store, sims)
    points = world_oriented_points(store.points[store.shape_id[sims]], truth["orientation_xyzw"][:, 0]).astype(np.float32)
    return points, truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0]


def test_a_batch_equals_one_object_roll_outs_and_the_torch_loop(prior_model, starts, monkeypatch):
    points, v0, w0 = starts
    batch = prior_model.rollout_changes(points, v0, w0, STEPS, topple=False)
    moved = np.abs(batch["changes"][:, :, 6:8].numpy()).sum(axis=(1, 2))
    assert (moved > 0.05).sum() >= 4  # the pushes slide: the roll-outs are not trivially zero
    for b in range(len(points)):
        one = prior_model.rollout_changes(points[b : b + 1], v0[b : b + 1], w0[b : b + 1], STEPS, topple=False)
        for key in ("changes", "fed"):
            # the one-object roll-out feeds its prior float32 velocities, this one float64
            np.testing.assert_allclose(batch[key][b].numpy(), one[key][0].numpy(), rtol=0, atol=1e-6, err_msg=key)
    monkeypatch.setattr(batch_rollout_module, "PRIOR_ON_NUMPY", False)
    loop = prior_model.rollout_changes(points, v0, w0, STEPS, topple=False)
    for key in ("changes", "fed"):
        np.testing.assert_allclose(batch[key].numpy(), loop[key].numpy(), rtol=0, atol=1e-4, err_msg=key)


def test_the_roll_out_stops_stepping_once_every_sequence_rests(prior_model, starts, monkeypatch):
    points, v0, w0 = starts
    calls = []
    substeps = prior_rollout_module._substeps
    monkeypatch.setattr(prior_rollout_module, "_substeps", lambda *a: calls.append(len(a[1])) or substeps(*a))
    out = prior_model.rollout_changes(points, v0, w0, 400, topple=False)
    fed = out["fed"].numpy()
    last = max(np.flatnonzero(np.abs(fed[b]).max(axis=1) > 0).max() for b in range(len(fed)))
    assert len(calls) <= last + 1 < 400  # no sub-steps past the last moving step
    assert (fed[:, last + 1 :] == 0).all() and (out["changes"].numpy()[:, last + 1 :] == 0).all()


def test_a_friction_per_sequence_equals_separate_roll_outs(prior_model, starts):
    points, v0, w0 = starts
    geometry = prior_model.split_code(prior_model.encode_points(points))[1].double().numpy()
    mu = np.linspace(0.15, 0.45, len(points))
    args = (prior_model.prior_dt, None, prior_model.prior_gravity, prior_model.config.model.contact_substeps)
    together = prior_rollout(geometry, v0, w0, STEPS, args[0], mu, *args[2:])
    for b in range(len(points)):
        alone = prior_rollout(geometry[b : b + 1], v0[b : b + 1], w0[b : b + 1], STEPS, args[0], mu[b], *args[2:])
        np.testing.assert_allclose(together["changes"][b], alone["changes"][0], rtol=0, atol=1e-12)
    travel = np.abs(together["changes"][:, :, 6:8]).sum(axis=(1, 2))
    slow = np.linalg.norm(v0[:, :2], axis=1) > 0.3
    # more friction, a shorter slide: the friction is used, per sequence
    low = prior_rollout(geometry, v0, w0, STEPS, args[0], 0.15, *args[2:])
    assert (np.abs(low["changes"][:, :, 6:8]).sum(axis=(1, 2))[slow] >= travel[slow] - 1e-12).all()
    assert (travel[slow][1:] < np.abs(low["changes"][:, :, 6:8]).sum(axis=(1, 2))[slow][1:]).any()
