"""PyBullet on what a model sees: a rigid body made from a point cloud alone, rolled out from a given state.

A learned model receives the cloud (body frame, centre of mass at the origin) and the step-0 velocities.
The same information makes a simulator body: the cloud's convex hull as the collision shape (the
conventions' collision shape is the mesh's hull, and a dense surface cloud's hull is close to it), and the
body's own inertia where it is known (a store records it, a mesh gives it), else that of the hull as a
uniform solid about the known centre of mass (mass itself cancels out of rigid-body motion under Coulomb
friction). Two uses (measured in docs/research/simulated-start.md):

- ``CloudSimulator.max_tilt``: a short roll-out (1 s at 1/240 s) whose largest tilt tells the topple
  classifier what a step-0 summary cannot — how the tilt evolves against the edge;
- ``CloudSimulator.trajectories``: whole roll-outs, the ``cloud_sim`` baseline of ``physdyn test --cloud-sim``:
  what "just running the simulator" on the model's own input gives.

One PyBullet world is reused for every roll-out and one body per distinct cloud: creating a world per push
cost more than the roll-out itself.
"""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager
from dataclasses import replace
from typing import Iterator

import numpy as np
import trimesh

from physdyn.config import PhysicsConfig
from physdyn.errors import ShapeError
from physdyn.geometry.rotations import quat_multiply, quat_to_matrix
from physdyn.sim.bullet import pb
from physdyn.sim.body import RigidBodySpec
from physdyn.sim.trajectory import record, steps_per_frame
from physdyn.sim.world import PhysicsWorld

DENSITY = 1000.0  # kg/m^3; any value gives the same motion
# A coarser step than the data's 1/960 s: the roll-outs here are estimates from a cloud, and 1/240 s
# scored the same topple accuracy on the external validation set (0.933 against 0.942) at a third of the cost.
CLOUD_TIME_STEP = 1.0 / 240.0
MAX_SHAPES = 256  # collision shapes kept per world before it is rebuilt
_SPECS: dict[bytes, RigidBodySpec] = {}  # cloud (and inertia) -> body, for every simulator of the process
TILT_EVERY = 4  # physics steps between two readings of the tilt (60 Hz at 1/240 s)
TILT_HORIZONS_S = (0.25, 0.5, 1.0)  # s: the largest tilt within each, the topple classifier's physics features


def cloud_body_spec(points: np.ndarray, inertia_per_mass: np.ndarray | None = None) -> RigidBodySpec:
    """points: (N, 3) the cloud in the body frame (its origin is the centre of mass) -> the simulator's body:
    the cloud's convex hull, solid at uniform density, its inertia taken about the origin; or, where the
    body's own inertia is known (a mesh or a store carries it), ``inertia_per_mass`` (3, 3) in the cloud's
    axes (I / m; one that is not finite and positive definite is ignored). The hull misjudges hollow and concave solids: per unit mass 0.75-0.8x a mug's or a
    trash can's, up to 1.2x an irregular blob's (docs/research/simulated-start.md)."""
    try:
        hull = trimesh.convex.convex_hull(np.asarray(points, np.float64))
    except Exception as exc:  # qhull on a flat or degenerate cloud
        raise ShapeError(f"the point cloud has no 3D convex hull ({type(exc).__name__}); it must span a volume") from None
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat hull's centroid divides by its zero volume
        solid = hull.is_volume and hull.volume > 0
    if not solid:
        raise ShapeError("the point cloud has no 3D convex hull; it must span a volume")
    mass = DENSITY * float(hull.volume)
    d = np.asarray(hull.center_mass, np.float64)
    given = None if inertia_per_mass is None else np.asarray(inertia_per_mass, np.float64).reshape(3, 3)
    if given is not None and (not np.isfinite(given).all() or np.linalg.eigvalsh(given).min() <= 0):
        given = None  # a store or mesh without usable mass properties (NaN, zeros): the hull's, as the contact prior does
    if given is None:  # the hull's about its own centroid, moved to the cloud's origin (the centre of mass)
        inertia = DENSITY * np.asarray(hull.moment_inertia, np.float64) + mass * (d @ d * np.eye(3) - np.outer(d, d))
    else:
        inertia = mass * given
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return RigidBodySpec(mass=mass, inertia_diag=moments, principal_axes=axes, com_mesh=np.zeros(3),
                         hull_vertices=np.asarray(hull.vertices, np.float64) @ axes)


class CloudSimulator:
    """One PyBullet world for many roll-outs of cloud bodies (a context manager; ``close`` frees it).

    physics: the conventions' settings (friction is set per roll-out); its time step is replaced by
    ``time_step``.
    """

    def __init__(self, physics: PhysicsConfig | None = None, time_step: float = CLOUD_TIME_STEP):
        self.physics = replace(physics or PhysicsConfig(), time_step=float(time_step))
        self.world = PhysicsWorld(self.physics)
        self._bodies: dict[bytes, tuple[int, RigidBodySpec]] = {}  # cloud -> (collision shape, spec)

    def close(self) -> None:
        self.world.close()
        self._bodies.clear()

    def __enter__(self) -> "CloudSimulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _start(self, points: np.ndarray, orientation_xyzw: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray,
               friction: float, inertia_per_mass: np.ndarray | None = None) -> tuple[int, RigidBodySpec]:
        """The cloud's body alone on the ground, at rest in ``orientation_xyzw`` (mesh frame), centre of
        mass above the origin, given the velocities. Its hull shape is made once per distinct cloud (a
        batch often pushes one object many times); the caller removes the body after its roll-out."""
        points = np.asarray(points, np.float64)
        key = points.tobytes() + (
            b"" if inertia_per_mass is None else np.ascontiguousarray(inertia_per_mass, np.float64).tobytes())
        if key not in self._bodies and len(self._bodies) >= MAX_SHAPES:  # a long-lived simulator: start afresh
            self.world.close()
            self.world = PhysicsWorld(self.physics)
            self._bodies.clear()
        if key not in self._bodies:
            spec = _SPECS.get(key)
            if spec is None:  # the hull is the costly part (2.6 ms for 1,024 points): shared by every simulator
                if len(_SPECS) >= 4 * MAX_SHAPES:
                    _SPECS.clear()
                spec = _SPECS[key] = cloud_body_spec(points, inertia_per_mass)
            self._bodies[key] = (self.world.collision_shape(spec), spec)
        shape, spec = self._bodies[key]
        body = self.world.add_body(spec, shape)
        cid = self.world.client
        q_base = quat_multiply(np.asarray(orientation_xyzw, np.float64), spec.principal_quat_xyzw)
        world_vertices = spec.body_vertices() @ quat_to_matrix(orientation_xyzw).T
        pb.resetBasePositionAndOrientation(body, [0.0, 0.0, float(-world_vertices[:, 2].min())], q_base.tolist(),
                                           physicsClientId=cid)
        pb.resetBaseVelocity(body, [float(x) for x in lin_vel], [float(x) for x in ang_vel], physicsClientId=cid)
        self.world.set_object_friction(body, float(friction) / self.physics.lateral_friction_ground)
        return body, spec

    def max_tilt(self, points: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray, friction: float,
                 inertia_per_mass: np.ndarray | None = None, horizons_s: tuple[float, ...] = TILT_HORIZONS_S) -> np.ndarray:
        """The largest tilt (deg) of the initial up direction within each horizon of a roll-out.

        points: (B, N, 3) each cloud in its step-0 *world* orientation, centre of mass at the origin;
        velocities (B, 3) world frame; ``inertia_per_mass``: optional (B, 3, 3) each body's own I / m in
        those world axes (default: the hull's) -> (B, len(horizons_s)). The tilt is read every ``TILT_EVERY``
        physics steps (60 Hz). A roll-out stops once the body lies past 90 degrees (it has toppled) or
        rests; later horizons then keep the largest tilt so far.
        """
        v0 = np.asarray(lin_vel, np.float64).reshape(-1, 3)
        w0 = np.asarray(ang_vel, np.float64).reshape(-1, 3)
        dt = self.physics.time_step
        ends = [max(1, int(round(h / (dt * TILT_EVERY)))) for h in horizons_s]
        out = np.zeros((len(points), len(horizons_s)))
        rest_v2, rest_w2 = self.physics.rest_linear_speed ** 2, self.physics.rest_angular_speed ** 2
        for b in range(len(points)):
            body, spec = self._start(points[b], np.array([0.0, 0.0, 0.0, 1.0]), v0[b], w0[b], friction,
                                     None if inertia_per_mass is None else inertia_per_mass[b])
            cid = self.world.client  # after _start: it may have rebuilt the world
            # the initial up direction (world z at step 0) in the base frame: the principal axes' z components
            up = spec.principal_axes[2]
            largest, k, h = 0.0, 0, 0
            try:
                while k < ends[-1]:
                    self.world.step(TILT_EVERY)
                    k += 1
                    m = pb.getMatrixFromQuaternion(pb.getBasePositionAndOrientation(body, physicsClientId=cid)[1])
                    cos_tilt = m[6] * up[0] + m[7] * up[1] + m[8] * up[2]
                    largest = max(largest, math.degrees(math.acos(max(-1.0, min(1.0, cos_tilt)))))
                    while h < len(ends) and k >= ends[h]:
                        out[b, h] = largest
                        h += 1
                    if largest > 90.0:
                        break
                    v, w = pb.getBaseVelocity(body, physicsClientId=cid)
                    if v[0] ** 2 + v[1] ** 2 + v[2] ** 2 < rest_v2 and w[0] ** 2 + w[1] ** 2 + w[2] ** 2 < rest_w2:
                        break
            finally:  # a body left behind would stand in the next roll-out's way
                self.world.remove_body(body)
            out[b, h:] = largest
        return out

    def trajectories(self, points: np.ndarray, orientation_xyzw: np.ndarray, com_position: np.ndarray,
                     lin_vel: np.ndarray, ang_vel: np.ndarray, friction: np.ndarray, steps: int, rate_hz: float,
                     inertia_per_mass: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Whole roll-outs recorded at ``rate_hz``, one push at a time.

        points: (B, N, 3) body frame; orientation (B, 4) mesh frame, com_position (B, 3), velocities (B, 3):
        step 0, world frame; friction (B,) Coulomb mu; inertia_per_mass: optional (B, 3, 3) in body axes.
        Each body starts at rest in its orientation on the ground (lowest hull point at z = 0), given the
        velocities, and is recorded for ``steps`` transitions; once it has rested ``rest_duration`` the rest
        is padded with its resting pose. Positions are shifted so step 0 is ``com_position``. Returns
        ``com_position`` (B, T, 3), ``orientation_xyzw`` (B, T, 4), ``linear_velocity`` and
        ``angular_velocity`` (B, T, 3), T = steps + 1.
        """
        q0 = np.asarray(orientation_xyzw, np.float64).reshape(-1, 4)
        p0 = np.asarray(com_position, np.float64).reshape(-1, 3)
        v0 = np.asarray(lin_vel, np.float64).reshape(-1, 3)
        w0 = np.asarray(ang_vel, np.float64).reshape(-1, 3)
        mu = np.broadcast_to(np.asarray(friction, np.float64), (len(points),))
        T = int(steps) + 1
        steps_per_frame(self.physics.time_step, rate_hz)  # a rate the physics step does not divide: refused before any body
        out = {"com_position": np.zeros((len(points), T, 3)), "orientation_xyzw": np.zeros((len(points), T, 4)),
               "linear_velocity": np.zeros((len(points), T, 3)), "angular_velocity": np.zeros((len(points), T, 3))}
        for b in range(len(points)):
            body, spec = self._start(points[b], q0[b], v0[b], w0[b], mu[b],
                                     None if inertia_per_mass is None else inertia_per_mass[b])
            try:
                traj = record(self.world, body, spec, rate_hz, max_frames=T)
            finally:
                self.world.remove_body(body)
            n = len(traj)
            out["com_position"][b, :n] = traj.com_position - traj.com_position[0] + p0[b]
            out["orientation_xyzw"][b, :n] = traj.orientation_xyzw
            out["linear_velocity"][b, :n] = traj.linear_velocity
            out["angular_velocity"][b, :n] = traj.angular_velocity
            out["com_position"][b, n:] = out["com_position"][b, n - 1]
            out["orientation_xyzw"][b, n:] = traj.orientation_xyzw[-1]
        return out


_SHARED: dict[float, CloudSimulator] = {}
_SHARED_LOCK = threading.Lock()  # one PyBullet client is not to be stepped from two threads at once


@contextmanager
def shared_simulator(time_step: float = CLOUD_TIME_STEP) -> Iterator[CloudSimulator]:
    """The process's ``CloudSimulator`` of this physics step, held for the caller alone while in use:
    predictions reuse one world and its hull shapes (connecting a world cost more than a roll-out)."""
    with _SHARED_LOCK:
        if time_step not in _SHARED:
            _SHARED[time_step] = CloudSimulator(time_step=time_step)
        yield _SHARED[time_step]


def forget_clouds() -> None:
    """Drop every cloud body this process keeps (hulls and collision shapes, keyed by content), so the next
    cloud is built afresh: a benchmark of meshes new to physdyn must not find them prepared."""
    with _SHARED_LOCK:
        _SPECS.clear()
        for simulator in _SHARED.values():
            simulator.world.close()
            simulator.world = PhysicsWorld(simulator.physics)
            simulator._bodies.clear()
