"""Dataset generation: shapes -> mass properties, resting poses, point clouds -> pushes -> a Zarr store.

The unit of work is a *block* of consecutive shapes. Every random draw is seeded from (seed, family,
shape index), never from the worker, so the store is identical whatever the worker count, executor or
number of interruptions; blocks land in the store's ``_parts`` as they finish, which is what ``--resume``
picks up.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import sys
import time
import warnings
import zlib
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from physdyn.config import DataConfig, to_dict
from physdyn.errors import ConfigError, ShapeError
from physdyn.registry import SHAPE_FAMILIES

FORMAT_NOTE = "physdyn dataset; layout in docs/dataset-format.md"


@dataclass(frozen=True)
class ShapeTask:
    family: str
    index: int
    category: int


@dataclass
class GenerationReport:
    out: str
    num_shapes: int
    num_sims: int
    num_frames: int
    skipped: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    blocks_resumed: int = 0


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
    from physdyn.sim.trajectory import steps_per_frame

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


# --------------------------------------------------------------------------------------------------
# Work (runs in worker processes)
# --------------------------------------------------------------------------------------------------
_WORKER: dict[str, Any] = {}


def _worker_state(cfg: DataConfig) -> dict:
    key = config_hash(cfg)
    if _WORKER.get("key") != key:
        from physdyn.sim.world import PhysicsWorld

        if "world" in _WORKER:
            _WORKER["world"].close()
        _WORKER.clear()
        _WORKER.update(key=key, world=PhysicsWorld(cfg.physics), families={})
    return _WORKER


def prepare_shape(cfg: DataConfig, family, task: ShapeTask) -> dict:
    """Draw one shape and compute everything stored about it. Raises ShapeError if it is unusable."""
    from physdyn.geometry.mass import exact_mass_properties, solid_mass_properties
    from physdyn.geometry.mesh_io import prepare_mesh
    from physdyn.geometry.poses import stable_orientations
    from physdyn.geometry.sampling import sample_surface_points
    from physdyn.sim.body import RigidBodySpec

    shape_ss, sims_ss, points_ss = task_streams(cfg, task)
    instance = family.make(task.index, np.random.default_rng(shape_ss))
    prepared = prepare_mesh(instance.mesh, instance.source)
    mesh, notes = prepared.mesh, list(prepared.warnings)
    # Not watertight: the hull's exact properties (prepare_mesh's warning already tells the user).
    props = solid_mass_properties(mesh, prepared.watertight, cfg.mass.density, instance.source, cfg.mass.method,
                                  cfg.mass.voxel_pitch)
    exact = exact_mass_properties(mesh, cfg.mass.density) if prepared.watertight and cfg.mass.method != "exact" else props
    spec = RigidBodySpec.from_mesh(mesh, props)
    rotations, probabilities = stable_orientations(mesh, props.com)
    points = sample_surface_points(mesh, cfg.num_points, cfg.oversample, seed=int(points_ss.generate_state(1)[0]))
    return dict(
        task=task, instance=instance, spec=spec, props=props, exact=exact, notes=notes,
        rotations=rotations, probabilities=probabilities, hull_mass=not prepared.watertight,
        points=(points - props.com).astype(np.float32), sims_rng=np.random.default_rng(sims_ss),
    )


def run_block(cfg: DataConfig, block_id: int, tasks: list[ShapeTask]) -> tuple[int, dict, dict]:
    """Simulate every shape of one block. Returns (block_id, arrays, attrs) ready for the store's part."""
    from physdyn.sim.impulse import sample_initial_condition
    from physdyn.sim.trajectory import simulate

    state = _worker_state(cfg)
    world = state["world"]
    shapes: list[dict] = []
    sims: list[dict] = []
    skipped, notes = [], []
    for task in tasks:
        family = state["families"].get(task.family) or build_family(cfg, task.family)
        state["families"][task.family] = family
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                shape = prepare_shape(cfg, family, task)
        except Exception as exc:  # an unusable shape is reported at the end, never a crash
            reason = str(exc) if isinstance(exc, ShapeError) else f"{type(exc).__name__}: {exc}"
            skipped.append({"family": task.family, "index": task.index, "reason": reason})
            continue
        notes += shape["notes"]
        body = world.add_body(shape["spec"])
        try:
            for _ in range(cfg.families[task.family].sims_per_shape):
                init, drawn = sample_initial_condition(
                    shape["sims_rng"], world, body, shape["spec"], shape["rotations"], shape["probabilities"], cfg
                )
                traj = simulate(world, body, shape["spec"], init, cfg.rate_hz)
                sims.append(dict(shape=len(shapes), init=init, drawn=drawn, length=len(traj), traj=traj))
        finally:
            world.remove_body(body)
        shapes.append(shape)
    return block_id, _block_arrays(shapes, sims), {"skipped": skipped, "notes": notes}


def _block_arrays(shapes: list[dict], sims: list[dict]) -> dict[str, np.ndarray]:
    def stack(values, dtype, shape=()):
        return np.asarray(values, dtype=dtype).reshape((len(values),) + shape)

    trajs = [s["traj"] for s in sims]

    def cat(attr, width):
        return np.concatenate([getattr(t, attr) for t in trajs]) if trajs else np.zeros((0, width))

    return {
        "shapes/points": np.stack([s["points"] for s in shapes]) if shapes else np.zeros((0, 1, 3), np.float32),
        "shapes/com_mesh": stack([s["props"].com for s in shapes], np.float64, (3,)),
        "shapes/mass": stack([s["props"].mass for s in shapes], np.float64),
        "shapes/inertia_diag": stack([s["spec"].inertia_diag for s in shapes], np.float64, (3,)),
        "shapes/inertia_orientation_xyzw": stack([s["spec"].principal_quat_xyzw for s in shapes], np.float64, (4,)),
        "shapes/category": stack([s["task"].category for s in shapes], np.int32),
        "shapes/source": np.asarray([s["instance"].source for s in shapes], dtype=str),
        "shapes/volume": stack([s["props"].volume for s in shapes], np.float64),
        "shapes/extents": stack([s["instance"].mesh.extents for s in shapes], np.float64, (3,)),
        "shapes/hull_mass": stack([s["hull_mass"] for s in shapes], bool),
        "shapes/exact_mass": stack([s["exact"].mass for s in shapes], np.float64),
        "shapes/exact_inertia_diag": stack([s["exact"].principal()[0] for s in shapes], np.float64, (3,)),
        "sims/shape_local": stack([s["shape"] for s in sims], np.int64),
        "sims/length": stack([s["length"] for s in sims], np.int64),
        "sims/toppled": stack([s["traj"].topple_step >= 0 for s in sims], bool),
        "sims/topple_step": stack([s["traj"].topple_step for s in sims], np.int32),
        "sims/friction": stack([s["init"].friction for s in sims], np.float64),
        "sims/impulse": stack([s["init"].impulse for s in sims], np.float64, (3,)),
        "sims/impulse_point": stack([s["init"].impulse_point for s in sims], np.float64, (3,)),
        "sims/initial_orientation_xyzw": stack([s["init"].orientation_xyzw for s in sims], np.float64, (4,)),
        "sims/speed": stack([s["drawn"]["speed"] for s in sims], np.float64),
        "sims/pose_index": stack([s["drawn"]["pose_index"] for s in sims], np.int32),
        "frames/com_position": cat("com_position", 3),
        "frames/orientation_xyzw": cat("orientation_xyzw", 4),
        "frames/linear_velocity": cat("linear_velocity", 3),
        "frames/angular_velocity": cat("angular_velocity", 3),
        "frames/topple_label": np.concatenate([t.topple_label for t in trajs]) if trajs else np.zeros(0, bool),
    }


# --------------------------------------------------------------------------------------------------
# Executors
# --------------------------------------------------------------------------------------------------
def _run_block_star(args: tuple) -> tuple[int, dict, dict]:
    return run_block(*args)


def _execute(cfg: DataConfig, work: list[tuple[int, list[ShapeTask]]], workers: int, executor: str) -> Iterator[tuple[int, dict, dict]]:
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


def _execute_ray(cfg: DataConfig, work: list[tuple[int, list[ShapeTask]]], workers: int) -> Iterator[tuple[int, dict, dict]]:
    try:
        import ray
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
    import os

    return os.environ.get("RAY_ADDRESS")


# --------------------------------------------------------------------------------------------------
# The whole run
# --------------------------------------------------------------------------------------------------
def generate_dataset(cfg: DataConfig, out: str, workers: int = 1, executor: str = "process",
                     resume: bool = False, overwrite: bool = False, progress: bool = True) -> GenerationReport:
    """Generate the dataset described by ``cfg`` into the store at ``out`` (a path or fsspec URL)."""
    from physdyn.data.store import replacing_store
    from physdyn.geometry.sampling import open3d

    if resume and overwrite:
        raise ConfigError("--resume and --overwrite contradict each other; pass one")
    open3d()  # at start-up: a missing system library is one line with its fix, not every shape skipped
    started = time.time()
    blocks, categories = plan(cfg)
    chash = config_hash(cfg)
    if resume:
        return _generate(cfg, out, blocks, categories, chash, workers, executor, True, progress, started)
    with replacing_store(out, overwrite) as target:  # a failed --overwrite leaves the old store as it was
        try:
            report = _generate(cfg, target, blocks, categories, chash, workers, executor, False, progress, started)
        except KeyboardInterrupt:
            if target == str(out):
                raise
            raise KeyboardInterrupt(f"the store at {out} is unchanged; rerun with --overwrite to replace it") from None
    report.out = str(out)
    return report


def _generate(cfg: DataConfig, out: str, blocks, categories, chash: str, workers: int, executor: str, resume: bool,
              progress: bool, started: float) -> GenerationReport:
    from physdyn.files import progress_bar

    from physdyn.data.store import StoreWriter

    if resume:
        writer = StoreWriter.resume(out, chash)
    else:
        attrs = {
            "format_note": FORMAT_NOTE,
            "rate_hz": cfg.rate_hz,
            "physics": to_dict(cfg.physics),
            "config": to_dict(cfg),
            "config_hash": chash,
            "num_blocks": len(blocks),
        }
        writer = StoreWriter.create(out, attrs)
    done = writer.done_blocks(len(blocks))
    work = [(b, tasks) for b, tasks in enumerate(blocks) if b not in done]
    sims_of = lambda tasks: sum(cfg.families[t.family].sims_per_shape for t in tasks)  # noqa: E731
    total = sum(sims_of(t) for t in blocks)
    bar = progress_bar(total, "simulate", "sim", enabled=progress, initial=total - sum(sims_of(t) for _, t in work))
    try:
        for block_id, arrays, attrs in _execute(cfg, work, workers, executor):
            writer.write_block(block_id, arrays, attrs)
            bar.update(sims_of(blocks[block_id]))
    except KeyboardInterrupt:
        bar.close()
        raise KeyboardInterrupt(
            f"{len(writer.done_blocks(len(blocks)))} of {len(blocks)} blocks are saved in {out}; "
            f"rerun the same command with --resume to finish"
        ) from None
    bar.close()
    report = _finalize(cfg, writer, len(blocks), categories)
    report.seconds = time.time() - started
    report.blocks_resumed = len(done)
    return report


def assign_splits(categories: np.ndarray, cfg: DataConfig) -> np.ndarray:
    """Split shapes per category, deterministically from the seed: 20 % test, then 10 % of the rest
    validation, the remainder train (at least one test and one validation shape per category of three or
    more). Returns (S,) int8: 0 train, 1 val, 2 test."""
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, zlib.crc32(b"split")]))
    split = np.zeros(len(categories), dtype=np.int8)
    for cat in np.unique(categories):
        ids = np.nonzero(categories == cat)[0]
        ids = ids[rng.permutation(len(ids))]
        n_test = _split_count(cfg.split.test_fraction, len(ids), minimum=1 if len(ids) >= 3 else 0)
        n_val = _split_count(cfg.split.val_fraction, len(ids) - n_test, minimum=1 if len(ids) - n_test >= 2 else 0)
        split[ids[:n_test]] = 2
        split[ids[n_test : n_test + n_val]] = 1
    return split


def _split_count(fraction: float, n: int, minimum: int) -> int:
    """round(fraction x n), but at least ``minimum`` when the fraction is positive: a small category still
    gets a validation and a test shape, or training would have nothing to select its checkpoint on."""
    if fraction <= 0:
        return 0
    return max(int(round(fraction * n)), minimum)


def _finalize(cfg: DataConfig, writer, num_blocks: int, categories: list[str]) -> GenerationReport:
    parts, skipped, notes = [], [], []
    for b in range(num_blocks):
        arrays, attrs = writer.read_block(b)
        parts.append(arrays)
        skipped += attrs.get("skipped", [])
        notes += attrs.get("notes", [])
    out: dict[str, np.ndarray] = {}
    keys = [k for k in parts[0] if not k.startswith("sims/shape_local") and k != "sims/length"]
    for key in keys:
        out[key] = np.concatenate([p[key] for p in parts])
    shape_offsets = np.cumsum([0] + [len(p["shapes/mass"]) for p in parts])
    out["sims/shape_id"] = np.concatenate([p["sims/shape_local"] + off for p, off in zip(parts, shape_offsets)])
    lengths = np.concatenate([p["sims/length"] for p in parts])
    out["sims/start"] = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    if len(out["shapes/mass"]) == 0:
        first = skipped[0].get("reason", "unknown") if skipped else "unknown"
        more = f" (and {len(skipped) - 1} more shapes)" if len(skipped) > 1 else ""
        raise ShapeError(f"every shape was unusable, nothing to write; first reason: {first}{more}")
    shape_split = assign_splits(out["shapes/category"], cfg)
    out["shapes/split"] = shape_split
    out["sims/split"] = shape_split[out["sims/shape_id"]]
    attrs = {"skipped": skipped, "notes": notes[:1000]}
    writer.finalize(out, attrs, group_attrs={"shapes": {"category_names": categories}})
    return GenerationReport(
        out=writer.url, num_shapes=len(out["shapes/mass"]), num_sims=len(out["sims/shape_id"]),
        num_frames=int(out["sims/start"][-1]), skipped=skipped, warnings=notes,
    )
