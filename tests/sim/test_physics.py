"""The simulator obeys the conventions and elementary mechanics."""

import numpy as np
import pytest
import trimesh

from physdyn.config import PhysicsConfig
from physdyn.geometry.mass import exact_mass_properties
from physdyn.geometry.rotations import quat_to_matrix, tilt_angle, world_delta_rotvec
from physdyn.sim.body import RigidBodySpec
from physdyn.sim.impulse import push_point
from physdyn.sim.trajectory import InitialCondition, resting_com_position, simulate
from physdyn.sim.world import PhysicsWorld

G = 9.81
MU = 0.25  # 0.5 x 0.5


def push(mesh, speed, height_fraction, rate_hz=15, lateral=0.0, yaw_deg=0.0, physics=None):
    """Push ``mesh`` (resting in its design pose) along +x at a height fraction of its top, through the
    centre-of-mass column offset sideways by ``lateral`` metres. Returns (trajectory, spec, com0)."""
    props = exact_mass_properties(mesh, 100.0)
    spec = RigidBodySpec.from_mesh(mesh, props)
    c, s = np.cos(np.radians(yaw_deg) / 2), np.sin(np.radians(yaw_deg) / 2)
    q0 = np.array([0, 0, s, c])
    com0 = resting_com_position(spec, q0)
    top = float((spec.body_vertices() @ quat_to_matrix(q0).T + com0)[:, 2].max())
    with PhysicsWorld(physics or PhysicsConfig()) as world:
        body = world.add_body(spec)
        p = push_point(world, body, spec, q0, com0, np.array([1.0, 0, 0]), height_fraction * top, lateral)
        init = InitialCondition(q0, np.array([props.mass * speed, 0, 0]), p, MU)
        traj = simulate(world, body, spec, init, rate_hz)
    return traj, spec, com0


@pytest.mark.parametrize("speed", [1.0, 1.5, 2.0])
def test_box_pushed_through_com_slides_coulomb_distance(speed):
    box = trimesh.creation.box((0.2, 0.2, 0.1))
    traj, spec, com0 = push(box, speed, height_fraction=0.5)
    v0 = np.linalg.norm(traj.linear_velocity[0])
    expected = v0**2 / (2 * MU * G)
    travelled = np.linalg.norm(traj.com_position[-1, :2] - traj.com_position[0, :2])
    assert travelled == pytest.approx(expected, rel=0.03)
    assert v0 == pytest.approx(speed, rel=0.02)  # impulse = mass x speed
    assert traj.topple_step == -1


def test_tall_thin_box_pushed_high_topples():
    traj, _, _ = push(trimesh.creation.box((0.04, 0.04, 0.3)), 1.5, height_fraction=0.9)
    assert traj.topple_step > 0
    assert traj.topple_label[traj.topple_step:].all() and not traj.topple_label[: traj.topple_step].any()


def test_low_flat_box_pushed_low_does_not_topple():
    traj, _, _ = push(trimesh.creation.box((0.3, 0.3, 0.05)), 2.0, height_fraction=0.2)
    assert traj.topple_step == -1 and not traj.topple_label.any()
    assert np.degrees(tilt_angle(traj.orientation_xyzw[0], traj.orientation_xyzw).max()) < 10


def test_step0_pose_follows_the_mesh_frame_convention():
    """A vertex x maps to R (x - com_mesh) + com_position; the object starts on the ground at x = y = 0."""
    mesh = trimesh.creation.cone(radius=0.08, height=0.2, sections=32)
    mesh.apply_translation([0.3, -0.2, 0.5])  # a mesh frame far from its centre of mass
    traj, spec, com0 = push(mesh, 0.8, height_fraction=0.3, yaw_deg=40)
    R = quat_to_matrix(traj.orientation_xyzw[0])
    world = (mesh.vertices - spec.com_mesh) @ R.T + traj.com_position[0]
    assert abs(world[:, 2].min()) < 3e-3  # resting on z = 0 (within Bullet's contact margin)
    np.testing.assert_allclose(com0[:2], 0.0, atol=1e-12)
    assert np.linalg.norm(traj.com_position[0, :2]) < 0.02  # one physics step after the push


def test_velocities_match_finite_differences_and_quaternions_are_unit():
    box = trimesh.creation.box((0.12, 0.06, 0.05))
    traj, _, _ = push(box, 1.5, height_fraction=0.5, rate_hz=240, lateral=0.025)  # off-centre: it spins
    dt = 1.0 / 240
    np.testing.assert_allclose(np.linalg.norm(traj.orientation_xyzw, axis=1), 1.0, atol=1e-9)
    moving = np.linalg.norm(traj.linear_velocity, axis=1) > 0.1
    k = np.nonzero(moving[1:-1])[0] + 1
    v_fd = (traj.com_position[k + 1] - traj.com_position[k - 1]) / (2 * dt)
    scale = np.abs(traj.linear_velocity).max()
    assert np.median(np.linalg.norm(v_fd - traj.linear_velocity[k], axis=1)) < 0.01 * scale
    w_fd = world_delta_rotvec(traj.orientation_xyzw[k - 1], traj.orientation_xyzw[k + 1]) / (2 * dt)
    w_scale = np.abs(traj.angular_velocity).max()
    assert w_scale > 1.0  # the off-centre push made it spin
    # The spin about z is smooth; the horizontal components carry Bullet's contact chatter (about
    # +/-1 rad/s of rocking at 240 Hz) which a central difference averages out, hence two tolerances.
    assert np.median(np.abs(w_fd[:, 2] - traj.angular_velocity[k, 2])) < 0.02 * w_scale
    assert np.median(np.linalg.norm(w_fd - traj.angular_velocity[k], axis=1)) < 0.08 * w_scale


def test_simulation_stops_at_rest_or_time_cap():
    box = trimesh.creation.box((0.2, 0.2, 0.1))
    traj, _, _ = push(box, 1.0, height_fraction=0.5)
    rest_frames = int(0.5 * 15)
    tail = traj.linear_velocity[-rest_frames:]
    assert np.all(np.linalg.norm(tail, axis=1) < 0.01)
    assert len(traj) < 7 * 15 + 1
    short = PhysicsConfig(max_duration=0.4)
    traj, _, _ = push(box, 2.0, height_fraction=0.5, physics=short)
    assert len(traj) == int(0.4 * 15) + 1  # the cap, step 0 included


def test_a_world_steps_at_its_new_time_step_after_sub_steps():
    """set_time_step: one call then runs one physics step of the new length, whatever sub-stepping ran
    before. Bullet integrates v += g dt, then z += v dt, so a body dropped from rest falls g dt^2 in one
    step of dt, and only 10/16 of that in four sub-steps of dt / 4 (what pb.setTimeStep alone leaves)."""
    from physdyn.sim.bullet import pb

    box = trimesh.creation.box((0.1, 0.1, 0.1))
    spec = RigidBodySpec.from_mesh(box, exact_mass_properties(box, 100.0))
    with PhysicsWorld(PhysicsConfig(time_step=1 / 240)) as world:
        body = world.add_body(spec)  # created at z = 1 m, far above the ground

        def drop(substeps: int) -> float:
            pb.resetBasePositionAndOrientation(body, [0, 0, 1], [0, 0, 0, 1], physicsClientId=world.client)
            pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=world.client)
            world.step(substeps)
            return 1.0 - pb.getBasePositionAndOrientation(body, physicsClientId=world.client)[0][2]

        assert drop(4) == pytest.approx(G * (1 / 240) ** 2 * (1 + 2 + 3 + 4), rel=1e-6)
        world.set_time_step(1 / 60)  # from four sub-steps to one step a call
        assert drop(1) == pytest.approx(G * (1 / 60) ** 2, rel=1e-6)
        assert drop(2) == pytest.approx(G * (1 / 60) ** 2 * (1 + 2), rel=1e-6)  # sub-steps of the new step
        world.set_time_step(1 / 30)  # the same sub-steps a call as before it
        assert drop(2) == pytest.approx(G * (1 / 30) ** 2 * (1 + 2), rel=1e-6)
        with pytest.raises(ValueError, match="time_step"):
            world.set_time_step(0.0)
