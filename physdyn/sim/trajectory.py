"""Simulate one push and record the trajectory at the dataset's rate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from physdyn.sim.bullet import pb

from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_matrix, tilt_angle
from physdyn.sim.body import RigidBodySpec
from physdyn.sim.world import PhysicsWorld

TOPPLE_ANGLE = np.deg2rad(45.0)


@dataclass
class InitialCondition:
    """orientation_xyzw: rotation of the mesh frame in the world before the push.
    impulse: (3,) N s, world frame; impulse_point: (3,) world point where it acts.
    friction: effective Coulomb coefficient of the object-ground contact (object x ground lateral)."""

    orientation_xyzw: np.ndarray
    impulse: np.ndarray
    impulse_point: np.ndarray
    friction: float


@dataclass
class Trajectory:
    """T recorded steps, step 0 immediately after the push (conventions: pose of the mesh frame).

    com_position (T, 3), orientation_xyzw (T, 4), linear_velocity (T, 3), angular_velocity (T, 3),
    topple_label (T,) bool, topple_step (int, -1 if none).
    """

    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    topple_label: np.ndarray
    topple_step: int

    def __len__(self) -> int:
        return len(self.com_position)


def resting_com_position(spec: RigidBodySpec, orientation_xyzw: np.ndarray) -> np.ndarray:
    """Where the centre of mass sits when the object rests in this orientation: lowest point on z = 0,
    centre of mass above the origin."""
    world_vertices = spec.body_vertices() @ quat_to_matrix(orientation_xyzw).T
    return np.array([0.0, 0.0, -world_vertices[:, 2].min()])


def resting_com_positions(spec: RigidBodySpec, orientations_xyzw: np.ndarray) -> np.ndarray:
    """``resting_com_position`` for many orientations (n, 4) of one body -> (n, 3), in one product (a batch of
    pushes of one object poses it hundreds of times). Each height is computed as the single call computes it."""
    vertices, turns = spec.body_vertices(), quat_to_matrix(orientations_xyzw).transpose(0, 2, 1)
    out = np.zeros((len(turns), 3))
    for lo in range(0, len(turns), 256):  # (256, V, 3) at a time: a few MB whatever the batch
        out[lo : lo + 256, 2] = -np.matmul(vertices, turns[lo : lo + 256])[..., 2].min(axis=1)
    return out


def topple_labels(orientations_xyzw: np.ndarray) -> tuple[np.ndarray, int]:
    """Per-step labels: 1 from the first step where the initial up direction has tilted past 45 degrees."""
    tilt = tilt_angle(orientations_xyzw[0], orientations_xyzw)
    over = np.nonzero(tilt > TOPPLE_ANGLE)[0]
    step = int(over[0]) if len(over) else -1
    labels = np.zeros(len(orientations_xyzw), dtype=bool)
    if step >= 0:
        labels[step:] = True
    return labels, step


def steps_per_frame(time_step: float, rate_hz: float) -> int:
    n = 1.0 / (time_step * rate_hz)
    if abs(n - round(n)) > 1e-6 or round(n) < 1:
        raise ValueError(f"rate_hz={rate_hz} must divide the physics rate 1/time_step={1 / time_step:g} Hz")
    return int(round(n))


def place_at_rest(world: PhysicsWorld, body: int, spec: RigidBodySpec, orientation_xyzw: np.ndarray) -> np.ndarray:
    """Put the body at rest on the ground in this mesh-frame orientation; returns the com position."""
    q_mesh0 = np.asarray(orientation_xyzw, dtype=np.float64)
    # PyBullet's base frame is the principal frame: R_base = R_mesh @ A.
    q_base = quat_multiply(q_mesh0, spec.principal_quat_xyzw)
    com0 = resting_com_position(spec, q_mesh0)
    pb.resetBasePositionAndOrientation(body, com0.tolist(), q_base.tolist(), physicsClientId=world.client)
    pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=world.client)
    return com0


REST_CHECK_INTERVAL = 1.0 / 240.0  # s: the longest stretch of physics steps between two rest checks


def rest_check_substeps(every: int, time_step: float, max_interval: float = REST_CHECK_INTERVAL) -> int:
    """Physics steps per rest check: the largest divisor of ``every`` (physics steps per recorded frame)
    that spans at most ``max_interval`` seconds, so frames still fall on a call boundary and rest is
    judged at 240 Hz or finer (one check per 1/960 s step cost a Python round trip each)."""
    limit = max(1, int(np.floor(max_interval / time_step + 1e-9)))
    return max(k for k in range(1, min(every, limit) + 1) if every % k == 0)


def record(world: PhysicsWorld, body: int, spec: RigidBodySpec, rate_hz: float, max_frames: int | None = None) -> Trajectory:
    """Step the world from the body's current state, recording at ``rate_hz`` (the current state is step
    0) until it has rested for ``physics.rest_duration`` or ``max_frames`` (default: the time cap)."""
    phys = world.physics
    cid = world.client
    every = steps_per_frame(phys.time_step, rate_hz)
    chunk = rest_check_substeps(every, phys.time_step)
    if max_frames is None:
        max_frames = int(np.floor(phys.max_duration * rate_hz + 1e-9)) + 1
    rest_steps_needed = int(np.ceil(phys.rest_duration / phys.time_step - 1e-9))
    v_rest, w_rest = phys.rest_linear_speed, phys.rest_angular_speed

    positions, quats, lin, ang = [], [], [], []
    rest_steps = 0
    step = 0
    while True:
        if step % every == 0:
            pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
            v, w = pb.getBaseVelocity(body, physicsClientId=cid)
            positions.append(pos)
            quats.append(orn)
            lin.append(v)
            ang.append(w)
            if rest_steps >= rest_steps_needed or len(positions) >= max_frames:
                break
        world.step(chunk)
        step += chunk
        v, w = pb.getBaseVelocity(body, physicsClientId=cid)
        at_rest = (v[0] ** 2 + v[1] ** 2 + v[2] ** 2 < v_rest**2) and (w[0] ** 2 + w[1] ** 2 + w[2] ** 2 < w_rest**2)
        rest_steps = rest_steps + chunk if at_rest else 0

    # Back from the principal frame to the mesh frame: R_mesh = R_base @ A^T.
    q_principal_inv = quat_conjugate(spec.principal_quat_xyzw)
    orientation = quat_multiply(np.asarray(quats), q_principal_inv)
    orientation /= np.linalg.norm(orientation, axis=1, keepdims=True)
    orientation = np.where(orientation[:, 3:4] < 0, -orientation, orientation)
    labels, topple_step = topple_labels(orientation)
    return Trajectory(
        com_position=np.asarray(positions, dtype=np.float64),
        orientation_xyzw=orientation,
        linear_velocity=np.asarray(lin, dtype=np.float64),
        angular_velocity=np.asarray(ang, dtype=np.float64),
        topple_label=labels,
        topple_step=topple_step,
    )


def simulate(world: PhysicsWorld, body: int, spec: RigidBodySpec, init: InitialCondition, rate_hz: float) -> Trajectory:
    """Place the body at rest, push it for one physics step, record until at rest or the time cap."""
    phys = world.physics
    place_at_rest(world, body, spec, init.orientation_xyzw)
    world.set_object_friction(body, init.friction / phys.lateral_friction_ground)
    # The push: a force over exactly one physics step, so the ground's reaction acts during it.
    force = np.asarray(init.impulse, dtype=np.float64) / phys.time_step
    pb.applyExternalForce(body, -1, force.tolist(), list(map(float, init.impulse_point)), pb.WORLD_FRAME,
                          physicsClientId=world.client)
    world.step(1)
    return record(world, body, spec, rate_hz)


def record_from_state(world: PhysicsWorld, body: int, spec: RigidBodySpec, orientation_xyzw: np.ndarray,
                      lin_vel: np.ndarray, ang_vel: np.ndarray, rate_hz: float, num_steps: int) -> dict[str, np.ndarray]:
    """The body from the state right after a push: at rest in ``orientation_xyzw`` (mesh frame), centre of mass
    above the origin, given the velocities directly (no impulse; friction as the body has it), recorded at
    ``rate_hz`` for ``num_steps`` steps. Once the body has been at rest for ``physics.rest_duration`` the rest
    is padded with the resting pose and zero velocities.

    Returns ``com_position`` (T, 3), ``orientation_xyzw`` (T, 4) of the mesh frame, ``linear_velocity``
    (T, 3), ``angular_velocity`` (T, 3), ``topple_label`` (T,) bool (the 45 degree rule).
    """
    place_at_rest(world, body, spec, orientation_xyzw)
    pb.resetBaseVelocity(body, list(map(float, lin_vel)), list(map(float, ang_vel)), physicsClientId=world.client)
    traj = record(world, body, spec, rate_hz, max_frames=num_steps)
    out = {
        "com_position": traj.com_position,
        "orientation_xyzw": traj.orientation_xyzw,
        "linear_velocity": traj.linear_velocity,
        "angular_velocity": traj.angular_velocity,
    }
    pad = num_steps - len(traj)
    if pad > 0:
        for key in ("com_position", "orientation_xyzw"):
            out[key] = np.concatenate([out[key], np.repeat(out[key][-1:], pad, axis=0)])
        for key in ("linear_velocity", "angular_velocity"):
            out[key] = np.concatenate([out[key], np.zeros((pad, 3))])
    out["topple_label"] = topple_labels(out["orientation_xyzw"])[0]
    return out
