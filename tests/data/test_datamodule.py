"""Windows, targets, normalisation and the DataModule, on a real simulated store."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physdyn.config import TrainDataConfig
from physdyn.data.datamodule import DynamicsDataModule, select_sims
from physdyn.data.normalization import Normalization, compute_normalization
from physdyn.data.store import load_store
from physdyn.data.windows import WindowSource, frame_targets, world_oriented_points
from physdyn.errors import ConfigError
from physdyn.geometry.rotations import canonical_quat, quat_multiply, rotvec_to_quat


@pytest.fixture(scope="module")
def store(tiny_store):
    return load_store(tiny_store)


def _datamodule(store, **kw) -> DynamicsDataModule:
    dm = DynamicsDataModule(TrainDataConfig(store=store.url, **kw), store=store)
    dm.setup("fit")
    return dm


def test_targets_reproduce_the_trajectory_when_integrated(store):
    t = frame_targets(store)
    moving = [i for i in range(store.num_sims) if np.ptp(store.angular_velocity[store.frames(i)]) > 0.5][:6]
    assert moving, "the tiny store should hold spinning objects"
    for sim in moving:
        f = store.frames(sim)
        v, w, p, q = (store.linear_velocity[f], store.angular_velocity[f], store.com_position[f], store.orientation_xyzw[f])
        dv, dw, dp, dth = (t.delta_linear_velocity[f], t.delta_angular_velocity[f], t.delta_position[f], t.delta_rotation[f])
        np.testing.assert_allclose(v[0] + np.cumsum(dv, axis=0)[:-1], v[1:], atol=1e-9)
        np.testing.assert_allclose(w[0] + np.cumsum(dw, axis=0)[:-1], w[1:], atol=1e-9)
        np.testing.assert_allclose(p[0] + np.cumsum(dp, axis=0)[:-1], p[1:], atol=1e-9)
        qk = q[0]
        for k in range(len(q) - 1):  # world frame: R_{t+1} = Exp(dtheta) R_t
            qk = quat_multiply(rotvec_to_quat(dth[k]), qk)
            np.testing.assert_allclose(canonical_quat(qk), canonical_quat(q[k + 1]), atol=1e-9)
        np.testing.assert_array_equal(t.next_topple_label[f][:-1], store.topple_label[f][1:])
        # the last frame has no next frame: nothing changes
        assert not np.any(dv[-1]) and not np.any(dth[-1])


def test_window_targets_match_frames_and_integrate(store):
    sim = int(np.argmax(store.lengths()))
    L = int(store.lengths()[sim])
    src = WindowSource(store, window=L - 1)
    b = src.gather(np.array([sim]), np.array([0]))
    f = store.frames(sim)
    np.testing.assert_allclose(b["linear_velocity"][0], store.linear_velocity[f][:-1], atol=1e-6)
    np.testing.assert_allclose(b["angular_velocity"][0], store.angular_velocity[f][:-1], atol=1e-6)
    p = store.com_position[f]
    np.testing.assert_allclose(p[0] + np.cumsum(b["delta_position"][0], axis=0), p[1:], atol=1e-5)
    assert b["valid"].all()


def test_short_simulation_is_padded_with_its_resting_state(store):
    sim = int(np.argmin(store.lengths()))
    L = int(store.lengths()[sim])
    T = L + 6
    b = WindowSource(store, window=T).gather(np.array([sim]), np.array([0]))
    f = store.frames(sim)
    last_v, last_w = store.linear_velocity[f][-1], store.angular_velocity[f][-1]
    assert b["linear_velocity"].shape == (1, T, 3)
    np.testing.assert_allclose(b["linear_velocity"][0, L - 1 :], np.broadcast_to(last_v, (T - L + 1, 3)), atol=1e-6)
    np.testing.assert_allclose(b["angular_velocity"][0, L - 1 :], np.broadcast_to(last_w, (T - L + 1, 3)), atol=1e-6)
    for key in ("delta_linear_velocity", "delta_angular_velocity", "delta_position", "delta_rotation"):
        assert not np.any(b[key][0, L - 1 :]), key
        assert np.any(b[key][0, : L - 1]), key  # the real steps do change
    np.testing.assert_array_equal(b["topple_label"][0, L - 1 :], float(store.topple_label[f][-1]))
    np.testing.assert_array_equal(b["valid"][0], np.arange(T) < L - 1)


def test_point_cloud_is_rotated_into_the_first_steps_world_orientation(store):
    sim = int(np.argmax(store.lengths()))
    start = 5
    b = WindowSource(store, window=4).gather(np.array([sim]), np.array([start]))
    frame = store.start[sim] + start
    q = store.orientation_xyzw[frame]
    body = store.points[store.shape_id[sim]]
    expected = Rotation.from_quat(q).apply(body)
    np.testing.assert_allclose(b["points"][0], expected, atol=1e-5)
    # and so points + com position are the object's surface in the world at that step (conventions.md)
    com_mesh = store.com_mesh[store.shape_id[sim]]
    mesh_points = body + com_mesh
    world = Rotation.from_quat(q).apply(mesh_points - com_mesh) + store.com_position[frame]
    np.testing.assert_allclose(b["points"][0] + b["com_position0"][0], world, atol=1e-5)
    np.testing.assert_allclose(world_oriented_points(body, q), expected, atol=1e-9)


def test_random_starts_stay_inside_the_simulation(store):
    src = WindowSource(store, window=15)
    rng = np.random.default_rng(0)
    sims = np.repeat(np.arange(store.num_sims), 20)
    starts = src.random_starts(sims, rng)
    L = store.lengths()[sims]
    assert np.all(starts >= 0)
    assert np.all(starts <= np.maximum(L - 16, 0))
    long = L > 40
    assert np.any(starts[long] > 0) and len(np.unique(starts[long])) > 5


def test_normalization_comes_from_the_training_split_only(store):
    dm = _datamodule(store)
    train = select_sims(store, 0)
    assert dm.normalization == compute_normalization(store, train)
    f = np.concatenate([np.arange(store.start[i], store.start[i + 1]) for i in train])
    assert dm.normalization.linear_velocity == pytest.approx(np.abs(store.linear_velocity[f]).max())
    assert dm.normalization.angular_velocity == pytest.approx(np.abs(store.angular_velocity[f]).max())
    # Blow up every non-training simulation and shape: the statistics must not move.
    other = copy.deepcopy(store)
    not_train = np.ones(len(other.com_position), bool)
    not_train[f] = False
    other.linear_velocity[not_train] *= 100.0
    other.angular_velocity[not_train] *= 100.0
    other.com_position[not_train] *= 100.0
    test_shapes = np.setdiff1d(np.arange(other.num_shapes), other.shape_id[train])
    assert len(test_shapes) > 0
    other.points[test_shapes] *= 10.0
    assert _datamodule(other).normalization == dm.normalization
    restored = Normalization.from_dict(dm.normalization.to_dict())
    assert restored == dm.normalization


def test_category_selection_and_exclusion(store):
    names = store.category_names
    dm = _datamodule(store, categories=[names[0], names[1]])
    assert set(store.sim_category()[dm.sims.train]) == {0, 1}
    dm = _datamodule(store, exclude_categories=[names[2]])
    cats = store.sim_category()
    assert 2 not in set(cats[dm.sims.train]) and 2 not in set(cats[dm.sims.test])
    assert len(dm.sims.train) == int(np.sum((store.split == 0) & (cats != 2)))
    with pytest.raises(ConfigError, match=r"data.exclude_categories.*'chairs'.*" + names[0]):
        _datamodule(store, exclude_categories=["chairs"])


def test_one_epoch_is_one_window_from_every_training_simulation(store):
    dm = _datamodule(store, batch_size=16, num_points=64)
    seen = []
    for batch in dm.train_dataloader():
        assert batch["points"].shape[1:] == (64, 3)
        assert batch["linear_velocity"].shape[1:] == (15, 3)
        seen.extend(batch["sim"].tolist())
    assert sorted(seen) == sorted(dm.sims.train.tolist())


def test_validation_windows_are_fixed_and_training_windows_random(store):
    dm1, dm2 = _datamodule(store, num_points=64), _datamodule(store, num_points=64)
    a = next(iter(dm1.val_dataloader()))
    b = next(iter(dm1.val_dataloader()))
    c = next(iter(dm2.val_dataloader()))
    for key in ("points", "start", "delta_position"):
        assert (a[key] == b[key]).all() and (a[key] == c[key]).all()
    # the tiny store has no validation split: validation falls back to fixed training windows
    assert dm1.val_uses_train == (len(dm1.sims.val) == 0)
    t1 = next(iter(dm1.train_dataloader()))
    t2 = next(iter(dm1.train_dataloader()))
    assert not (t1["points"].shape == t2["points"].shape and (t1["points"] == t2["points"]).all())


def test_subsampled_points_are_a_subset_of_the_cloud(store):
    dm = _datamodule(store, num_points=50, batch_size=4)
    b = next(iter(dm.val_dataloader()))
    sim, start = int(b["sim"][0]), int(b["start"][0])
    full = WindowSource(store, 15).gather(np.array([sim]), np.array([start]))["points"][0]
    d = np.linalg.norm(b["points"][0].numpy()[:, None, :] - full[None], axis=-1).min(axis=1)
    assert b["points"].shape == (4, 50, 3) and d.max() < 1e-6
    with pytest.raises(ConfigError, match="data.num_points"):
        _datamodule(store, num_points=10_000)
