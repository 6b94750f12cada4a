"""The pushes a plan searches over. The push as the conventions define it, for a prepared body resting on the
ground: where a horizontal ray meets the surface, and the velocities right after a force over one physics
step there (``PushResponse``); the bounds of the search (``PushBounds``) and its coordinates (``PushSpace``).

``PushResponse`` keeps one PyBullet world with the body in it and answers each push by one physics step
(tens of microseconds), exactly as the dataset generator pushes (``physdyn.sim.trajectory.simulate``).
The ideal free-body formula (``free_body_velocities``: v = J / m, w = I^-1 (r x J)) ignores the ground,
which pushes back while the force acts: on 200 generator pushes of external meshes it was within 0.4 % (speed)
and 0.6 % (yaw rate) of PyBullet's at the median, but off by 4.5 % (horizontal speed) and
16 % (yaw rate) at the 90th percentile and by 0.76 rad/s (median) in tilt rate, the part that decides a
topple (docs/plan.md, "The push"). So the step is taken, not the formula.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from physdyn.config import ImpulseConfig, PhysicsConfig
from physdyn.errors import PredictionError
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.plan.goal import Goal
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


@dataclass(frozen=True)
class PushBounds:
    """The pushes searched over: speed (m/s, the speed change of a free body), the push point's height
    within the centre-of-mass height +/- ``height_fraction`` of the object's height, and its sideways offset
    up to ``lateral_fraction`` of the half-width. None: the training pushes' (``ImpulseConfig``)."""

    speed_min: float | None = None
    speed_max: float | None = None
    height_fraction: float | None = None
    lateral_fraction: float | None = None

    def resolved(self) -> tuple[float, float, float, float]:
        """(speed_min, speed_max, height_fraction, lateral_fraction), defaults filled in, or a one-line
        ``PredictionError``."""
        defaults = ImpulseConfig()
        values = []
        for name in ("speed_min", "speed_max", "height_fraction", "lateral_fraction"):
            value = getattr(self, name)
            value = getattr(defaults, name) if value is None else value
            try:
                values.append(float(value))
            except (TypeError, ValueError):
                raise PredictionError(f"{name} must be a number, got {value!r}") from None
            if not math.isfinite(values[-1]) or values[-1] < 0:
                raise PredictionError(f"{name} must be a finite number >= 0, got {value!r}")
        lo, hi, height, lateral = values
        if not 0 < lo <= hi <= 10.0:
            raise PredictionError(f"speed bounds must satisfy 0 < speed_min <= speed_max <= 10 m/s, got {lo:g} and {hi:g}")
        if height > 0.5 or lateral > 1.0:
            raise PredictionError(f"height_fraction must be at most 0.5 and lateral_fraction at most 1, got {height:g} and {lateral:g}")
        return lo, hi, height, lateral


class PushSpace:
    """Search coordinates u (B, 4) in [0, 1] -> pushes. u = (heading of the push / 2 pi, height in the band,
    sideways offset, speed): the point is where a horizontal ray at that height, offset sideways of the
    centre of mass by up to ``lateral_fraction`` of the half-width, meets the surface (as the generator
    draws it, ``physdyn.sim.impulse``); the band is the centre-of-mass height +/- ``height_fraction`` of the
    object's height; the impulse is mass x speed along the heading. ``bounds``: ``PushBounds.resolved()``."""

    def __init__(self, response: PushResponse, bounds: tuple[float, float, float, float]):
        speed_min, speed_max, height_fraction, lateral_fraction = bounds
        self.response = response
        self.speed = (speed_min, speed_max)
        top, com_z = response.top, float(response.com[2])
        lo = max(com_z - height_fraction * top, 0.05 * top)
        hi = min(com_z + height_fraction * top, 0.95 * top)
        self.height = (min(lo, hi), max(lo, hi))
        self.lateral_fraction = lateral_fraction

    def pushes(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """``push_direction``, ``push_point`` (B, 3) world; ``push_speed`` (B,); ``impulse`` (B, 3) N s;
        ``lin_vel``, ``ang_vel`` (B, 3): the state right after the push."""
        heading = 2.0 * np.pi * u[:, 0]
        direction = np.stack([np.cos(heading), np.sin(heading), np.zeros(len(u))], axis=1)
        height = self.height[0] + u[:, 1] * (self.height[1] - self.height[0])
        lateral = (2.0 * u[:, 2] - 1.0) * self.lateral_fraction * self.response.half_width(direction)
        speed = self.speed[0] + u[:, 3] * (self.speed[1] - self.speed[0])
        point = self.response.surface_points(direction, height, lateral)
        impulse = self.response.spec.mass * speed[:, None] * direction
        lin, ang = self.response.velocities(point, impulse)
        return {"push_direction": direction, "push_point": point, "push_speed": speed, "impulse": impulse,
                "lin_vel": lin, "ang_vel": ang}

    def toward(self, goal: Goal) -> np.ndarray:
        """(4,) search coordinates of a straight push toward the goal at the speed a Coulomb slide needs (at
        the push world's friction and gravity): where the first round's distribution is centred."""
        physics = self.response.world.physics
        friction, gravity = physics.lateral_friction_object * physics.lateral_friction_ground, physics.gravity
        heading = math.atan2(goal.xy[1], goal.xy[0]) % (2.0 * np.pi)
        speed = math.sqrt(2.0 * friction * abs(gravity) * float(np.linalg.norm(goal.xy)))
        s = np.clip((speed - self.speed[0]) / max(self.speed[1] - self.speed[0], 1e-9), 0.0, 1.0)
        return np.array([heading / (2.0 * np.pi), 0.5, 0.5, s])
