"""The simulator beside the model (``compare_sim=True``, ``physdyn predict --compare-sim``): PyBullet started
from the state the model starts from, recorded at the model's rate."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from physdyn.config import PhysicsConfig
from physdyn.sim.trajectory import record_from_state
from physdyn.sim.world import PhysicsWorld

SIMULATOR_NAME = "pybullet"  # the ``checkpoint`` key of a simulated result


def simulate_from_state(spec: Any, orientation_xyzw: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray,
                        rate_hz: float, num_steps: int, physics: Any = None, friction: float | None = None) -> dict[str, np.ndarray]:
    """PyBullet from the state right after a push: the body at rest in ``orientation_xyzw`` (mesh frame),
    given the velocities directly (no impulse), recorded at ``rate_hz`` for ``num_steps`` steps. ``friction``:
    the effective Coulomb coefficient with the ground (the object's lateral friction set so that its product
    with the ground's is it; None: ``physics``').

    Once the body has been at rest for ``physics.rest_duration`` the rest is padded with the resting pose
    and zero velocities. Returns ``com_position`` (T, 3), ``orientation_xyzw`` (T, 4) of the mesh frame,
    ``linear_velocity`` (T, 3), ``angular_velocity`` (T, 3), ``topple_label`` (T,) bool (the 45° rule).
    """

    physics = physics or PhysicsConfig()
    if friction is not None:
        physics = dataclasses.replace(physics, lateral_friction_object=float(friction) / physics.lateral_friction_ground)
    with PhysicsWorld(physics) as world:
        body = world.add_body(spec)
        return record_from_state(world, body, spec, orientation_xyzw, lin_vel, ang_vel, rate_hz, num_steps)
