"""Simulating a dataset: shapes -> mass properties, resting poses, point clouds -> pushes -> records.

The unit of work is a *block* of consecutive shapes; ``simulate_blocks`` yields one ``SimulatedBlock`` (a
record per shape and per push) as each finishes, in worker processes or on Ray. Every random draw is seeded
from (seed, family, shape index), never from the worker, so the records are identical whatever the worker
count, executor or number of interruptions. Writing them to a store, and resuming, is the data layer's job
(``physdyn.data.simulated_store``); nothing here knows the store's format.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import sys
import warnings
import zlib
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from physdyn.config import DataConfig, to_dict
from physdyn.errors import ConfigError, ShapeError
from physdyn.geometry.mass import exact_mass_properties
from physdyn.geometry.poses import stable_orientations
from physdyn.registry import SHAPE_FAMILIES
from physdyn.sim.body import rigid_body
from physdyn.sim.ensemble import EnsemblePlan, PushMembers, simulate_members
from physdyn.sim.impulse import sample_initial_condition
from physdyn.sim.trajectory import InitialCondition, Trajectory, simulate, steps_per_frame
from physdyn.sim.world import PhysicsWorld


@dataclass(frozen=True)
class ShapeTask:
    family: str
    index: int
    category: int


@dataclass
class SimulatedShape:
    """What a dataset keeps of one shape. Mesh coordinates unless said; SI units.

    points: (N, 3) float32 surface points in the body frame. com_mesh: (3,) centre of mass.
    inertia_diag: (3,) principal moments about the centre of mass; inertia_orientation_xyzw: (4,) the
    principal axes in the mesh frame. hull_mass: the mesh was not watertight, so its convex hull's mass
    properties stand in. exact_*: the exact solid's properties (differ from the simulated ones only when
    ``mass.method`` is voxel). extents: (3,) the mesh's bounding box size.
    """

    category: int
    source: str
    points: np.ndarray
    com_mesh: np.ndarray
    mass: float
    volume: float
    inertia_diag: np.ndarray
    inertia_orientation_xyzw: np.ndarray
    extents: np.ndarray
    hull_mass: bool
    exact_mass: float
    exact_inertia_diag: np.ndarray


@dataclass
class SimulatedPush:
    """One simulation: the push drawn for shape ``shape`` (its index in the block) and the recorded motion."""

    shape: int
    init: InitialCondition
    speed: float
    pose_index: int
    trajectory: Trajectory


@dataclass
class SimulatedBlock:
    """One block's records, in task order. skipped: unusable shapes ({family, index, reason});
    notes: warnings met while preparing the meshes; members: each push's ensemble (in push order) when the
    config has one, as ``ensemble`` plans it."""

    block_id: int
    shapes: list[SimulatedShape] = field(default_factory=list)
    pushes: list[SimulatedPush] = field(default_factory=list)
    ensemble: EnsemblePlan | None = None
    members: list[PushMembers] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------------------------------
# Planning
# --------------------------------------------------------------------------------------------------
def family_params(cfg: DataConfig, name: str) -> dict:
    """A family's parameters: ``families.<name>.params``; the mesh folder family also reads ``meshes``."""
    params = dict(cfg.families[name].params)
    if name == "meshes":
        params = {**to_dict(cfg.meshes), **params}
    return params


def build_family(cfg: DataConfig, name: str):
    return SHAPE_FAMILIES.build(name, family_params(cfg, name), where=f"families.{name}.params")


def validate(cfg: DataConfig) -> None:
    """Check what the schema's types cannot: ranges, and that the physics step divides the frame rate."""
    if not cfg.families:
        raise ConfigError("families is empty; add at least one, e.g. families.primitives.shapes=10")
    for name, spec in cfg.families.items():
        if spec.sims_per_shape < 1 or spec.shapes < 0:
            raise ConfigError(f"families.{name}: shapes must be >= 0 and sims_per_shape >= 1")
    try:
        steps_per_frame(cfg.physics.time_step, cfg.rate_hz)
    except ValueError as exc:
        raise ConfigError(f"rate_hz: {exc}") from None
    if not 0 < cfg.impulse.speed_min <= cfg.impulse.speed_max:
        raise ConfigError("impulse: need 0 < speed_min <= speed_max (m/s)")
    if cfg.friction.random and not 0 < cfg.friction.min <= cfg.friction.max:
        raise ConfigError("friction: need 0 < min <= max for random friction")
    if cfg.mass.method not in ("exact", "voxel"):
        raise ConfigError(f"mass.method: must be 'exact' or 'voxel', got '{cfg.mass.method}'")
    if cfg.mass.density <= 0:
        raise ConfigError("mass.density must be positive (kg/m^3)")
    if not (0 <= cfg.split.test_fraction < 1 and 0 <= cfg.split.val_fraction < 1):
        raise ConfigError("split fractions must be in [0, 1)")
    if cfg.num_points < 1 or cfg.oversample < 1 or cfg.shapes_per_block < 1:
        raise ConfigError("num_points, oversample and shapes_per_block must be >= 1")
    if cfg.ensemble.members < 0:
        raise ConfigError("ensemble.members must be >= 0 (0: no ensemble)")
    cfg.ensemble.uncertainty_config()  # a bad uncertainty: one line naming the key, before anything runs


def plan(cfg: DataConfig) -> tuple[list[list[ShapeTask]], list[str]]:
    """Blocks of shape tasks, and the category names (index = shapes/category)."""
    validate(cfg)
    categories: list[str] = []
    tasks: list[ShapeTask] = []
    for name, spec in cfg.families.items():
        family = build_family(cfg, name)
        if family.category not in categories:
            categories.append(family.category)
        cat = categories.index(family.category)
        tasks += [ShapeTask(name, i, cat) for i in range(family.num_shapes(spec.shapes))]
    if not tasks:
        raise ConfigError("the config asks for no shapes; set families.<name>.shapes above 0")
    n = cfg.shapes_per_block
    return [tasks[i : i + n] for i in range(0, len(tasks), n)], categories


def config_hash(cfg: DataConfig) -> str:
    return hashlib.sha256(json.dumps(to_dict(cfg), sort_keys=True).encode()).hexdigest()[:16]


def shape_seed(cfg: DataConfig, task: ShapeTask) -> np.random.SeedSequence:
    # crc32 of the family name, not its position, so adding a family leaves the others' shapes unchanged.
    return np.random.SeedSequence([cfg.seed, zlib.crc32(task.family.encode()), task.index])


def task_streams(cfg: DataConfig, task: ShapeTask) -> list[np.random.SeedSequence]:
    """The task's three random streams: the shape, its simulations, its point cloud (in that order)."""
    return shape_seed(cfg, task).spawn(3)


def ensemble_streams(cfg: DataConfig, task: ShapeTask) -> list[np.random.SeedSequence]:
    """The task's fourth stream, one child per push: its ensemble's perturbations. ``task_streams``'s three
    are unchanged by it, so a store's pushes are the same with or without an ensemble."""
    return shape_seed(cfg, task).spawn(4)[3].spawn(cfg.families[task.family].sims_per_shape)


# --------------------------------------------------------------------------------------------------
# Work (runs in worker processes)
# --------------------------------------------------------------------------------------------------
_WORKER: dict[str, Any] = {}


def _worker_state(cfg: DataConfig) -> dict:
    key = config_hash(cfg)
    if _WORKER.get("key") != key:
        if "world" in _WORKER:
            _WORKER["world"].close()
        _WORKER.clear()
        _WORKER.update(key=key, world=PhysicsWorld(cfg.physics), families={})
    return _WORKER


def prepare_shape(cfg: DataConfig, family, task: ShapeTask) -> dict:
    """Draw one shape and compute everything stored about it. Raises ShapeError if it is unusable."""

    shape_ss, sims_ss, points_ss = task_streams(cfg, task)
    instance = family.make(task.index, np.random.default_rng(shape_ss))
    # Not watertight: the hull's exact properties (the cleaning's warning already tells the user).
    body = rigid_body(instance.mesh, instance.source, cfg.mass.density, cfg.mass.method, cfg.mass.voxel_pitch)
    mesh, props = body.mesh, body.props
    exact = exact_mass_properties(mesh, cfg.mass.density) if body.watertight and cfg.mass.method != "exact" else props
    rotations, probabilities = stable_orientations(mesh, props.com)
    return dict(
        task=task, instance=instance, spec=body.spec, props=props, exact=exact, notes=body.notes,
        rotations=rotations, probabilities=probabilities, hull_mass=not body.watertight,
        points=body.surface_points(cfg.num_points, cfg.oversample, int(points_ss.generate_state(1)[0]), cfg.points_method),
        sims_rng=np.random.default_rng(sims_ss),
    )


def run_block(cfg: DataConfig, block_id: int, tasks: list[ShapeTask]) -> SimulatedBlock:
    """Simulate every shape of one block."""

    state = _worker_state(cfg)
    world = state["world"]
    ensemble = EnsemblePlan.from_config(cfg)
    block = SimulatedBlock(block_id, ensemble=ensemble)
    for task in tasks:
        family = state["families"].get(task.family) or build_family(cfg, task.family)
        state["families"][task.family] = family
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                shape = prepare_shape(cfg, family, task)
        except Exception as exc:  # an unusable shape is reported at the end, never a crash
            reason = str(exc) if isinstance(exc, ShapeError) else f"{type(exc).__name__}: {exc}"
            block.skipped.append({"family": task.family, "index": task.index, "reason": reason})
            continue
        block.notes += shape["notes"]
        body = world.add_body(shape["spec"])
        try:
            first = len(block.pushes)
            for _ in range(cfg.families[task.family].sims_per_shape):
                init, drawn = sample_initial_condition(
                    shape["sims_rng"], world, body, shape["spec"], shape["rotations"], shape["probabilities"], cfg
                )
                traj = simulate(world, body, shape["spec"], init, cfg.rate_hz)
                block.pushes.append(SimulatedPush(len(block.shapes), init, drawn["speed"], drawn["pose_index"], traj))
            if ensemble is not None:  # after the shape's pushes, which are then those of a store without one
                for push, stream in zip(block.pushes[first:], ensemble_streams(cfg, task)):
                    block.members.append(simulate_members(world, body, shape["spec"], push.trajectory,
                                                          push.init.friction, ensemble, np.random.default_rng(stream)))
        finally:
            world.remove_body(body)
        block.shapes.append(_shape_record(shape))
    return block


def _shape_record(shape: dict) -> SimulatedShape:
    props, spec, instance = shape["props"], shape["spec"], shape["instance"]
    return SimulatedShape(
        category=shape["task"].category, source=instance.source, points=shape["points"], com_mesh=props.com,
        mass=props.mass, volume=props.volume, inertia_diag=spec.inertia_diag,
        inertia_orientation_xyzw=spec.principal_quat_xyzw, extents=instance.mesh.extents,
        hull_mass=shape["hull_mass"], exact_mass=shape["exact"].mass, exact_inertia_diag=shape["exact"].principal()[0],
    )


# --------------------------------------------------------------------------------------------------
# Executors
# --------------------------------------------------------------------------------------------------
def _run_block_star(args: tuple) -> SimulatedBlock:
    return run_block(*args)


def simulate_blocks(cfg: DataConfig, work: list[tuple[int, list[ShapeTask]]], workers: int,
                    executor: str) -> Iterator[SimulatedBlock]:
    """Simulate the blocks of ``work`` ((block id, tasks) pairs), yielding each as it finishes (in any order)."""
    if executor == "ray":
        yield from _execute_ray(cfg, work, workers)
        return
    if executor != "process":
        raise ConfigError(f"--executor must be 'process' or 'ray', got '{executor}'")
    if workers <= 1:
        for block_id, tasks in work:
            yield run_block(cfg, block_id, tasks)
        return
    # fork shares the imported modules; each worker opens its own PyBullet client on first use.
    ctx = mp.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    pool = ctx.Pool(workers)
    try:
        yield from pool.imap_unordered(_run_block_star, [(cfg, b, t) for b, t in work], chunksize=1)
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()


def _execute_ray(cfg: DataConfig, work: list[tuple[int, list[ShapeTask]]], workers: int) -> Iterator[SimulatedBlock]:
    try:
        import ray  # optional: pip install 'physdyn[ray]'
    except ImportError:
        raise ConfigError("--executor ray needs Ray: pip install 'physdyn[ray]'") from None
    if not ray.is_initialized():
        # Joins the cluster named by RAY_ADDRESS if set, else starts a local instance.
        ray.init(num_cpus=None if _ray_address() else max(workers, 1), include_dashboard=False,
                 log_to_driver=False, ignore_reinit_error=True)
    remote = ray.remote(run_block)
    pending = [remote.remote(cfg, b, t) for b, t in work]
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise


def _ray_address() -> str | None:
    return os.environ.get("RAY_ADDRESS")
