"""Baselines that need no learning: exact where their physics is (a box pushed through its centre of mass)."""

import numpy as np
import pytest
import trimesh

from physdyn.config import PhysicsConfig
from physdyn.data.store import load_store
from physdyn.errors import PhysdynError
from physdyn.eval.baselines import CoulombSlide, StayPut, coulomb_slide, resolve_predictor, stay_put
from physdyn.eval.evaluate import evaluate, gather_truth, predict_single_steps, select_sequences
from physdyn.geometry.mass import exact_mass_properties
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.sim.body import RigidBodySpec
from physdyn.sim.impulse import push_point
from physdyn.sim.trajectory import InitialCondition, resting_com_position, simulate
from physdyn.sim.world import PhysicsWorld

MU = 0.25  # conventions: 0.5 x 0.5


def push_box(extents, speed, yaw_deg, rate_hz=15):
    """Push a box in its resting pose through its centre of mass along the world direction ``yaw_deg``."""
    box = trimesh.creation.box(extents)
    props = exact_mass_properties(box, 100.0)
    spec = RigidBodySpec.from_mesh(box, props)
    q0 = np.array([0, 0, 0, 1.0])
    com0 = resting_com_position(spec, q0)
    top = float((spec.body_vertices() @ quat_to_matrix(q0).T + com0)[:, 2].max())
    direction = np.array([np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg)), 0.0])
    with PhysicsWorld(PhysicsConfig()) as world:
        body = world.add_body(spec)
        point = push_point(world, body, spec, q0, com0, direction, 0.5 * top, 0.0)
        init = InitialCondition(q0, props.mass * speed * direction, point, MU)
        return simulate(world, body, spec, init, rate_hz)


@pytest.mark.parametrize("speed,yaw_deg", [(1.0, 0.0), (1.8, 30.0)])
def test_coulomb_slide_matches_the_simulated_box(speed, yaw_deg):
    traj = push_box((0.2, 0.2, 0.1), speed, yaw_deg)
    T = len(traj)
    out = coulomb_slide(traj.com_position[:1], traj.orientation_xyzw[:1], traj.linear_velocity[:1],
                        traj.angular_velocity[:1], T - 1, friction=MU, rate_hz=15)
    travelled_sim = np.linalg.norm(traj.com_position[-1] - traj.com_position[0])
    final_error = np.linalg.norm(out.com_position[0, -1] - traj.com_position[-1])
    assert final_error < 0.03 * travelled_sim, (final_error, travelled_sim)
    # it stops where the simulated box stops, and the whole path agrees within a few % of the distance
    assert np.linalg.norm(out.linear_velocity[0, -1]) == 0.0
    path_error = np.linalg.norm(out.com_position[0] - traj.com_position, axis=-1).max()
    assert path_error < 0.05 * travelled_sim
    np.testing.assert_allclose(out.orientation_xyzw[0], np.repeat(traj.orientation_xyzw[:1], T, axis=0))


def test_coulomb_slide_closed_form_by_hand():
    # 2 m/s along +y, mu g = 0.25 * 9.81: stops after 0.8155 s having slid 2^2 / (2 mu g) = 0.8155 m
    out = coulomb_slide(np.array([[1.0, 2.0, 0.05]]), np.array([[0, 0, 0, 1.0]]), np.array([[0, 2.0, -0.3]]),
                        np.array([[0, 0, 3.0]]), steps=20, friction=np.array([0.25]), rate_hz=10)
    a = 0.25 * 9.81
    t = 0.3
    np.testing.assert_allclose(out.com_position[0, 3], [1.0, 2.0 + 2.0 * t - 0.5 * a * t**2, 0.05])
    np.testing.assert_allclose(out.linear_velocity[0, 3], [0, 2.0 - a * t, 0])
    np.testing.assert_allclose(out.com_position[0, -1], [1.0, 2.0 + 4.0 / (2 * a), 0.05])
    assert out.com_position.shape == (1, 21, 3) and out.orientation_xyzw.shape == (1, 21, 4)
    np.testing.assert_array_equal(out.linear_velocity[0, 0], [0, 2.0, -0.3])  # step 0 is the given state
    np.testing.assert_array_equal(out.angular_velocity[0, 1:], 0.0)
    np.testing.assert_allclose(out.delta_position.sum(axis=1)[0], out.com_position[0, -1] - out.com_position[0, 0])
    assert out.topple_probability.shape == (1, 21) and not out.topple_probability.any()


def test_coulomb_slide_refuses_unknown_or_non_positive_friction():
    args = (np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), np.tile([1.0, 0, 0], (2, 1)), np.zeros((2, 3)))
    for friction in ([0.25, np.nan], [0.25, 0.0], [-0.1, 0.25]):
        with pytest.raises(ValueError, match="friction must be positive and known"):
            coulomb_slide(*args, steps=5, friction=np.array(friction), rate_hz=15)


def test_stay_put_never_moves():
    q = np.array([[0, 0, np.sin(0.3), np.cos(0.3)]])
    out = stay_put(np.array([[0.1, 0.2, 0.3]]), q, np.array([[1.0, 0, 0]]), np.array([[0, 0, 2.0]]), steps=5)
    np.testing.assert_array_equal(out.com_position[0], np.repeat([[0.1, 0.2, 0.3]], 6, axis=0))
    np.testing.assert_allclose(out.orientation_xyzw[0], np.repeat(q, 6, axis=0))
    np.testing.assert_array_equal(out.delta_position, 0.0)
    np.testing.assert_array_equal(out.delta_linear_velocity[0, 0], [-1.0, 0, 0])


def test_baselines_evaluate_on_a_real_store(tiny_store):
    store = load_store(tiny_store)
    sims = select_sequences(store, "test")
    truth = gather_truth(store, sims)
    # single step of Coulomb sliding from each true state = its one-step closed form
    single = predict_single_steps(CoulombSlide(), store, sims, truth)
    one = coulomb_slide(truth["com_position"][:, 3], truth["orientation_xyzw"][:, 3], truth["linear_velocity"][:, 3],
                        truth["angular_velocity"][:, 3], 1, truth["friction"], store.rate_hz)
    np.testing.assert_allclose(single["delta_position"][:, 3], one.delta_position[:, 0])
    slide, still = evaluate("coulomb_slide", store), evaluate(StayPut(), store)
    assert slide["predictor"] == "coulomb_slide" and still["predictor"] == "stay_put"
    # sliding is closer to the truth than standing still (the data are pushes that slide)
    assert slide["headline"]["final_position_m_median"] < still["headline"]["final_position_m_median"]
    assert still["rollout"]["all"]["relative"]["position"] == pytest.approx(1.0)  # zero prediction: 100 %
    assert isinstance(resolve_predictor("stay_put"), StayPut)


def test_the_simulator_on_the_cloud_is_scored_as_a_baseline(tiny_store):
    # cloud_sim: PyBullet on each shape's cloud hull with the store's mass properties. The tiny store's
    # own simulations used the mesh's hull at 1/960 s, so it is close to them but not equal.
    from physdyn.eval.baselines import CloudSim
    from physdyn.eval.rollout import integrate

    store = load_store(tiny_store)
    sim, slide = evaluate(CloudSim(), store), evaluate("coulomb_slide", store)
    assert sim["predictor"] == "cloud_sim" and isinstance(resolve_predictor("cloud_sim"), CloudSim)
    assert sim["headline"]["final_position_m_median"] < 0.5 * slide["headline"]["final_position_m_median"]
    assert sim["headline"]["final_rotation_deg_median"] < 0.5 * slide["headline"]["final_rotation_deg_median"]
    toppled = store.toppled[select_sequences(store, "test")].astype(bool)
    assert toppled.any() and sim["topple"]["accuracy"] > max(toppled.mean(), 1 - toppled.mean())
    # its per-step changes are those of its own states: integrating them gives its trajectory back
    sims = select_sequences(store, "test")[:4]
    truth = gather_truth(store, sims)
    shapes = store.shape_id[sims]
    out = CloudSim().rollout(truth["com_position"][:, 0], truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, 0],
                             truth["angular_velocity"][:, 0], 12, truth["friction"], store.rate_hz,
                             points_body=store.points[shapes])
    again = integrate(truth["com_position"][:, 0], truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, 0],
                      truth["angular_velocity"][:, 0], out.deltas())
    np.testing.assert_allclose(again["com_position"], out.com_position, atol=1e-9)
    dots = np.abs((again["orientation_xyzw"] * out.orientation_xyzw).sum(-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-6)
    with pytest.raises(PhysdynError, match="point cloud"):
        CloudSim().rollout(truth["com_position"][:, 0], truth["orientation_xyzw"][:, 0], truth["linear_velocity"][:, 0],
                           truth["angular_velocity"][:, 0], 3, truth["friction"], store.rate_hz)
