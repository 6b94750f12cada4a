"""Random initial conditions: resting pose, yaw, push point, push direction and strength, friction."""

from __future__ import annotations

import numpy as np

from physdyn.config import DataConfig
from physdyn.geometry.rotations import matrix_to_quat, quat_multiply
from physdyn.sim.body import RigidBodySpec
from physdyn.sim.bullet import pb
from physdyn.sim.trajectory import InitialCondition, resting_com_position
from physdyn.sim.world import PhysicsWorld


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def push_point(world: PhysicsWorld, body: int, spec: RigidBodySpec, orientation: np.ndarray, com: np.ndarray,
               direction: np.ndarray, height: float, lateral: float) -> np.ndarray:
    """The first point of the collision hull met by a horizontal ray along ``direction`` at ``height``
    (world z) offset sideways by ``lateral`` from the centre of mass. Halves the offset until the ray hits;
    the ray through the centre-of-mass column always hits a convex hull at a height inside it."""

    base_orientation = quat_multiply(orientation, spec.principal_quat_xyzw)
    pb.resetBasePositionAndOrientation(body, com.tolist(), base_orientation.tolist(), physicsClientId=world.client)
    side = np.array([-direction[1], direction[0], 0.0])
    reach = 2.0 * float(np.linalg.norm(spec.hull_vertices, axis=1).max()) + 0.1
    for scale in (1.0, 0.5, 0.25, 0.0):
        centre = np.array([com[0], com[1], height]) + scale * lateral * side
        hit = world.ray_hit(body, centre - reach * direction, centre + reach * direction)
        if hit is not None:
            return hit
    raise RuntimeError("push ray missed the object's hull")  # impossible for a convex hull; a bug if seen


def sample_initial_condition(rng: np.random.Generator, world: PhysicsWorld, body: int, spec: RigidBodySpec,
                             rest_rotations: np.ndarray, rest_probabilities: np.ndarray, cfg: DataConfig) -> tuple[InitialCondition, dict]:
    """Draw one push as the paper does: a stable pose by probability, a random yaw, a horizontal push at a
    surface point near the centre-of-mass height, impulse = mass x a random speed. Returns the condition
    and the drawn values for the record (pose index, yaw, speed)."""
    pose = int(rng.choice(len(rest_probabilities), p=rest_probabilities))
    yaw = float(rng.uniform(0.0, 2.0 * np.pi))
    rotation = yaw_matrix(yaw) @ rest_rotations[pose]
    orientation = matrix_to_quat(rotation)
    com = resting_com_position(spec, orientation)

    world_vertices = spec.body_vertices() @ rotation.T + com
    top = float(world_vertices[:, 2].max())
    heading = float(rng.uniform(0.0, 2.0 * np.pi))
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    side = np.array([-direction[1], direction[0], 0.0])
    height = com[2] + float(rng.uniform(-1.0, 1.0)) * cfg.impulse.height_fraction * top
    height = float(np.clip(height, 0.05 * top, 0.95 * top))
    half_width = float(np.abs((world_vertices - com) @ side).max())
    lateral = float(rng.uniform(-1.0, 1.0)) * cfg.impulse.lateral_fraction * half_width
    speed = float(rng.uniform(cfg.impulse.speed_min, cfg.impulse.speed_max))
    if cfg.friction.random:
        friction = float(rng.uniform(cfg.friction.min, cfg.friction.max))
    else:
        friction = cfg.physics.lateral_friction_object * cfg.physics.lateral_friction_ground

    point = push_point(world, body, spec, orientation, com, direction, height, lateral)
    init = InitialCondition(orientation, spec.mass * speed * direction, point, friction)
    return init, {"pose_index": pose, "yaw": yaw, "speed": speed}
