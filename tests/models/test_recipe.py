"""The training-recipe levers of docs/research/training-recipe.md: each one's config path, its maths, and a tiny
run that learns."""

from __future__ import annotations

import math

import lightning
import numpy as np
import pytest
import torch

from physdyn.data.datamodule import DynamicsDataModule
from physdyn.data.normalization import compute_normalization
from physdyn.data.store import load_store
from physdyn.data.windows import WindowSource, frame_targets, turned_about_vertical
from physdyn.errors import ConfigError
from physdyn.eval.baselines import coulomb_slide
from physdyn.eval.evaluate import evaluate, gather_truth
from physdyn.eval.rollout import RolloutOptions, rollout, teacher_forced
from physdyn.models.network_loss import closed_loop
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.rotations import rotation_6d
from physdyn.models.priors import contact_changes, contact_geometry, prior_changes
from physdyn.models.training import fit, load_experiment_config
from tests.models.conftest import QUICKSTART, shrunk_overrides

LEVERS = [
    ["data.normalization=std"],
    ["rollout.input_noise=0.02"],
    ["rollout.feedback=1.0"],
    ["rollout.feedback=0.5", "rollout.input_noise=0.01"],
    ["data.first_window_fraction=0.5"],
    ["loss.kind=huber"],
    ["model.orientation_input=true"],
    ["model.prior=kinematic"],
    ["model.prior=coulomb", "model.orientation_input=true", "data.normalization=std"],
    ["model.prior=planar", "data.normalization=std_inputs", "rollout.feedback=1.0"],
    ["model.prior=contact", "model.orientation_input=true", "rollout.feedback=1.0", "loss.kind=huber"],
    ["model.prior=contact", "model.orientation_input=true", "model.contact_inertia=body"],
    ["model.prior=planar", "model.residual_gate_linear=0.1", "model.residual_gate_angular=1.0"],
    ["model.prior=contact", "model.orientation_input=true", "data.yaw_augment=true"],
    ["model.prior=contact", "model.orientation_input=true", "model.residual_channels=linear"],
    ["model.prior=contact", "model.orientation_input=true", "model.contact_footprint=area"],
]


@pytest.fixture(scope="module")
def store(tiny_store):
    return load_store(tiny_store)


# The shipped recipe's prior in the default run; every other lever with the tests marked slow (CI runs them):
# the default suite stays near its 3 minutes
DEFAULT_LEVERS = (["model.prior=contact", "model.orientation_input=true", "model.contact_inertia=body"],
                  ["model.prior=contact", "model.orientation_input=true", "model.residual_channels=linear"])


@pytest.mark.parametrize("overrides", [pytest.param(o, marks=() if o in DEFAULT_LEVERS else pytest.mark.slow)
                                       for o in LEVERS], ids=lambda o: " ".join(o))
def test_every_lever_trains_reloads_and_rolls_out_through_evaluation(quickstart_config, store, overrides):
    result = fit(quickstart_config(*overrides))
    assert math.isfinite(result.metrics["train/loss"]) and math.isfinite(result.metrics["best_val_loss"])
    model = DynamicsModel.load_from_checkpoint(result.last_checkpoint)
    for item in overrides:
        key, value = item.split("=")
        section, name = key.split(".")
        saved = getattr(getattr(model.config, section), name)
        assert str(saved).lower() == value.lower(), (key, saved)
    report = evaluate(model, store, split="test")  # roll-out and teacher forcing, orientation fed where used
    assert math.isfinite(report["headline"]["final_position_m_median"])


def test_unknown_choices_are_one_line_config_errors(tiny_store, tmp_path):
    for bad, key in (("model.prior=newton", "model.prior"), ("data.normalization=minmax", "data.normalization"),
                     ("loss.kind=l2", "loss.kind"), ("rollout.feedback=1.5", "rollout.feedback"),
                     ("rollout.input_noise=-0.1", "rollout.input_noise"), ("data.first_window_fraction=2", "data.first_window_fraction"),
                     ("model.contact_footprint=corners", "model.contact_footprint"),
                     ("model.sim_seconds=-0.1", "model.sim_seconds"), ("model.sim_seconds=10", "model.sim_seconds"),
                     ("model.contact_substeps=0", "model.contact_substeps")):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")) as info:
            load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path, bad))
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("prior", ["coulomb", "planar"])
def test_sliding_prior_alone_rolls_out_exactly_the_coulomb_sliding_baseline(quickstart_config, store, prior):
    # A model whose network outputs nothing: its roll-out is its prior's, step by step. Coulomb sliding in
    # closed form (the baseline) must come out, to float32 precision, including the stop within a step.
    # A fresh model with a prior starts as the prior: its residual layer is zero (nothing zeroed here).
    model = DynamicsModel(quickstart_config(f"model.prior={prior}"),
                          compute_normalization(store, np.arange(store.num_sims)), {"rate_hz": 15.0, "friction": 0.25})
    assert not model.head.linear.weight.any() and not model.head.linear.bias.any()
    B = 4
    rng = np.random.default_rng(0)
    v0 = np.concatenate([rng.uniform(-2, 2, (B, 2)), np.zeros((B, 1))], axis=1)
    w0 = np.zeros((B, 3))
    p0, q0 = np.zeros((B, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (B, 1))
    points = store.points[store.shape_id[:B]]
    ours = rollout(model, points, q0, p0, v0, w0, steps=30)
    slide = coulomb_slide(p0, q0, v0, w0, 30, 0.25, 15.0)
    np.testing.assert_allclose(ours.com_position, slide.com_position, atol=2e-5)
    np.testing.assert_allclose(ours.linear_velocity[:, 1:], slide.linear_velocity[:, 1:], atol=2e-5)
    if prior == "planar":  # a spin given at step 0 has stopped by the step the slide stops
        spun = rollout(model, points, q0, p0, v0, np.tile([0.3, 0.0, 5.0], (B, 1)), steps=30)
        stopped = np.linalg.norm(slide.linear_velocity[:, -1], axis=-1) < 1e-9
        assert stopped.all()
        np.testing.assert_allclose(spun.angular_velocity[:, -1], 0.0, atol=1e-4)
        np.testing.assert_allclose(spun.angular_velocity[:, 1, :2], 0.0, atol=1e-6)


def test_priors_are_kinematics_and_coulomb_deceleration():
    v = torch.tensor([[3.0, 4.0, 0.1]])
    w = torch.tensor([[0.0, 1.0, 2.0]])
    kin = prior_changes("kinematic", v, w, dt=0.1, friction=0.25)
    assert torch.allclose(kin[0, 0:6], torch.zeros(6))
    assert torch.allclose(kin[0, 6:9], v[0] * 0.1) and torch.allclose(kin[0, 9:12], w[0] * 0.1)
    c = prior_changes("coulomb", v, w, dt=0.1, friction=0.25, gravity=10.0)
    # speed 5 m/s slows by mu g dt = 0.25 m/s along -v_xy; travels 5 * 0.1 - 2.5 * 0.01 / 2
    assert torch.allclose(c[0, 0:3], torch.tensor([-0.15, -0.2, 0.0]), atol=1e-6)
    assert torch.allclose(torch.linalg.vector_norm(c[0, 6:8]), torch.tensor(0.5 - 0.0125), atol=1e-6)
    slow = prior_changes("coulomb", torch.tensor([[0.1, 0.0, 0.0]]), w, dt=0.1, friction=0.25, gravity=10.0)
    assert torch.allclose(slow[0, 0], torch.tensor(-0.1)) and torch.allclose(slow[0, 6], torch.tensor(0.1**2 / 5.0))
    assert prior_changes("none", v, w, 0.1, 0.25) is None
    # planar: the spin about z stops when the slide stops (t_stop = 5 / 2.5 = 2 s), tilt and v_z are removed
    planar = prior_changes("planar", v, w, dt=0.1, friction=0.25, gravity=10.0)
    assert torch.allclose(planar[0, 0:6], torch.tensor([-0.15, -0.2, -0.1, 0.0, -1.0, -2.0 * 0.1 / 2.0]), atol=1e-6)
    assert torch.allclose(planar[0, 6:9], torch.cat([c[0, 6:8], torch.zeros(1)]), atol=1e-7)
    assert torch.allclose(planar[0, 9:12], torch.tensor([0.0, 0.0, 2.0 * 0.1 - 2.0 * 0.01 / 4.0]), atol=1e-7)


def _box_footprint(half_x: float, half_y: float, height: float, n: int = 9) -> torch.Tensor:
    """Points of a box's bottom face (a grid) and of its top, centre of mass at the origin: (1, 2 n^2, 3)."""
    x, y = torch.meshgrid(torch.linspace(-half_x, half_x, n), torch.linspace(-half_y, half_y, n), indexing="ij")
    bottom = torch.stack([x.flatten(), y.flatten(), torch.full((n * n,), -height / 2)], dim=1)
    top = bottom * torch.tensor([1.0, 1.0, -1.0])
    return torch.cat([bottom, top])[None]


def test_contact_prior_slides_like_coulomb_without_spin_and_couples_spin_and_slide():
    identity = torch.tensor([[[0.0, 0.0, 0.0, 1.0]]])
    geometry = contact_geometry(_box_footprint(0.05, 0.05, 0.1))
    # the footprint: the bottom points, weighted equally, the centre of mass 5 cm above them
    K = (geometry.shape[1] - 2) // 4
    assert torch.allclose(geometry[0, 3 * K : 4 * K].sum(), torch.tensor(1.0))
    assert torch.allclose(geometry[0, -1], torch.tensor(0.05))
    dt, mu, g = 1.0 / 15.0, 0.25, 9.81

    def roll(v, w, steps=60):
        v, w = torch.tensor([[v]]), torch.tensor([[w]])
        p, yaw = torch.zeros(2), 0.0
        for _ in range(steps):
            c = contact_changes(v, w, identity, geometry, dt, mu, g)[0, 0]
            v, w = v + c[0:3], w + c[3:6]
            p, yaw = p + c[6:8], yaw + float(c[11])
        return p, yaw, v, w

    # pure sliding: Coulomb's stopping distance v^2 / (2 mu g), along v, and no spin appears
    p, yaw, v, w = roll([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert abs(float(p[0]) - 1.0 / (2 * mu * g)) < 0.01 and abs(float(p[1])) < 1e-3 and abs(yaw) < 0.01
    assert float(v.abs().max()) < 1e-3
    # spinning while sliding: friction is shared between the two, so the object slides farther than
    # Coulomb's point mass, and both motions stop (Goyal, Ruina & Papadopoulos 1991)
    p_spun, yaw_spun, v, w = roll([1.0, 0.0, 0.0], [0.0, 0.0, 8.0])
    assert float(p_spun[0]) > float(p[0]) + 0.01 and yaw_spun > 0.1
    assert float(v.abs().max()) < 1e-3 and float(w.abs().max()) < 0.05
    # tilt and vertical velocity are taken away, as the planar prior does
    c = contact_changes(torch.tensor([[[0.5, 0.0, 0.2]]]), torch.tensor([[[1.0, -2.0, 0.0]]]), identity, geometry, dt, mu, g)
    assert torch.allclose(c[0, 0, 2:5], torch.tensor([-0.2, -1.0, 2.0]))


def test_below_the_gate_speeds_the_prediction_is_the_priors_alone(quickstart_config, store):
    model = DynamicsModel(quickstart_config("model.prior=planar", "model.residual_gate_linear=0.1",
                                            "model.residual_gate_angular=1.0"),
                          compute_normalization(store, np.arange(store.num_sims)), {"rate_hz": 15.0, "friction": 0.25})
    with torch.no_grad():  # a network with a large residual everywhere
        model.head.linear.bias.fill_(0.5)
    feature = model.encode_points(torch.zeros(2, 64, 3) + torch.randn(2, 64, 3) * 0.05)
    v = torch.tensor([[0.05, 0.0, 0.0], [0.5, 0.0, 0.0]])  # one slow (gated), one fast
    w = torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5]])
    pred = model.step(feature, v, w, None, torch.tensor([[0.0, 0.0, 0.0, 1.0]] * 2))
    prior = prior_changes("planar", v, w, 1 / 15, 0.25)
    got = torch.cat([pred.delta_linear_velocity, pred.delta_angular_velocity, pred.delta_position, pred.delta_rotation], -1)
    assert torch.allclose(got[0], prior[0], atol=1e-6)  # below both gates: the prior exactly
    assert not torch.allclose(got[1], prior[1], atol=1e-3)  # above: the residual applies


def test_the_contact_prior_needs_the_orientation(tiny_store, tmp_path):
    with pytest.raises(ConfigError, match="model.prior.*orientation_input=true"):
        load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path, "model.prior=contact",
                                                            "model.orientation_input=false"))


def test_rotation_6d_is_the_first_two_matrix_columns():
    from physdyn.geometry.rotations import quat_to_matrix

    q = np.random.default_rng(1).normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quat_to_matrix(q)
    six = rotation_6d(torch.tensor(q)).numpy()
    np.testing.assert_allclose(six, np.concatenate([R[:, :, 0], R[:, :, 1]], axis=1), atol=1e-12)


def test_orientation_fed_step_by_step_matches_the_teacher_forced_window(quickstart_config, store):
    model = DynamicsModel(quickstart_config("model.orientation_input=true"), compute_normalization(store, np.arange(5)))
    sims = np.arange(3)
    truth = gather_truth(store, sims, num_steps=8)
    points = store.points[store.shape_id[sims]]
    window = teacher_forced(model, points, truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, :8],
                            truth["angular_velocity"][:, :8], truth["orientation_xyzw"][:, :8])
    with pytest.raises(ValueError, match="orientation"):
        teacher_forced(model, points, truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, :8], truth["angular_velocity"][:, :8])
    # a roll-out warm-started with the true velocities feeds its own integrated orientation instead: same
    # velocities in, different orientation in, so the changes differ once the object has turned
    warm = (truth["linear_velocity"][:, 1:8], truth["angular_velocity"][:, 1:8])
    rolled = rollout(model, points, truth["orientation_xyzw"][:, 0], truth["com_position"][:, 0],
                     truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0], 8, RolloutOptions(warm))
    np.testing.assert_allclose(rolled.fed_linear_velocity, truth["linear_velocity"][:, :8], atol=1e-6)
    np.testing.assert_allclose(rolled.delta_position[:, 0], window["delta_position"][:, 0], atol=1e-5)


def test_std_normalisation_is_per_channel_and_round_trips(store):
    sims = np.flatnonzero(store.split == 0)
    norm = compute_normalization(store, sims, mode="std")
    frames = np.concatenate([np.arange(store.start[i], store.start[i + 1]) for i in sims])
    t = frame_targets(store)
    np.testing.assert_allclose(norm.change_std[6:9], t.delta_position[frames].std(axis=0), rtol=1e-9)
    np.testing.assert_allclose(norm.input_mean[:3], store.linear_velocity[frames].mean(axis=0), rtol=1e-9)
    assert type(norm).from_dict(norm.to_dict()) == norm
    inputs_only = compute_normalization(store, sims, mode="std_inputs")
    np.testing.assert_allclose(inputs_only.input_scales(), norm.input_scales())
    np.testing.assert_allclose(inputs_only.change_scales(), compute_normalization(store, sims).change_scales())


def test_feedback_targets_lead_from_the_fed_velocities_to_the_true_next_ones(quickstart_config, tiny_store):
    cfg = quickstart_config("rollout.feedback=1.0", "rollout.input_noise=0.05")
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    model = DynamicsModel(cfg, dm.normalization)
    model.train()
    batch = next(iter(dm.train_dataloader()))
    torch.manual_seed(0)
    changes, logit, targets = closed_loop(model, model.encode(batch["points"]), batch)
    assert changes.shape == targets.shape == batch["delta_position"].shape[:2] + (12,)
    si = targets * model.change_scale + model.change_shift
    true_next_v = batch["linear_velocity"] + batch["delta_linear_velocity"]
    fed_v = true_next_v - si[..., 0:3]
    # step 0 is fed the truth plus noise; later steps the model's own prediction (never the truth here)
    assert not torch.allclose(fed_v[:, 1:], batch["linear_velocity"][:, 1:], atol=1e-4)
    pred_si = changes.detach() * model.change_scale + model.change_shift
    assert torch.allclose(fed_v[:, 1:] - (fed_v[:, :-1] + pred_si[:, :-1, 0:3]), torch.zeros_like(fed_v[:, 1:]),
                          atol=0.2 * float(model.velocity_scale[0]))  # within the injected noise
    torch.testing.assert_close(si[..., 6:9], batch["delta_position"])


@pytest.mark.slow  # a training run long enough to learn (about 20 s)
def test_tiny_training_run_lowers_the_rollout_error(tiny_store, tmp_path):
    """The recipe of the bundled model on the tiny store: roll-out errors on the training pushes fall."""
    lightning.seed_everything(0)
    store = load_store(tiny_store)
    overrides = shrunk_overrides(tiny_store, tmp_path, "model.prior=planar", "model.orientation_input=true",
                                 "rollout.feedback=1.0", "data.first_window_fraction=0.5", "data.normalization=std_inputs",
                                 "model.predictor.params.hidden=64", "trainer.max_steps=250")
    cfg = load_experiment_config(QUICKSTART, overrides)
    before = evaluate(DynamicsModel(cfg, compute_normalization(store, np.flatnonzero(store.split == 0)),
                                    {"rate_hz": store.rate_hz, "friction": 0.25}), store, split="train")
    after = evaluate(str(fit(cfg).last_checkpoint), store, split="train")
    b, a = before["headline"], after["headline"]
    # A fresh model with a prior *is* the prior (its residual layer starts at zero), so "before" is already
    # planar Coulomb sliding, not noise: training must improve on the analytic prior itself.
    assert a["position"] < 0.9 * b["position"], (a["position"], b["position"])
    assert a["final_position_m_median"] < 0.9 * b["final_position_m_median"]
    assert a["linear_velocity"] < b["linear_velocity"]


def test_the_one_object_contact_prior_is_the_tensor_one_to_rounding():
    # A one-at-a-time roll-out takes the contact prior on Python numbers; batches and training the tensor
    # loop. Both must give the same changes: resting, slow, sliding, spinning and tumbling states.
    from physdyn.models.priors import AT_REST, contact_changes, contact_geometry

    torch.manual_seed(0)
    for trial in range(60):
        points = torch.randn(1, 128, 3, dtype=torch.float64) * torch.tensor([0.08, 0.05, 0.1], dtype=torch.float64)
        geometry = contact_geometry(points)
        v = torch.randn(1, 1, 3, dtype=torch.float64) * (2.0 if trial % 3 else 0.005)
        w = torch.randn(1, 1, 3, dtype=torch.float64) * (5.0 if trial % 2 else 0.02)
        q = torch.randn(1, 1, 4, dtype=torch.float64)
        if trial % 5 == 0:  # all but at rest on its base, as a slide leaves it (the shortcut's case)
            v, w = v * 1e-9, w * 1e-9
            q[..., :2] = 0.0  # turned about the vertical only
        q = q / q.norm()
        with torch.no_grad():
            one = contact_changes(v, w, q, geometry, 1 / 15, 0.25)
        batch = contact_changes(v.expand(2, 1, 3), w.expand(2, 1, 3), q.expand(2, 1, 4), geometry.expand(2, -1), 1 / 15, 0.25)
        if trial % 5 == 0:  # at rest the one-object path stops the motion at once, where the sub-steps
            # trade the last 1e-8 m/s of slide for spin through the footprint's lever (r / I ~ 30 / m)
            torch.testing.assert_close(one[..., :6], batch[:1, :, :6], rtol=0, atol=100 * AT_REST)
            torch.testing.assert_close(one[..., 6:], batch[:1, :, 6:], rtol=0, atol=AT_REST)
        else:
            torch.testing.assert_close(one, batch[:1], rtol=0, atol=1e-10)
        assert one.dtype == torch.float64 and one.shape == (1, 1, 12)


def test_without_gradient_the_contact_prior_stops_resting_pairs_and_substeps_the_rest():
    # Roll-outs and evaluation (no gradient): (sequence, step) pairs at rest are stopped at once, the others
    # take the sub-steps as training does, each as if alone.
    from physdyn.models.priors import contact_changes, contact_geometry

    torch.manual_seed(1)
    points = torch.randn(3, 128, 3, dtype=torch.float64) * torch.tensor([0.08, 0.05, 0.1], dtype=torch.float64)
    geometry = contact_geometry(points)
    v = torch.randn(3, 2, 3, dtype=torch.float64)
    w = torch.randn(3, 2, 3, dtype=torch.float64) * 3.0
    q = torch.randn(3, 2, 4, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    resting = torch.tensor([[True, False], [False, False], [False, True]])
    v[resting], w[resting] = v[resting] * 1e-10, w[resting] * 1e-10
    with torch.no_grad():
        fast = contact_changes(v, w, q, geometry, 1 / 15, 0.25)
    full = contact_changes(v, w, q, geometry, 1 / 15, 0.25)  # with gradient: the sub-steps everywhere
    stop = torch.cat([-v, -w, torch.zeros_like(v), torch.zeros_like(w)], dim=-1)
    torch.testing.assert_close(fast[resting], stop[resting], rtol=0, atol=0)
    torch.testing.assert_close(fast[~resting], full[~resting], rtol=0, atol=1e-12)
    assert (full[~resting].abs() > 1e-3).any()  # the moving pairs did move


def test_a_body_at_rest_on_a_far_contact_stays_at_rest():
    # One support point 0.16 m from the vertical through the centre of mass, spin inertia a quarter of its
    # r^2: friction's stick regime must not overshoot there and swap slide and spin (an overshoot grows x4 per
    # two sub-steps).
    geometry = torch.tensor([[0.158, -0.034, -0.21] * 4 + [1.0, 0.0, 0.0, 0.0, 0.0063, 0.21]], dtype=torch.float64)
    v = torch.tensor([[[-1.7e-9, 6e-10, 0.0]]], dtype=torch.float64)
    w = torch.tensor([[[0.0, 0.0, 6.5e-9]]], dtype=torch.float64)
    q = torch.tensor([[[0.0, 0.0, 0.0, 1.0]]], dtype=torch.float64)
    for _ in range(20):
        c = contact_changes(v.expand(2, 1, 3), w.expand(2, 1, 3), q.expand(2, 1, 4), geometry.expand(2, -1), 1 / 15, 0.25)[:1]
        v, w = v + c[..., 0:3], w + c[..., 3:6]
    assert float(v.norm()) < 1e-8 and float(w.norm()) < 1e-8
    # while a real slide on the same contact still slides and stops
    c = contact_changes(torch.tensor([[[1.0, 0.0, 0.0]]], dtype=torch.float64), torch.zeros(1, 1, 3, dtype=torch.float64),
                        q, geometry, 1 / 15, 0.25)
    assert 0.5 * 2.45 / 15 < -float(c[0, 0, 0]) <= 2.45 / 15 + 1e-9


def test_the_footprint_does_not_depend_on_the_order_of_the_cloud():
    # The same cloud listed in another order is the same object: the same footprint, weights and inertia
    # (farthest-point sampling must not start from whichever touching point comes first).
    rng = np.random.default_rng(3)
    base = np.c_[rng.uniform(-0.06, 0.06, (200, 2)), np.zeros(200)]  # a flat 12 cm square base
    rest = np.c_[rng.uniform(-0.03, 0.03, (300, 2)), rng.uniform(0.01, 0.2, 300)]
    cloud = np.concatenate([base, rest]) - [0.0, 0.0, 0.08]
    points = torch.tensor(cloud[None])
    geometry = contact_geometry(points)
    for seed in range(5):
        order = np.random.default_rng(seed).permutation(len(cloud))
        torch.testing.assert_close(contact_geometry(points[:, order]), geometry)
    K = (geometry.shape[1] - 2) // 4
    support = geometry[0, : 3 * K].reshape(K, 3)
    assert float(support[:, :2].abs().max()) > 0.05  # it spans the base, out to its corners


def test_a_turned_window_is_the_same_push_in_another_direction(store):
    """data.yaw_augment: the turned batch's orientations turn its turned points as the original's turn the
    original points, its changes are the original's turned, and the contact prior's changes turn with it."""
    source = WindowSource(store, 6, 128)
    sims = np.flatnonzero(store.split == 0)[:6]
    batch = source.gather(sims, np.zeros(len(sims), np.int64), None)
    yaw = np.linspace(0.4, 5.9, len(sims))
    turned = turned_about_vertical(batch, yaw)
    c, s = np.cos(yaw), np.sin(yaw)
    Z = np.zeros((len(yaw), 3, 3))
    Z[:, 0, 0], Z[:, 0, 1], Z[:, 1, 0], Z[:, 1, 1], Z[:, 2, 2] = c, -s, s, c, 1.0
    turn = lambda x: np.einsum("bij,b...j->b...i", Z, x)  # noqa: E731
    for key in ("linear_velocity", "angular_velocity", "delta_position", "delta_rotation", "points"):
        np.testing.assert_allclose(turned[key], turn(batch[key]), atol=1e-6)
    for t in (1, 5):
        R = quat_to_matrix(batch["relative_orientation_xyzw"][:, t].astype(np.float64))
        Rt = quat_to_matrix(turned["relative_orientation_xyzw"][:, t].astype(np.float64))
        np.testing.assert_allclose(np.einsum("bij,bnj->bni", Rt, turned["points"]),
                                   turn(np.einsum("bij,bnj->bni", R, batch["points"])), atol=1e-5)
    assert not np.allclose(turned["linear_velocity"], batch["linear_velocity"], atol=1e-3)  # it did turn

    def prior(b):
        with torch.no_grad():
            return contact_changes(torch.tensor(b["linear_velocity"]), torch.tensor(b["angular_velocity"]),
                                   torch.tensor(b["relative_orientation_xyzw"]), contact_geometry(torch.tensor(b["points"])),
                                   1 / 15, 0.25).numpy()
    before, after = prior(batch), prior(turned)
    for k in range(4):
        np.testing.assert_allclose(after[..., 3 * k : 3 * k + 3], turn(before[..., 3 * k : 3 * k + 3]), atol=1e-4)


def test_yaw_augment_turns_training_windows_only(quickstart_config):
    cfg = quickstart_config("data.yaw_augment=true", "data.first_window_fraction=1.0")
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    torch.manual_seed(0)
    train = next(iter(dm.train_dataloader()))
    sims = train["sim"].numpy()
    plain = dm.source.gather(sims, train["start"].numpy(), None)
    speed = lambda v: np.linalg.norm(np.asarray(v)[..., :2], axis=-1)  # noqa: E731
    np.testing.assert_allclose(speed(train["linear_velocity"]), speed(plain["linear_velocity"]), rtol=1e-5, atol=1e-6)
    assert not np.allclose(np.asarray(train["linear_velocity"]), plain["linear_velocity"], atol=1e-3)
    val = next(iter(dm.val_dataloader()))
    again = dm.source.gather(val["sim"].numpy(), val["start"].numpy(), None)
    np.testing.assert_allclose(np.asarray(val["linear_velocity"]), again["linear_velocity"])


def test_the_footprint_can_be_given_and_defaults_to_the_lowest_points():
    rng = np.random.default_rng(3)
    points = torch.tensor(rng.uniform(-0.1, 0.1, (2, 200, 3)), dtype=torch.float32)
    z = points[..., 2]
    lowest = z <= z.min(dim=1, keepdim=True).values + 0.005
    torch.testing.assert_close(contact_geometry(points, lowest), contact_geometry(points))
    mine = torch.zeros_like(lowest)
    mine[:, :3] = True  # three points anywhere carry the weight, the lowest ones or not
    support = contact_geometry(points, mine)[:, :12].reshape(2, 4, 3)
    for b in range(2):
        assert all(any(torch.allclose(s, p) for p in points[b, :3]) for s in support[b])


def test_one_clouds_footprint_on_numpy_equals_the_batched_one_to_the_bit():
    # One cloud (a new mesh's prediction) takes a numpy path; it must give the batch's numbers exactly,
    # ties included: flat bottoms (many touching points) and clouds on a grid (equal distances).
    g = torch.Generator().manual_seed(1)
    for trial in range(300):
        n = (4, 64, 256)[trial % 3]
        clouds = torch.randn(3, n, 3, generator=g) * 0.05
        if trial % 2:
            clouds[:, : n // 2, 2] = clouds[:, :, 2].min(dim=1, keepdim=True).values
        if trial % 5 == 0:
            clouds = torch.round(clouds * 50) / 50
        batch = contact_geometry(clouds)
        for i in range(3):
            assert torch.equal(contact_geometry(clouds[i : i + 1]), batch[i : i + 1])
    # a cloud a caller did not check (no finite lowest point): the same numbers, NaNs where the batch has them
    bad = torch.randn(2, 64, 3, generator=g) * 0.05
    bad[1, 5, 2] = float("nan")
    torch.testing.assert_close(contact_geometry(bad[1:]), contact_geometry(bad)[1:], rtol=0, atol=0, equal_nan=True)


def test_the_area_footprint_finds_a_rectangles_four_corners_where_spreading_misses_some():
    box = _box_footprint(0.05, 0.03, 0.04)  # the bottom face of a 10 x 6 cm box: a grid with its corners
    corners = {(sx * 0.05, sy * 0.03) for sx in (-1, 1) for sy in (-1, 1)}

    def footprint(kind):
        geometry = contact_geometry(box, footprint=kind)
        xy = geometry[0, :12].reshape(4, 3)[:, :2]
        return {(round(float(x), 4), round(float(y), 4)) for x, y in xy}, geometry

    area, area_geometry = footprint("area")
    spread, spread_geometry = footprint("spread")
    assert area == corners and torch.allclose(area_geometry[0, 12:16], torch.full((4,), 0.25))
    assert spread != corners  # farthest-point sampling takes a point of a long edge for a third corner
    # the corners grip a spin harder, as the simulator's manifold of the face's corners does
    identity, still, spin = torch.tensor([[[0.0, 0.0, 0.0, 1.0]]]), torch.zeros(1, 1, 3), torch.tensor([[[0.0, 0.0, 6.0]]])
    spin_lost = [float(-contact_changes(still, spin, identity, g, 1 / 60, 0.25)[0, 0, 5]) for g in (area_geometry, spread_geometry)]
    assert spin_lost[0] > 1.05 * spin_lost[1]
    # a line contact (a cylinder lying down) keeps its two ends, the other two points weigh nothing
    line = torch.stack([torch.linspace(-0.1, 0.1, 21), torch.zeros(21), torch.full((21,), -0.03)], dim=1)[None]
    weights = contact_geometry(line, footprint="area")[0, 12:16]
    assert torch.allclose(weights, torch.tensor([0.5, 0.5, 0.0, 0.0]))
    with pytest.raises(ValueError, match="unknown footprint"):
        contact_geometry(box, footprint="corners")


@pytest.mark.parametrize("detach", [False, True])
def test_a_detached_topple_head_trains_its_own_row_only(quickstart_config, detach):
    # The topple loss alone: with the paper's head it reaches the predictor and the encoder; detached, only
    # the topple row of the head. The numbers computed are the same either way.
    cfg = quickstart_config(f"model.head.params.detach_topple={str(detach).lower()}")
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    model = DynamicsModel(cfg, dm.normalization)
    torch.nn.init.normal_(model.head.linear.weight, std=0.1)  # a prior's head starts at zero
    model.train()
    batch = next(iter(dm.train_dataloader()))
    feature = model.encode(batch["points"], batch.get("spin_inertia"))
    changes, logit, _ = model(feature, batch["linear_velocity"], batch["angular_velocity"], None,
                              batch["relative_orientation_xyzw"])
    torch.nn.functional.binary_cross_entropy_with_logits(logit, batch["topple_label"].float()).backward()
    reached = lambda module: any(p.grad is not None and p.grad.abs().sum() > 0 for p in module.parameters())  # noqa: E731
    assert reached(model.predictor) != detach and reached(model.encoder) != detach
    grad = model.head.linear.weight.grad
    assert grad[12].abs().sum() > 0 and grad[:12].abs().sum() == 0
    paper = DynamicsModel(quickstart_config("model.head.params.detach_topple=false", out="paper"), dm.normalization)
    paper.load_state_dict(model.state_dict())
    paper.train()
    same_changes, same_logit, _ = paper(paper.encode(batch["points"], batch.get("spin_inertia")), batch["linear_velocity"],
                                        batch["angular_velocity"], None, batch["relative_orientation_xyzw"])
    torch.testing.assert_close(same_changes, changes)
    torch.testing.assert_close(same_logit, logit)


def test_a_detached_topple_head_is_saved_with_the_model_and_rolls_out(quickstart_config, store):
    result = fit(quickstart_config("model.head.params.detach_topple=true"))
    model = DynamicsModel.load_from_checkpoint(result.last_checkpoint)
    assert model.head.config.detach_topple is True
    # its topple row learned although it starts at zero (a prior's head), and its loss does not shape the network
    assert model.head.linear.weight[12].abs().sum() > 0
    report = evaluate(model, store, split="test")
    assert math.isfinite(report["headline"]["final_position_m_median"]) and 0 <= report["topple"]["accuracy"] <= 1
