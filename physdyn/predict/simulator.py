"""The simulator beside the model (``compare_sim=True``, ``physdyn predict --compare-sim``): PyBullet started
from the state the model starts from, recorded at the model's rate."""

from __future__ import annotations

from typing import Any

import numpy as np

from physdyn.config import PhysicsConfig
from physdyn.sim.bullet import pb
from physdyn.sim.trajectory import place_at_rest, record, topple_labels
from physdyn.sim.world import PhysicsWorld

SIMULATOR_NAME = "pybullet"  # the ``checkpoint`` key of a simulated result


def simulate_from_state(spec: Any, orientation_xyzw: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray,
                        rate_hz: float, num_steps: int, physics: Any = None) -> dict[str, np.ndarray]:
    """PyBullet from the state right after a push: the body at rest in ``orientation_xyzw`` (mesh frame),
    given the velocities directly (no impulse), recorded at ``rate_hz`` for ``num_steps`` steps.

    Once the body has been at rest for ``physics.rest_duration`` the rest is padded with the resting pose
    and zero velocities. Returns ``com_position`` (T, 3), ``orientation_xyzw`` (T, 4) of the mesh frame,
    ``linear_velocity`` (T, 3), ``angular_velocity`` (T, 3), ``topple_label`` (T,) bool (the 45° rule).
    """

    phys = physics or PhysicsConfig()
    with PhysicsWorld(phys) as world:
        body = world.add_body(spec)
        place_at_rest(world, body, spec, orientation_xyzw)
        pb.resetBaseVelocity(body, list(map(float, lin_vel)), list(map(float, ang_vel)), physicsClientId=world.client)
        traj = record(world, body, spec, rate_hz, max_frames=num_steps)
    out = {
        "com_position": traj.com_position,
        "orientation_xyzw": traj.orientation_xyzw,
        "linear_velocity": traj.linear_velocity,
        "angular_velocity": traj.angular_velocity,
    }
    recorded = len(traj)
    if recorded < num_steps:
        pad = num_steps - recorded
        for key in ("com_position", "orientation_xyzw"):
            out[key] = np.concatenate([out[key], np.repeat(out[key][-1:], pad, axis=0)])
        for key in ("linear_velocity", "angular_velocity"):
            out[key] = np.concatenate([out[key], np.zeros((pad, 3))])
    out["topple_label"] = topple_labels(out["orientation_xyzw"])[0]
    return out
