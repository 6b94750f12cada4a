"""One PyBullet client with a ground plane, set up to the physics config."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from physdyn.sim.bullet import pb

from physdyn.config import PhysicsConfig
from physdyn.sim.body import RigidBodySpec


class PhysicsWorld:
    """A headless PyBullet world: z up, the ground is the plane z = 0.

    PyBullet's own inertia estimate for a mesh comes from its bounding box with wrong axes, so bodies get
    their mass, principal moments and principal frame set explicitly; with the collision hull expressed in
    the principal frame, PyBullet's base frame *is* the inertial frame and no conversion is needed.
    """

    def __init__(self, physics: PhysicsConfig):
        self.physics = physics
        self.client = pb.connect(pb.DIRECT)
        pb.setGravity(0, 0, physics.gravity, physicsClientId=self.client)
        pb.setTimeStep(physics.time_step, physicsClientId=self.client)
        self._substeps = 1
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=self.client)
        self.ground = pb.createMultiBody(0, plane, physicsClientId=self.client)
        pb.changeDynamics(
            self.ground,
            -1,
            lateralFriction=physics.lateral_friction_ground,
            rollingFriction=physics.rolling_friction_ground,
            spinningFriction=physics.spinning_friction,
            restitution=physics.restitution,
            physicsClientId=self.client,
        )

    def collision_shape(self, spec: RigidBodySpec) -> int:
        """The body's convex hull as a collision shape of this world (reusable by ``add_body``)."""
        return pb.createCollisionShape(pb.GEOM_MESH, vertices=spec.hull_vertices.tolist(), physicsClientId=self.client)

    def add_body(self, spec: RigidBodySpec, shape: int | None = None) -> int:
        """A body of ``spec`` (mass properties set explicitly); ``shape``: its ``collision_shape`` made before."""
        if shape is None:
            shape = self.collision_shape(spec)
        body = pb.createMultiBody(
            baseMass=spec.mass,
            baseCollisionShapeIndex=shape,
            baseInertialFramePosition=[0, 0, 0],
            baseInertialFrameOrientation=[0, 0, 0, 1],
            basePosition=[0, 0, 1],
            physicsClientId=self.client,
        )
        p = self.physics
        pb.changeDynamics(
            body,
            -1,
            mass=spec.mass,
            localInertiaDiagonal=spec.inertia_diag.tolist(),
            lateralFriction=p.lateral_friction_object,
            rollingFriction=p.rolling_friction_object,
            spinningFriction=p.spinning_friction,
            linearDamping=p.linear_damping,
            angularDamping=p.angular_damping,
            restitution=p.restitution,
            physicsClientId=self.client,
        )
        return body

    def step(self, substeps: int = 1) -> None:
        """Advance ``substeps`` physics steps of ``time_step`` in one call.

        Bullet's sub-stepping runs the same fixed steps as that many single calls (bitwise the same
        states, measured) without a Python round trip each: at the 1/960 s step the per-call overhead was
        ~17 % of the simulation time. An external force lasts one call, so pushes use ``substeps=1``.
        """
        if substeps != self._substeps:
            pb.setPhysicsEngineParameter(fixedTimeStep=self.physics.time_step * substeps, numSubSteps=substeps,
                                         physicsClientId=self.client)
            self._substeps = substeps
        pb.stepSimulation(physicsClientId=self.client)

    def set_time_step(self, time_step: float) -> None:
        """Step at ``time_step`` from now on (a body keeps its state): a run can take a fine step while the
        contact settles and a coarse one after (benchmarks/frontier.py's step schedule)."""
        if not np.isfinite(time_step) or time_step <= 0:
            raise ValueError(f"time_step must be a positive number of seconds, got {time_step}")
        self.physics = replace(self.physics, time_step=float(time_step))
        # as a new world steps: one physics step a call, no sub-stepping (setTimeStep alone would keep it)
        pb.setPhysicsEngineParameter(fixedTimeStep=self.physics.time_step, numSubSteps=0, physicsClientId=self.client)
        self._substeps = 1

    def remove_body(self, body: int) -> None:
        pb.removeBody(body, physicsClientId=self.client)

    def set_object_friction(self, body: int, lateral: float) -> None:
        pb.changeDynamics(body, -1, lateralFriction=lateral, physicsClientId=self.client)

    def ray_hit(self, body: int, start: np.ndarray, end: np.ndarray) -> np.ndarray | None:
        """First point where the segment start->end hits ``body``, or None."""
        hit = pb.rayTest(start.tolist(), end.tolist(), physicsClientId=self.client)[0]
        return np.asarray(hit[3]) if hit[0] == body else None

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None

    def __enter__(self) -> "PhysicsWorld":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
