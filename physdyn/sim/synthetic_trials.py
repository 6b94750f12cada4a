"""Motion-capture-like trials from the simulator, to check `physdyn import-mocap` without a tracker.

A trial is what a tracker would record of a hand push (docs/real-world.md): the object rests on the floor
for a few hundred ms, a horizontal force at the centre-of-mass height ramps up over 0.15-0.3 s and is then
released, and the object slides (and maybe spins) to rest. It is written as the import reads it — one CSV
per trial, header ``time,x,y,z,qx,qy,qz,qw``, 120 Hz (physics step 1/960 s, every 8th step recorded), the
pose of the *mesh frame* with tracking noise and a floor offset — plus a sidecar ``<trial>.truth.npz``
holding the simulator's noiseless poses, true velocities and the release time.

This module also holds the *tracked shape* (``TrackedShape``): the shape a trial is of, shared with the
import (physdyn.data.mocap_import), since both need its mass properties, hull and point cloud.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from physdyn.config import MassConfig, PhysicsConfig
from physdyn.errors import PhysdynError, ShapeError
from physdyn.files import atomic_output
from physdyn.geometry.mesh_io import load_mesh
from physdyn.geometry.poses import stable_orientations
from physdyn.geometry.rotations import canonical_quat, continuous_quat, matrix_to_quat, quat_conjugate, quat_multiply, quat_to_matrix, rotvec_to_quat
from physdyn.sim.body import RigidBodySpec, body_surface_points, rigid_body
from physdyn.sim.bullet import pb
from physdyn.sim.impulse import yaw_matrix
from physdyn.sim.trajectory import place_at_rest
from physdyn.sim.world import PhysicsWorld

CSV_HEADER = "time,x,y,z,qx,qy,qz,qw"
PAPER_BOX = (0.073, 0.060, 0.170)  # m, the supplement's cardboard box
DEFAULT_DENSITY = MassConfig.density  # kg/m^3, as the simulated datasets
MAX_FLOOR_OFFSET = 10.0  # m: a tracker origin off the floor by more is a unit mistake


# --------------------------------------------------------------------------------------------------
# The tracked shape
# --------------------------------------------------------------------------------------------------
@dataclass
class TrackedShape:
    """A rigid shape whose mesh frame is the tracked body frame.

    mesh: the cleaned mesh, mesh frame; source: ``box:W,D,H`` or the file; spec: mass, principal frame and
    hull (physdyn.sim.body); com_mesh (3,): centre of mass in mesh coordinates; volume (m^3).
    """

    mesh: trimesh.Trimesh
    source: str
    spec: RigidBodySpec
    com_mesh: np.ndarray
    volume: float

    def lowest_vertex_z(self, com_position: np.ndarray, orientation_xyzw: np.ndarray) -> np.ndarray:
        """World z of the lowest hull vertex at each pose: com_position (T, 3), orientation (T, 4) -> (T,)."""
        R = quat_to_matrix(orientation_xyzw)  # (T, 3, 3)
        z = np.einsum("tj,vj->tv", R[:, 2, :], self.spec.body_vertices()) + com_position[:, 2:3]
        return z.min(axis=1)

    def surface_points(self, num_points: int = 1024, oversample: int = 3, seed: int = 0) -> np.ndarray:
        """(num_points, 3) float32 surface points in the body frame, sampled as the simulator samples them."""
        return body_surface_points(self.mesh, self.spec, num_points, oversample, seed)


def parse_box(text: str) -> tuple[float, float, float]:
    """``box:W,D,H`` (metres) -> (W, D, H); a one-line ShapeError naming the fix otherwise."""
    kind, _, dims = str(text).partition(":")
    if kind.strip().lower() != "box" or not dims:
        raise ShapeError(f"--shape '{text}': expected box:W,D,H in metres, e.g. box:0.073,0.060,0.170 (or use --mesh FILE)")
    try:
        values = tuple(float(v) for v in dims.split(","))
    except ValueError:
        raise ShapeError(f"--shape '{text}': W,D,H must be numbers in metres, e.g. box:0.073,0.060,0.170") from None
    if len(values) != 3 or not all(np.isfinite(v) and v > 0 for v in values):
        raise ShapeError(f"--shape '{text}': need box:W,D,H with three positive sizes in metres, e.g. box:0.073,0.060,0.170")
    return values  # type: ignore[return-value]


def tracked_shape(box: str | None = None, mesh_path: str | None = None, scale: float = 1.0,
                  density: float = DEFAULT_DENSITY) -> TrackedShape:
    """The tracked shape from ``--shape box:W,D,H`` (a box centred at its mesh origin, edges along the mesh
    axes) or ``--mesh FILE`` (read in its own frame, times ``scale``). Mass at uniform ``density``."""

    if (box is None) == (mesh_path is None):
        raise ShapeError("give the tracked shape with exactly one of --shape box:W,D,H or --mesh FILE")
    if box is not None:
        mesh = trimesh.creation.box(extents=parse_box(box))
        source = "box:" + ",".join(f"{v:g}" for v in parse_box(box))
    else:
        mesh = load_mesh(mesh_path, scale)
        source = str(mesh_path) + (f" x{scale:g}" if scale != 1.0 else "")
    body = rigid_body(mesh, source, density)
    return TrackedShape(mesh=body.mesh, source=source, spec=body.spec, com_mesh=body.spec.com_mesh,
                        volume=float(body.props.volume))


# --------------------------------------------------------------------------------------------------
# Synthetic trials
# --------------------------------------------------------------------------------------------------
@dataclass
class SyntheticSettings:
    """How synthetic trials are drawn. Times in s, speeds in m/s, noise as RMS magnitudes."""

    rate_hz: float = 120.0
    rest_before: tuple[float, float] = (0.2, 0.5)
    push_duration: tuple[float, float] = (0.15, 0.3)
    release_speed: tuple[float, float] = (0.5, 1.5)
    lateral_fraction: float = 0.3  # push offset sideways from the centre of mass, x half-width (spin)
    position_noise_m: float = 0.5e-3
    rotation_noise_deg: float = 0.5
    floor_offset_m: float = 0.0  # added to every z: the tracker's origin need not be on the floor
    rest_after: float = 0.7  # s recorded once the object is at rest
    max_duration: float = 5.0  # s after the release


@dataclass
class SyntheticTrial:
    """One trial at the tracker's rate. time (N,); true com_position (N, 3), orientation_xyzw (N, 4) of the
    mesh frame, linear/angular_velocity (N, 3) world frame; csv_position (N, 3), csv_orientation (N, 4):
    what the tracker reports (mesh-frame origin, noise, floor offset); push_start / release: times (s)."""

    time: np.ndarray
    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    csv_position: np.ndarray
    csv_orientation: np.ndarray
    push_start: float
    release: float
    friction: float
    floor_offset: float


def ramp_acceleration(speed: float, duration: float, mu_g: float) -> float:
    """Peak force per mass a of a linear ramp F(t) = m a t / D that leaves a body sliding against Coulomb
    friction (mu g) at ``speed`` when released at t = D: v = (a - mu g)^2 D / (2 a), solved for a."""
    b = mu_g * duration + speed
    return (b + np.sqrt(b * b - (mu_g * duration) ** 2)) / duration


def simulate_trial(world, body: int, shape: TrackedShape, rng: np.random.Generator,
                   settings: SyntheticSettings = SyntheticSettings()) -> SyntheticTrial:
    """One push of ``shape`` (already added to ``world`` as ``body``) recorded like a tracker would."""

    phys, cid, spec = world.physics, world.client, shape.spec
    every = int(round(1.0 / (phys.time_step * settings.rate_hz)))
    rotations, probabilities = stable_orientations(shape.mesh, shape.com_mesh)
    pose = int(rng.choice(len(probabilities), p=probabilities))
    q_mesh = matrix_to_quat(yaw_matrix(float(rng.uniform(0, 2 * np.pi))) @ rotations[pose])
    com0 = place_at_rest(world, body, spec, q_mesh)
    mu = phys.lateral_friction_object * phys.lateral_friction_ground

    heading = float(rng.uniform(0, 2 * np.pi))
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    side = np.array([-direction[1], direction[0], 0.0])
    world_vertices = spec.body_vertices() @ quat_to_matrix(q_mesh).T
    offset = float(rng.uniform(-1, 1)) * settings.lateral_fraction * float(np.abs(world_vertices @ side).max())
    # Whole recorded samples, so the release falls exactly on a tracker sample.
    sample_dt = every * phys.time_step
    rest_samples = int(round(rng.uniform(*settings.rest_before) / sample_dt))
    push_samples = max(1, int(round(rng.uniform(*settings.push_duration) / sample_dt)))
    duration = push_samples * sample_dt
    peak = ramp_acceleration(float(rng.uniform(*settings.release_speed)), duration, mu * abs(phys.gravity)) * spec.mass
    push_start_step, release_step = rest_samples * every, (rest_samples + push_samples) * every

    rest_needed = int(np.ceil(settings.rest_after / phys.time_step))
    max_steps = release_step + int(settings.max_duration / phys.time_step)
    q_principal_inv = quat_conjugate(spec.principal_quat_xyzw)
    rec: dict[str, list] = {"p": [], "q": [], "v": [], "w": []}
    step, rest = 0, 0
    while True:
        if step % every == 0:
            pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
            v, w = pb.getBaseVelocity(body, physicsClientId=cid)
            for key, val in zip("pqvw", (pos, orn, v, w)):
                rec[key].append(val)
            if step >= release_step and (rest >= rest_needed or step >= max_steps):
                break
        if push_start_step <= step < release_step:
            ramp = (step - push_start_step + 1) / (release_step - push_start_step)
            pos, _ = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
            point = np.asarray(pos) + offset * side
            pb.applyExternalForce(body, -1, (peak * ramp * direction).tolist(), point.tolist(), pb.WORLD_FRAME, physicsClientId=cid)
        world.step(1)
        step += 1
        v, w = pb.getBaseVelocity(body, physicsClientId=cid)
        at_rest = np.linalg.norm(v) < phys.rest_linear_speed and np.linalg.norm(w) < phys.rest_angular_speed
        rest = rest + 1 if (at_rest and step > release_step) else 0

    com = np.asarray(rec["p"], dtype=np.float64)
    q_true = canonical_quat(quat_multiply(np.asarray(rec["q"]), q_principal_inv))
    q_true /= np.linalg.norm(q_true, axis=1, keepdims=True)
    n = len(com)
    time = np.arange(n) * sample_dt
    # The tracker reports the mesh frame's origin: com - R com_mesh.
    origin = com - np.einsum("tij,j->ti", quat_to_matrix(q_true), shape.com_mesh)
    noise_p = rng.normal(0.0, settings.position_noise_m / np.sqrt(3), (n, 3))
    noise_r = rng.normal(0.0, np.deg2rad(settings.rotation_noise_deg) / np.sqrt(3), (n, 3))
    csv_q = quat_multiply(rotvec_to_quat(noise_r), q_true)
    csv_q = continuous_quat(csv_q)
    csv_p = origin + noise_p + np.array([0.0, 0.0, settings.floor_offset_m])
    return SyntheticTrial(
        time=time, com_position=com, orientation_xyzw=q_true,
        linear_velocity=np.asarray(rec["v"], dtype=np.float64), angular_velocity=np.asarray(rec["w"], dtype=np.float64),
        csv_position=csv_p, csv_orientation=csv_q, push_start=push_start_step * phys.time_step,
        release=release_step * phys.time_step, friction=mu, floor_offset=settings.floor_offset_m,
    )


def write_trial_csv(path: str | Path, time: np.ndarray, position: np.ndarray, orientation_xyzw: np.ndarray) -> None:
    """The import's input format: header ``time,x,y,z,qx,qy,qz,qw``, one row per sample."""
    table = np.column_stack([time, position, orientation_xyzw])
    with atomic_output(path, suffix=".csv") as tmp:
        np.savetxt(tmp, table, delimiter=",", header=CSV_HEADER, comments="", fmt=["%.6f"] + ["%.7f"] * 3 + ["%.8f"] * 4)


def simulate_mocap_trials(out: str | Path, trials: int = 12, seed: int = 0, box: str | None = None,
                          settings: SyntheticSettings = SyntheticSettings(), overwrite: bool = False,
                          physics: PhysicsConfig | None = None) -> list[Path]:
    """Write ``trials`` synthetic trials (``trial_NNN.csv`` + ``trial_NNN.truth.npz``) into ``out``.
    Returns the CSV paths. Refuses a folder that already holds CSV files unless ``overwrite``."""

    if trials < 1:
        raise PhysdynError(f"--trials must be at least 1, got {trials}")
    offset = float((settings or SyntheticSettings()).floor_offset_m)
    if not math.isfinite(offset) or abs(offset) > MAX_FLOOR_OFFSET:
        raise PhysdynError(f"--floor-offset must be a finite number of metres within +-{MAX_FLOOR_OFFSET:g}, got {offset:g}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise PhysdynError(f"--out {out} is a file; choose a folder for the trials")
    existing = sorted(out.glob("*.csv")) if out.is_dir() else []
    if existing and not overwrite:
        raise PhysdynError(f"{out} already holds {len(existing)} CSV file(s); pass --overwrite to replace them or choose another --out")
    box = box or "box:" + ",".join(f"{v:g}" for v in PAPER_BOX)
    shape = tracked_shape(box=box)
    out.mkdir(parents=True, exist_ok=True)
    for old in existing:
        old.unlink()
        old.with_suffix(".truth.npz").unlink(missing_ok=True)
    paths = []
    physics = physics or PhysicsConfig()
    with PhysicsWorld(physics) as world:
        body = world.add_body(shape.spec)
        for i in range(trials):
            rng = np.random.default_rng(np.random.SeedSequence([seed, i]))
            trial = simulate_trial(world, body, shape, rng, settings)
            path = out / f"trial_{i:03d}.csv"
            # the truth first: a trial whose CSV is there has its truth too (each file whole or absent)
            with atomic_output(path.with_suffix(".truth.npz")) as tmp, open(tmp, "wb") as fh:
                np.savez(
                    fh, time=trial.time, com_position=trial.com_position,
                    orientation_xyzw=trial.orientation_xyzw, linear_velocity=trial.linear_velocity,
                    angular_velocity=trial.angular_velocity, push_start=trial.push_start, release=trial.release,
                    friction=trial.friction, floor_offset=trial.floor_offset, shape=shape.source,
                    settings=json.dumps(settings.__dict__),
                )
            write_trial_csv(path, trial.time, trial.csv_position, trial.csv_orientation)
            paths.append(path)
    return paths
