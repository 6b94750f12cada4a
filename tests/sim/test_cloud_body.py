"""PyBullet on a body made from a point cloud alone: its mass properties, and short roll-outs' tilt."""

import numpy as np
import pytest
import trimesh

from physdyn.config import PhysicsConfig
from physdyn.errors import ShapeError
from physdyn.geometry.sampling import sample_surface_points
from physdyn.predict.simulator import simulate_from_state
from physdyn.sim.body import rigid_body
from physdyn.sim.cloud_body import CloudSimulator, cloud_body_spec
from physdyn.sim.trajectory import topple_labels


def _box_cloud(extents, n=1024, seed=0):
    return sample_surface_points(trimesh.creation.box(extents), n, 3, seed=seed)


def test_a_box_cloud_makes_the_box_solid():
    a, b, c = 0.1, 0.2, 0.4
    spec = cloud_body_spec(_box_cloud((a, b, c)))
    # a solid box: I / m = (sum of the other two sides squared) / 12, about its own centre
    per_mass = np.sort(spec.inertia_diag / spec.mass)
    np.testing.assert_allclose(per_mass, np.sort([(b * b + c * c) / 12, (a * a + c * c) / 12, (a * a + b * b) / 12]), rtol=0.03)
    assert spec.mass == pytest.approx(1000 * a * b * c, rel=0.03)
    body = spec.body_vertices()
    np.testing.assert_allclose(body.max(axis=0) - body.min(axis=0), [a, b, c], rtol=0.03)
    # the inertia is taken about the cloud's origin (the known centre of mass), not the hull's centroid
    shifted = cloud_body_spec(_box_cloud((a, b, c)) + [0.0, 0.0, 0.05])
    assert shifted.inertia_diag.max() / shifted.mass > per_mass.max() + 0.05 ** 2 * 0.9
    # mass properties a store does not know (NaN, zeros) fall back to the hull's, as the contact prior's do
    for unknown in (np.full((3, 3), np.nan), np.zeros((3, 3))):
        np.testing.assert_allclose(cloud_body_spec(_box_cloud((a, b, c)), unknown).inertia_diag, spec.inertia_diag)
    with pytest.raises(ShapeError, match="no 3D convex hull"):
        cloud_body_spec(np.c_[np.random.default_rng(0).normal(size=(64, 2)), np.zeros(64)])  # flat


def test_short_rollouts_tilt_a_tall_box_over_and_leave_a_squat_one_standing():
    tall, squat = _box_cloud((0.06, 0.06, 0.3)), _box_cloud((0.2, 0.2, 0.08), seed=1)
    points = np.stack([tall, squat, tall, squat])
    v = np.array([[0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]])
    w = np.array([[0.0, 12.0, 0.0], [0.0, 0.0, 3.0], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    with CloudSimulator() as sim:
        tilt = sim.max_tilt(points, v, w, friction=0.25)
        again = np.concatenate([sim.max_tilt(points[i : i + 1], v[i : i + 1], w[i : i + 1], 0.25) for i in range(4)])
    assert tilt.shape == (4, 3) and (np.diff(tilt, axis=1) >= 0).all()  # the largest so far, per horizon
    np.testing.assert_allclose(tilt, again, atol=1e-9)  # a body per cloud, reused: the same roll-outs
    assert tilt[0, -1] > 80  # a hard tilt spin topples the tall box
    assert tilt[1, -1] < 2 and tilt[3, -1] < 2  # sliding and spinning flat leaves a squat box upright
    assert 1 < tilt[2, -1] < 45, tilt[2]  # a milder push rocks it and it falls back

    # the same verdicts as the conventions' simulation of the real box mesh (1/960 s)
    box = rigid_body(trimesh.creation.box((0.06, 0.06, 0.3)), "tall", 500.0)
    for i in (0, 2):
        real = simulate_from_state(box.spec, np.array([0, 0, 0, 1.0]), v[i], w[i], 15.0, 16, PhysicsConfig())
        assert (topple_labels(real["orientation_xyzw"])[1] >= 0) == (tilt[i, -1] > 45)


def test_with_the_bodys_inertia_and_a_turned_pose_it_is_the_simulation_of_that_body():
    # An irregular convex body whose cloud is its own hull's vertices: given its inertia (world axes for
    # max_tilt, body axes for trajectories) the cloud's body is the body, so the roll-outs must be those of
    # the simulator on the real body at the same step, in a turned pose where a frame mix-up would show.
    from physdyn.geometry.mass import world_inertia_per_mass
    from physdyn.geometry.rotations import quat_to_matrix
    from physdyn.sim.trajectory import tilt_angle

    rng = np.random.default_rng(3)
    mesh = trimesh.convex.convex_hull(rng.normal(size=(40, 3)) * [0.04, 0.07, 0.12])
    body = rigid_body(mesh, "blob", 500.0)
    spec = body.spec
    q0 = np.array([0.3, -0.2, 0.4, 0.8]) / np.linalg.norm([0.3, -0.2, 0.4, 0.8])
    v0, w0 = np.array([0.6, 0.2, 0.0]), np.array([1.5, 5.0, 2.0])
    mass = (spec.inertia_diag, spec.principal_axes, spec.mass)
    cloud = spec.body_vertices()
    physics = PhysicsConfig(time_step=1.0 / 240.0)
    real = simulate_from_state(spec, q0, v0, w0, 60.0, 61, physics)  # 60 Hz: every 4th step, as max_tilt reads
    real_tilt = np.degrees(tilt_angle(real["orientation_xyzw"][0], real["orientation_xyzw"]))
    with CloudSimulator() as sim:
        tilt = sim.max_tilt((cloud @ quat_to_matrix(q0).T)[None], v0[None], w0[None], 0.25,
                            world_inertia_per_mass(*mass, q0)[None])
        whole = sim.trajectories(cloud[None], q0[None], real["com_position"][:1], v0[None], w0[None], [0.25], 12, 15.0,
                                 world_inertia_per_mass(*mass, np.array([0.0, 0.0, 0.0, 1.0]))[None])
    assert real_tilt.max() > 20  # the push tilts it hard: the test can tell inertias apart
    over = np.flatnonzero(real_tilt > 90)
    seen = real_tilt[: over[0] + 1] if len(over) else real_tilt  # max_tilt stops once past 90 degrees
    np.testing.assert_allclose(tilt[0], [seen[:16].max(), seen[:31].max(), seen.max()], atol=0.1)  # 0.25, 0.5, 1 s
    slow = simulate_from_state(spec, q0, v0, w0, 15.0, 13, physics)
    np.testing.assert_allclose(whole["com_position"][0], slow["com_position"], atol=1e-6)
    np.testing.assert_allclose(np.abs((whole["orientation_xyzw"][0] * slow["orientation_xyzw"]).sum(-1)), 1.0, atol=1e-6)
    # with the inertia of another body (the hull's own is this body's here, so turn it) the roll-out differs
    with CloudSimulator() as sim:
        wrong = sim.max_tilt((cloud @ quat_to_matrix(q0).T)[None], v0[None], w0[None], 0.25,
                             world_inertia_per_mass(*mass, np.array([0.0, 0.0, 0.0, 1.0]))[None])
    assert abs(wrong[0, 0] - tilt[0, 0]) > 0.5


def test_a_long_lived_simulator_rebuilds_its_world_and_never_keeps_a_body(monkeypatch):
    import physdyn.sim.cloud_body as cloud_body
    from physdyn.sim.bullet import pb
    from physdyn.sim.world import PhysicsWorld

    monkeypatch.setattr(cloud_body, "MAX_SHAPES", 2)
    clouds = np.stack([_box_cloud((0.1 + 0.02 * i, 0.1, 0.2), n=256, seed=i) for i in range(5)])
    v, w = np.tile([0.5, 0.0, 0.0], (5, 1)), np.tile([0.0, 3.0, 0.0], (5, 1))
    with CloudSimulator() as fresh:
        expected = np.concatenate([fresh.max_tilt(clouds[i : i + 1], v[:1], w[:1], 0.25) for i in range(5)])
    earlier = PhysicsWorld(PhysicsConfig())  # a client opened before and closed after: the rebuilt world
    sim = CloudSimulator()                   # may get another id than the one it replaces
    earlier.close()
    try:
        np.testing.assert_allclose(sim.max_tilt(clouds, v, w, 0.25), expected, atol=1e-9)  # rebuilt twice on the way
        assert pb.getNumBodies(physicsClientId=sim.world.client) == 1  # the ground alone
        with pytest.raises(ValueError, match="rate_hz"):  # 7 Hz does not divide 240 Hz: refused before any body
            sim.trajectories(clouds[:1], np.array([[0, 0, 0, 1.0]]), np.zeros((1, 3)), v[:1], w[:1], [0.25], 5, 7.0)
        assert pb.getNumBodies(physicsClientId=sim.world.client) == 1
    finally:
        sim.close()
