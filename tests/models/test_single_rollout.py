"""One object's roll-out on numpy (``physdyn.models.single_rollout``) gives the torch loop's numbers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from physdyn.data.normalization import compute_normalization
from physdyn.data.store import load_store
from physdyn.data.windows import world_oriented_points
from physdyn.eval.evaluate import gather_truth, select_sequences
from physdyn.models import batch_rollout as batch_rollout_module
from physdyn.models.batch_rollout import batch_rollout
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.single_rollout import SingleRollout

RECIPES = [
    # the shipped recipe: contact prior fed the orientation, rest gate, topple head
    ["model.prior=contact", "model.orientation_input=true", "model.residual_gate_linear=0.1",
     "model.residual_gate_angular=1.0"],
    ["model.prior=planar", "data.normalization=std_inputs"],
    ["model.prior=none", "model.head.name=no_topple"],
    ["model.prior=contact", "model.orientation_input=true", "model.residual_channels=linear"],
    # no network: the contact prior alone (contact_prior_predictor), its head's bias the only residual
    ["model.predictor.name=none", "model.head.name=no_topple", "model.prior=contact", "model.orientation_input=true",
     "model.residual_gate_linear=0.1", "model.residual_gate_angular=1.0"],
    ["model.predictor.name=none", "model.head.name=topple", "model.prior=contact", "model.orientation_input=true"],
    # the shipped fast model's prior: 8 sub-steps a recorded step
    ["model.predictor.name=none", "model.head.name=no_topple", "model.prior=contact", "model.orientation_input=true",
     "model.contact_substeps=8"],
]


@pytest.fixture(scope="module")
def store(tiny_store):
    return load_store(tiny_store)


def _model(quickstart_config, store, overrides) -> DynamicsModel:
    # Seeded: the two paths differ by float32 rounding, which a closed loop can grow (the torch loop at
    # B = 1 and B = 2 differs by up to 5e-5 over 45 steps of the bundled model); these weights stay below 1e-5.
    torch.manual_seed(0)
    model = DynamicsModel(quickstart_config(*overrides), compute_normalization(store, np.arange(store.num_sims)),
                          {"rate_hz": store.rate_hz, "friction": 0.25}).eval()
    with torch.no_grad():  # a residual that matters (a model with a prior starts with it at zero)
        model.head.linear.weight.normal_(0.0, 0.05)
        model.head.linear.bias.normal_(0.0, 0.05)
    return model


def _first_state(store, sim):
    truth = gather_truth(store, np.array([sim]))
    points = world_oriented_points(store.points[store.shape_id[[sim]]], truth["orientation_xyzw"][:, 0]).astype(np.float32)
    return points, truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0], truth


@pytest.mark.parametrize("overrides", RECIPES, ids=lambda o: " ".join(o))
def test_one_object_rollout_equals_the_torch_loop(quickstart_config, store, overrides):
    model = _model(quickstart_config, store, overrides)
    assert SingleRollout.supports(model)
    for sim in select_sequences(store, "test")[:3]:
        points, v0, w0, truth = _first_state(store, sim)
        warm = (torch.as_tensor(truth["linear_velocity"][:, 1:3]), torch.as_tensor(truth["angular_velocity"][:, 1:3]))
        for warm_v, warm_w in ((None, None), warm):
            fast = model.rollout_changes(points, v0, w0, 25, warm_v, warm_w)  # B = 1: the numpy roll-out
            with torch.inference_mode():
                slow = batch_rollout(model, points, v0, w0, 25, warm_v, warm_w)  # the torch loop
            for key in ("changes", "fed", "topple_probability"):
                if slow[key] is None:
                    assert fast[key] is None
                    continue
                np.testing.assert_allclose(fast[key].numpy(), slow[key].numpy(), rtol=1e-5, atol=1e-5, err_msg=key)
            # without the head's probabilities, steps below the rest gate queue their LSTM input instead
            queued = model.rollout_changes(points, v0, w0, 25, warm_v, warm_w, topple=False)
            assert queued["topple_probability"] is None
            np.testing.assert_allclose(queued["changes"].numpy(), slow["changes"].numpy(), rtol=1e-5, atol=1e-5)

    moved = fast["changes"][0, :, 6:9].sum(0).norm()
    assert moved > 1e-2  # it slid: not a trivial match of two zero roll-outs



def test_the_roll_out_follows_a_changed_model(quickstart_config, store):
    model = _model(quickstart_config, store, RECIPES[1])
    points, v0, w0, _ = _first_state(store, int(select_sequences(store, "test")[0]))
    before = model.rollout_changes(points, v0, w0, 10)["changes"].clone()
    # an optimiser step changes parameters in place; EMA or vector_to_parameters assign through .data
    with torch.no_grad():
        model.head.linear.bias.add_(0.1)
    model.head.linear.weight.data = model.head.linear.weight.data * 3.0
    after = model.rollout_changes(points, v0, w0, 10)["changes"]
    with torch.inference_mode():
        reference = batch_rollout(model, points, v0, w0, 10, None, None)["changes"]
    assert not torch.allclose(before, after)
    np.testing.assert_allclose(after.numpy(), reference.numpy(), rtol=1e-5, atol=1e-5)


def test_other_predictors_take_the_torch_loop(quickstart_config, store):
    model = _model(quickstart_config, store, ["model.predictor.name=mlp", "model.predictor.params.num_layers=2"])
    assert not SingleRollout.supports(model)
    points, v0, w0, _ = _first_state(store, int(select_sequences(store, "test")[0]))
    out = model.rollout_changes(points, v0, w0, 5)
    assert out["changes"].shape == (1, 5, 12) and torch.isfinite(out["changes"]).all()


def test_contact_inertia_body_spins_the_prior_with_the_given_inertia(quickstart_config, store):
    from physdyn.data.windows import store_spin_inertia

    sims = select_sequences(store, "test")[:4]
    truth = gather_truth(store, sims)
    points = store.points[store.shape_id[sims]]
    q0, v0, w0 = truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0]
    exact = store_spin_inertia(store, sims, q0)
    body = _model(quickstart_config, store, RECIPES[0] + ["model.contact_inertia=body"])
    points_model = _model(quickstart_config, store, RECIPES[0] + ["model.contact_inertia=points"])
    column = -2  # the code ends with I_zz / m and the height of the centre of mass
    world = world_oriented_points(points, q0).astype(np.float32)
    np.testing.assert_allclose(body.encode_points(world, exact)[:, column].numpy(), exact, rtol=1e-6)
    estimate = points_model.encode_points(world)[:, column].numpy()
    assert not np.allclose(estimate, exact, rtol=0.02)  # the cloud's estimate is another number
    np.testing.assert_allclose(points_model.encode_points(world, exact)[:, column].numpy(), estimate)  # "points" ignores it
    unknown = np.array([np.nan, 0.0, exact[2], exact[3]])  # no usable mass properties: the estimate
    np.testing.assert_allclose(body.encode_points(world, unknown)[:, column].numpy(), [*estimate[:2], *exact[2:]], rtol=1e-6)
    # training windows carry it for the window's first step, as roll-outs get it for step 0
    from physdyn.data.windows import WindowSource

    starts = np.array([0, 3, 5, 0])
    window = WindowSource(store, 5).gather(sims, starts)
    first = store.start[sims] + np.minimum(starts, store.lengths()[sims] - 1)
    np.testing.assert_allclose(window["spin_inertia"], store_spin_inertia(store, sims, store.orientation_xyzw[first]), rtol=1e-6)
    # a roll-out with the body's inertia: batched and one object at a time alike
    from physdyn.eval.rollout import RolloutOptions, rollout

    batch = rollout(body, points, q0, truth["com_position"][:, 0], v0, w0, 20, RolloutOptions(spin_inertia=exact))
    one = rollout(body, points[:1], q0[:1], truth["com_position"][:1, 0], v0[:1], w0[:1], 20, RolloutOptions(spin_inertia=exact[:1]))
    np.testing.assert_allclose(one.com_position, batch.com_position[:1], atol=1e-5)
    plain = rollout(body, points[:1], q0[:1], truth["com_position"][:1, 0], v0[:1], w0[:1], 20)
    assert np.abs(plain.delta_rotation - one.delta_rotation).max() > 1e-4  # the inertia changed the spin


def test_steps_below_the_rest_gate_queue_the_lstm_and_give_the_same_roll_out(quickstart_config, store):
    # Without topple probabilities a step below the gate only queues its input: the LSTM takes the queue
    # when the object moves again (here: at rest at step 0, pushed by the warm-start velocities at step 1)
    # and never for a tail at rest. The roll-out must equal the torch loop's either way.
    model = _model(quickstart_config, store, RECIPES[0])
    sim = int(select_sequences(store, "test")[0])
    points, v0, w0, truth = _first_state(store, sim)
    warm = (torch.as_tensor(truth["linear_velocity"][:, 1:3]), torch.as_tensor(truth["angular_velocity"][:, 1:3]))
    with torch.no_grad():  # a small residual that still depends on the LSTM's state; the slide ends
        model.head.linear.weight.mul_(0.05)
        model.head.linear.bias.zero_()
    for start_v, start_w, warm_v, warm_w in ((np.zeros((1, 3)), np.zeros((1, 3))) + warm, (v0, w0, None, None)):
        queued = model.rollout_changes(points, start_v, start_w, 40, warm_v, warm_w, topple=False)
        with torch.inference_mode():
            slow = batch_rollout(model, points, start_v, start_w, 40, warm_v, warm_w)
        np.testing.assert_allclose(queued["changes"].numpy(), slow["changes"].numpy(), rtol=1e-5, atol=1e-5)
        fed = slow["fed"][0].numpy()
        resting = (np.linalg.norm(fed[:, :2], axis=1) < 0.1) & (np.linalg.norm(fed[:, 3:], axis=1) < 1.0)
        assert resting[0] if warm_v is not None else resting[-5:].all()  # the gate did close where meant
        assert not resting[1:].all()


def test_a_batch_runs_the_network_on_moving_sequences_only_and_gives_the_same_roll_out(quickstart_config, store):
    # The batched torch loop without topple probabilities: sequences below the rest gate queue their input
    # (one at rest at step 0 and pushed at step 1 takes its queue then), the network runs on the rest only.
    model = _model(quickstart_config, store, RECIPES[0])
    with torch.no_grad():
        model.head.linear.weight.mul_(0.05)
        model.head.linear.bias.zero_()
    sims = select_sequences(store, "test")[:3]
    truth = gather_truth(store, sims)
    points = world_oriented_points(store.points[store.shape_id[sims]], truth["orientation_xyzw"][:, 0]).astype(np.float32)
    v0, w0 = truth["linear_velocity"][:, 0].copy(), truth["angular_velocity"][:, 0].copy()
    v0[0], w0[0] = 0.0, 0.0  # the first one rests two steps, until the warm start pushes it at step 2
    warm_v, warm_w = torch.as_tensor(truth["linear_velocity"][:, 1:3]), torch.as_tensor(truth["angular_velocity"][:, 1:3])
    warm_v[0, 0], warm_w[0, 0] = 0.0, 0.0
    rows_seen = []
    hook = model.predictor.register_forward_hook(lambda module, args, out: rows_seen.append(tuple(args[0].shape[:2])))
    try:
        with torch.inference_mode():
            skipping = batch_rollout(model, points, v0, w0, 40, warm_v, warm_w, topple=False)
            calls = list(rows_seen)
            every = batch_rollout(model, points, v0, w0, 40, warm_v, warm_w, topple=True)
    finally:
        hook.remove()
    assert skipping["topple_probability"] is None and every["topple_probability"] is not None
    np.testing.assert_allclose(skipping["changes"].numpy(), every["changes"].numpy(), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(skipping["fed"].numpy(), every["fed"].numpy(), rtol=1e-5, atol=1e-5)
    # steps 0 and 1 run the two moving ones; at step 2 the pushed one first takes its two queued steps, one at
    # a time, then all three run
    assert calls[:5] == [(2, 1), (2, 1), (1, 1), (1, 1), (3, 1)]
    assert len(calls) < 40 and sum(b for b, _ in calls) < 3 * 40 / 2  # steps with all at rest run nothing


def test_the_prior_alone_repeats_its_state_at_rest_as_the_torch_loop_steps_it(quickstart_config, store, monkeypatch):
    # The prior alone has no recurrent state: once a step is fed the state of the step before, the roll-out
    # repeats it to its end instead of stepping (SingleRollout.run); the torch loop steps every one.
    from physdyn.models import single_rollout

    model = _model(quickstart_config, store, RECIPES[-1])
    with torch.no_grad():  # as contact_prior_predictor: no residual (a constant one would never let it rest)
        model.head.linear.weight.zero_()
        model.head.linear.bias.zero_()
    stepped = []
    step = single_rollout._Network.step
    monkeypatch.setattr(single_rollout._Network, "step", lambda self, *a, **k: stepped.append(1) or step(self, *a, **k))
    repeated = 0
    for sim in select_sequences(store, "test"):
        points, v0, w0, _ = _first_state(store, sim)
        stepped.clear()
        fast = model.rollout_changes(points, v0, w0, 150, None, None, topple=False)
        with torch.inference_mode():
            slow = batch_rollout(model, points, v0, w0, 150, None, None)
        for key in ("changes", "fed"):
            np.testing.assert_allclose(fast[key].numpy(), slow[key].numpy(), rtol=1e-5, atol=1e-5, err_msg=key)
        fed = fast["fed"][0].numpy()
        if len(stepped) < 150:  # it stopped stepping: from there on each step repeats the one before, to the bit
            repeated += 1
            assert (fed[len(stepped):] == fed[len(stepped) - 1]).all() and np.abs(fed[0, :3]).max() > 0.1
    assert repeated >= 3  # most pushes' states settle exactly (some keep a 1e-45 m/s flicker, and are stepped)


@pytest.mark.parametrize("head", ["topple", "no_topple"])
def test_a_batch_of_the_prior_alone_skips_the_network_with_the_same_numbers(quickstart_config, store, head, monkeypatch):
    # A batch of the prior alone (contact_prior_predictor, `fast`) takes the prior's changes without the
    # model's forward (DynamicsModel.changes_are_the_prior); the forward, which runs the empty network and adds its zero
    # residual, gives the same numbers to the bit, the head's constant topple probability included.
    torch.manual_seed(0)  # standardised changes (a shift and a scale per channel) and a non-zero topple logit
    model = DynamicsModel(quickstart_config("model.predictor.name=none", f"model.head.name={head}", "model.prior=contact",
                                            "model.orientation_input=true", "model.residual_gate_linear=0.1"),
                          compute_normalization(store, np.arange(store.num_sims), mode="std"),
                          {"rate_hz": store.rate_hz, "friction": 0.25}).eval()
    with torch.no_grad():
        model.head.linear.bias.normal_(0.0, 1.0)
        model.head.linear.bias[:12] = 0.0
    assert model.changes_are_the_prior() and model.change_shift.abs().min() > 0
    sims = select_sequences(store, "test")[:6]
    states = [_first_state(store, sim) for sim in sims] * 4  # 24 rows: torch's vectorised kernels take them
    points = np.concatenate([s[0] for s in states])
    v0 = np.concatenate([s[1] for s in states])
    w0 = np.concatenate([s[2] for s in states])
    warm_v = torch.as_tensor(np.stack([s[3]["linear_velocity"][0, 1:3] for s in states]))
    warm_w = torch.as_tensor(np.stack([s[3]["angular_velocity"][0, 1:3] for s in states]))

    def refuse(*args, **kwargs):
        raise AssertionError("the forward ran")

    # the torch loop's alone branch (without a warm start the CPU takes physdyn.models.prior_rollout instead)
    monkeypatch.setattr(batch_rollout_module, "PRIOR_ON_NUMPY", False)
    for warm in ((None, None), (warm_v, warm_w)):
        with torch.inference_mode():
            with monkeypatch.context() as patch:
                patch.setattr(DynamicsModel, "forward", refuse)
                skipped = batch_rollout(model, points, v0, w0, 30, *warm)
            with monkeypatch.context() as patch:
                patch.setattr(DynamicsModel, "changes_are_the_prior", lambda self: False)
                forward = batch_rollout(model, points, v0, w0, 30, *warm)
        for key in ("changes", "fed", "topple_probability"):
            if forward[key] is None:
                assert skipped[key] is None and head == "no_topple"
                continue
            np.testing.assert_array_equal(skipped[key].numpy(), forward[key].numpy(), err_msg=key)
        assert skipped["changes"][:, :, 6:9].sum(1).norm(dim=-1).min() > 0  # every push moved
    if head == "topple":  # the constant probability over many logits: torch's sigmoid kernels differ in a few
        for logit in torch.randn(64):
            with torch.no_grad():
                model.head.linear.bias[12] = logit
            with torch.inference_mode():
                skipped = batch_rollout(model, points, v0, w0, 2)
                with monkeypatch.context() as patch:
                    patch.setattr(DynamicsModel, "changes_are_the_prior", lambda self: False)
                    forward = batch_rollout(model, points, v0, w0, 2)
            np.testing.assert_array_equal(skipped["topple_probability"].numpy(), forward["topple_probability"].numpy())
    with torch.no_grad():  # a residual, however small, is a network's: the forward runs
        model.head.linear.bias[0] = 1e-3
    assert not model.changes_are_the_prior()
