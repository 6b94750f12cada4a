"""The network's residual on some channels only (``model.residual_channels``), and a model that
takes its velocity and position changes from a second network (``export --linear-from``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from physdyn.data.datamodule import DynamicsDataModule
from physdyn.data.store import load_store
from physdyn.data.windows import world_oriented_points
from physdyn.errors import ConfigError
from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import evaluate, gather_truth, select_sequences
from physdyn.eval.rollout import teacher_forced
from physdyn.models.batch_rollout import batch_rollout
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.dynamics_network import DynamicsNetwork
from physdyn.models.export import export_checkpoint
from physdyn.models.single_rollout import SingleRollout
from physdyn.models.training import load_experiment_config
from physdyn.predict.predictor import load_predictor
from tests.models.conftest import QUICKSTART, shrunk_overrides

ANGULAR = [3, 4, 5, 9, 10, 11]  # dw, dtheta in [dv, dw, dp, dtheta]
LINEAR = [0, 1, 2, 6, 7, 8]


@pytest.fixture(scope="module")
def store(tiny_store):
    return load_store(tiny_store)


@pytest.fixture(scope="module")
def data(tiny_store, tmp_path_factory):
    cfg = load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path_factory.mktemp("dm")))
    dm = DynamicsDataModule(cfg.data)
    dm.setup("fit")
    return dm


def _model(tiny_store, tmp_path, data, *overrides, seed=0) -> DynamicsModel:
    cfg = load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path / f"m{seed}", *overrides))
    torch.manual_seed(seed)
    model = DynamicsModel(cfg, data.normalization, {"rate_hz": 15.0, "friction": 0.25})
    with torch.no_grad():  # a residual that matters (a model with a prior starts with it at zero)
        model.head.linear.weight.normal_(0.0, 0.05)
        model.head.linear.bias.normal_(0.0, 0.05)
    return model.eval()


def _save(model: DynamicsModel, path) -> str:
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams),
                "pytorch-lightning_version": "2.0.0"}, path)
    return str(path)


def _window(data):
    batch = next(iter(data.val_dataloader()))
    return batch["points"], batch["linear_velocity"], batch["angular_velocity"], batch["relative_orientation_xyzw"]


@pytest.mark.parametrize("channels", ["linear", "angular"])
def test_a_residual_on_some_channels_leaves_the_others_to_the_prior(tiny_store, tmp_path, data, channels):
    kept, prior_only = (LINEAR, ANGULAR) if channels == "linear" else (ANGULAR, LINEAR)
    model = _model(tiny_store, tmp_path, data, f"model.residual_channels={channels}")
    plain = _model(tiny_store, tmp_path, data)  # the same weights (same seed), every channel corrected
    points, v, w, q = _window(data)
    with torch.no_grad():
        geometry = model.split_code(model.encode(points))[1]
        prior = (model.analytic_prior(v, w, q, geometry) - model.change_shift) / model.change_scale
    changes, _, _ = model(model.encode(points), v, w, None, q)  # eval mode (batch norm), with gradients
    moving = model.rest_gate(v, w)
    torch.testing.assert_close(changes[..., prior_only], prior[..., prior_only])
    with torch.no_grad():
        mixed = plain.eval()(plain.encode(points), v, w, None, q)[0]
    assert (mixed[..., prior_only] - prior[..., prior_only])[moving].abs().max() > 1e-3  # the plain model corrects them
    torch.testing.assert_close(changes.detach()[..., kept], mixed[..., kept], rtol=1e-5, atol=1e-5)
    changes.square().sum().backward()  # no gradient reaches the rows of channels it does not correct
    grad = model.head.linear.weight.grad
    assert grad[prior_only].abs().sum() == 0 and grad[kept].abs().sum() > 0


def test_residual_channels_is_checked(tiny_store, tmp_path):
    for bad in (["model.residual_channels=spin"], ["model.prior=none", "model.residual_channels=linear"]):
        with pytest.raises(ConfigError, match=r"model\.residual_channels") as info:
            load_experiment_config(QUICKSTART, shrunk_overrides(tiny_store, tmp_path, *bad))
        assert "\n" not in str(info.value)


@pytest.fixture
def combined(tiny_store, tmp_path, data):
    """(linear network, the other, the file combining them, loaded): different encoders, so the shape
    code's two parts have different widths."""
    linear = _model(tiny_store, tmp_path, data, "model.residual_channels=linear", "model.encoder.params.feature_size=4", seed=1)
    angular = _model(tiny_store, tmp_path, data, seed=2)
    out = export_checkpoint(_save(angular, tmp_path / "a.ckpt"), tmp_path / "combined.ckpt",
                            linear_from=_save(linear, tmp_path / "l.ckpt"))
    return linear, angular, out, load_checkpoint(out)


def test_a_combined_model_takes_velocity_and_position_from_one_network_and_the_rest_from_the_other(combined, store):
    linear, angular, _, both = combined
    # loaded for prediction as the plain network, both parts (no Lightning)
    assert type(both) is type(both.linear_channels) is DynamicsNetwork
    assert both.linear_channels.config.model.residual_channels == "linear"
    sims = select_sequences(store, "test")[:6]
    truth = gather_truth(store, sims)
    points = store.points[store.shape_id[sims]][:, :64]
    args = (points, truth["orientation_xyzw"][:, 0], truth["linear_velocity"], truth["angular_velocity"], truth["orientation_xyzw"])
    a, b, ab = teacher_forced(linear, *args), teacher_forced(angular, *args), teacher_forced(both, *args)
    for key in ("delta_linear_velocity", "delta_position"):
        np.testing.assert_allclose(ab[key], a[key], rtol=1e-5, atol=1e-6, err_msg=key)
        assert np.abs(ab[key] - b[key]).max() > 1e-4, key  # not the other network's
    for key in ("delta_angular_velocity", "delta_rotation", "topple_probability"):
        np.testing.assert_allclose(ab[key], b[key], rtol=1e-5, atol=1e-6, err_msg=key)


def test_a_combined_model_rolls_out_the_same_on_every_path(combined, store):
    linear, angular, _, both = combined
    assert SingleRollout.supports(both)
    sims = select_sequences(store, "test")[:4]
    truth = gather_truth(store, sims)
    points = world_oriented_points(store.points[store.shape_id[sims]][:, :64], truth["orientation_xyzw"][:, 0]).astype(np.float32)
    v0, w0 = truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0]
    with torch.inference_mode():
        forward = batch_rollout(both, points, v0, w0, 25)  # the model's forward every step, topple probabilities
        rows = batch_rollout(both, points, v0, w0, 25, topple=False)  # each network on its moving rows only
        alone = batch_rollout(angular, points, v0, w0, 25)
    np.testing.assert_allclose(rows["changes"].numpy(), forward["changes"].numpy(), rtol=1e-5, atol=1e-5)
    for i in range(len(sims)):  # one object: the numpy roll-out
        one = both.rollout_changes(points[i : i + 1], v0[i : i + 1], w0[i : i + 1], 25)
        np.testing.assert_allclose(one["changes"][0].numpy(), forward["changes"][i].numpy(), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(one["topple_probability"][0].numpy(), forward["topple_probability"][i].numpy(), rtol=1e-5, atol=1e-5)
    assert (forward["changes"] - alone["changes"])[..., LINEAR].abs().max() > 1e-4  # the other network's slide


def test_a_model_combined_with_itself_is_that_model(tiny_store, tmp_path, data, store):
    model = _model(tiny_store, tmp_path, data)
    path = _save(model, tmp_path / "m.ckpt")
    both = load_checkpoint(export_checkpoint(path, tmp_path / "self.ckpt", linear_from=path))
    sims = select_sequences(store, "test")[:3]
    truth = gather_truth(store, sims)
    points = world_oriented_points(store.points[store.shape_id[sims]][:, :64], truth["orientation_xyzw"][:, 0]).astype(np.float32)
    v0, w0 = truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0]
    for topple in (True, False):
        with torch.inference_mode():
            expected = batch_rollout(model, points, v0, w0, 20, topple=topple)["changes"]
            got = batch_rollout(both, points, v0, w0, 20, topple=topple)["changes"]
        # float32 round-off: the combined model sums its two networks' outputs in another order, and a
        # multi-threaded matmul under parallel test workers moves the last digit (as the test above allows)
        np.testing.assert_allclose(got.numpy(), expected.numpy(), rtol=1e-5, atol=1e-5)


def test_a_combined_model_predicts_and_evaluates_through_the_public_path(combined, store):
    _, _, path, _ = combined
    report = evaluate(str(path), store, split="test")
    assert np.isfinite(report["headline"]["final_position_m_median"])
    result = load_predictor(str(path)).predict(trimesh.creation.box(extents=[0.12, 0.08, 0.06]), lin_vel=[1.0, 0.2, 0.0],
                                                ang_vel=[0.0, 0.0, 3.0], seconds=1.0)
    assert np.isfinite(np.asarray(result["com_position"])).all() and len(result["com_position"]) == 16
    assert np.linalg.norm(np.asarray(result["com_position"])[-1, :2] - np.asarray(result["com_position"])[0, :2]) > 0.01


def test_combining_refuses_what_cannot_be_combined(combined, tiny_store, tmp_path, data):
    _, angular, path, _ = combined
    a = _save(angular, tmp_path / "a2.ckpt")
    with pytest.raises(ConfigError, match="combines two networks itself"):
        export_checkpoint(a, tmp_path / "nested.ckpt", linear_from=path)
    other_rate = _model(tiny_store, tmp_path, data, seed=3)
    other_rate.hparams["data_info"]["rate_hz"] = 30.0
    with pytest.raises(ConfigError, match="different rates"):
        export_checkpoint(a, tmp_path / "rates.ckpt", linear_from=_save(other_rate, tmp_path / "r.ckpt"))
    assert not (tmp_path / "nested.ckpt").exists() and not (tmp_path / "rates.ckpt").exists()


def test_an_inference_setting_reaches_both_networks_of_a_combined_file(combined, tmp_path, store):
    # export --set on a combined file (or with --linear-from) sets both networks: each computes its own prior
    _, _, path, before = combined
    assert before.linear_channels.config.model.contact_footprint == "spread"
    again = load_checkpoint(export_checkpoint(path, tmp_path / "area.ckpt",
                                              settings=["model.contact_footprint=area", "name=boxes"]))
    assert again.config.model.contact_footprint == "area" and again.linear_channels.config.model.contact_footprint == "area"
    assert again.config.name == "boxes"
    sims = select_sequences(store, "test")[:4]
    truth = gather_truth(store, sims)
    points = world_oriented_points(store.points[store.shape_id[sims]][:, :64], truth["orientation_xyzw"][:, 0]).astype(np.float32)
    v0, w0 = truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0]
    with torch.inference_mode():
        a, b = batch_rollout(before, points, v0, w0, 10)["changes"], batch_rollout(again, points, v0, w0, 10)["changes"]
    assert (a - b)[..., LINEAR].abs().max() > 1e-6  # the velocity network's prior changed too
