"""The push as the conventions define it, for a prepared body resting on the ground: where a horizontal
ray meets the surface, and the velocities right after a force over one physics step there.

``PushResponse`` keeps one PyBullet world with the body in it and answers each push by one physics step
(tens of microseconds), exactly as the dataset generator pushes (``physdyn.sim.trajectory.simulate``).
The ideal free-body formula (``free_body_velocities``: v = J / m, w = I^-1 (r x J)) ignores the ground,
which pushes back while the force acts: on 200 generator pushes of external meshes it was within 0.4 % (speed)
and 0.6 % (yaw rate) of PyBullet's at the median, but off by 4.5 % (horizontal speed) and
16 % (yaw rate) at the 90th percentile and by 0.76 rad/s (median) in tilt rate, the part that decides a
topple (docs/plan.md, "The push"). So the step is taken, not the formula.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from physdyn.config import PhysicsConfig
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.sim.bullet import pb
from physdyn.sim.trajectory import place_at_rest
from physdyn.sim.world import PhysicsWorld

# A point of the band whose ray misses the hull (a narrow top, a lateral offset past the edge) is moved
# toward the centre-of-mass column, as the generator does (``physdyn.sim.impulse.push_point``).
LATERAL_RETRIES = (1.0, 0.5, 0.25, 0.0)


def free_body_velocities(spec: Any, orientation_xyzw: np.ndarray, com: np.ndarray, points: np.ndarray,
                         impulses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ideal rigid-body response to impulses J (B, 3) N s at world points (B, 3) of a free body (no
    ground): v = J / m, w = I_world^-1 ((p - com) x J). Returns (v, w), each (B, 3), world frame."""
    R = quat_to_matrix(np.asarray(orientation_xyzw, dtype=np.float64)) @ spec.principal_axes
    inertia = R @ np.diag(spec.inertia_diag) @ R.T
    torque = np.cross(np.asarray(points) - np.asarray(com), impulses)
    return np.asarray(impulses) / spec.mass, np.linalg.solve(inertia, torque.T).T


class PushResponse:
    """One body resting in one orientation, in a PyBullet world of its own, pushed again and again.

    spec: the body's ``RigidBodySpec``; orientation_xyzw: its resting orientation (mesh frame);
    physics: a ``PhysicsConfig`` (default: the conventions'). Use as a context manager, or ``close()``.
    """

    def __init__(self, spec: Any, orientation_xyzw: np.ndarray, physics: PhysicsConfig | None = None):
        self.spec = spec
        self.orientation_xyzw = np.asarray(orientation_xyzw, dtype=np.float64)
        self.world = PhysicsWorld(physics or PhysicsConfig())
        self.body = self.world.add_body(spec)
        self.com = place_at_rest(self.world, self.body, spec, self.orientation_xyzw)
        # PyBullet's base frame is the principal frame (``place_at_rest``): kept to reset it cheaply per push
        self._base_pose = pb.getBasePositionAndOrientation(self.body, physicsClientId=self.world.client)
        vertices = spec.body_vertices() @ quat_to_matrix(self.orientation_xyzw).T + self.com
        self.top = float(vertices[:, 2].max())  # height of the highest point, m
        self._vertices = vertices
        self._reach = 2.0 * float(np.linalg.norm(spec.hull_vertices, axis=1).max()) + 0.1

    def half_width(self, directions: np.ndarray) -> np.ndarray:
        """(B,) how far the body reaches sideways of each horizontal push direction (B, 3), m."""
        side = np.stack([-directions[:, 1], directions[:, 0], np.zeros(len(directions))], axis=1)
        return np.abs((self._vertices - self.com) @ side.T).max(axis=0)

    def surface_points(self, directions: np.ndarray, heights: np.ndarray, laterals: np.ndarray) -> np.ndarray:
        """(B, 3) world points where horizontal rays along ``directions`` (B, 3), at world heights ``heights``
        (B,) and offset sideways of the centre of mass by ``laterals`` (B,) m, first meet the hull. A ray that
        misses is tried again with the offset halved, then through the centre-of-mass column (which meets a
        convex hull at any height inside it)."""
        self._rest()
        directions = np.asarray(directions, dtype=np.float64)
        side = np.stack([-directions[:, 1], directions[:, 0], np.zeros(len(directions))], axis=1)
        points = np.full((len(directions), 3), np.nan)
        todo = np.arange(len(directions))
        for fraction in LATERAL_RETRIES:
            if not len(todo):
                break
            centre = np.column_stack([np.full(len(todo), self.com[0]), np.full(len(todo), self.com[1]), heights[todo]])
            centre = centre + (fraction * laterals[todo])[:, None] * side[todo]
            starts, ends = centre - self._reach * directions[todo], centre + self._reach * directions[todo]
            hits = pb.rayTestBatch(starts.tolist(), ends.tolist(), physicsClientId=self.world.client)
            missed = []
            for i, hit in zip(todo, hits):
                if hit[0] == self.body:
                    points[i] = hit[3]
                else:
                    missed.append(i)
            todo = np.asarray(missed, dtype=int)
        if len(todo):  # impossible for a convex hull at a height inside it; a bug if seen
            raise RuntimeError(f"push rays missed the hull at heights {heights[todo][:3]}")
        return points

    def velocities(self, points: np.ndarray, impulses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state right after each push: impulse J (B, 3) N s at world point (B, 3) applied as a force
        J / dt over one physics step from rest, the ground reacting. Returns (lin_vel, ang_vel), each (B, 3),
        world frame: what ``Predictor.predict`` takes and what a store records at step 0."""
        cid = self.world.client
        dt = self.world.physics.time_step
        lin, ang = np.empty((len(points), 3)), np.empty((len(points), 3))
        for i, (point, impulse) in enumerate(zip(np.asarray(points, dtype=np.float64), np.asarray(impulses, dtype=np.float64))):
            self._rest()
            pb.applyExternalForce(self.body, -1, (impulse / dt).tolist(), point.tolist(), pb.WORLD_FRAME, physicsClientId=cid)
            self.world.step(1)
            v, w = pb.getBaseVelocity(self.body, physicsClientId=cid)
            lin[i], ang[i] = v, w
        self._rest()
        return lin, ang

    def _rest(self) -> None:
        cid = self.world.client
        pb.resetBasePositionAndOrientation(self.body, *self._base_pose, physicsClientId=cid)
        pb.resetBaseVelocity(self.body, [0, 0, 0], [0, 0, 0], physicsClientId=cid)

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> "PushResponse":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
