"""A store from simulation: ``physdyn simulate``'s whole run. The blocks ``physdyn.sim.generate``
simulates land in the store's ``_parts`` as they finish (which is what ``--resume`` picks up); once all are
there, they are joined in block order and the shapes split into train, validation and test.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field

import numpy as np

from physdyn.config import DataConfig, to_dict
from physdyn.data.store import StoreWriter, replacing_store
from physdyn.errors import ConfigError, ShapeError
from physdyn.files import progress_bar
from physdyn.geometry.sampling import open3d
from physdyn.sim.ensemble import EnsemblePlan, members_arrays
from physdyn.sim.generate import SimulatedBlock, config_hash, plan, simulate_blocks
from physdyn.write_lock import write_lock

FORMAT_NOTE = "physdyn dataset; layout in docs/dataset-format.md"


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


def generate_dataset(cfg: DataConfig, out: str, workers: int = 1, executor: str = "process",
                     resume: bool = False, overwrite: bool = False, progress: bool = True) -> GenerationReport:
    """Generate the dataset described by ``cfg`` into the store at ``out`` (a path or fsspec URL)."""
    if resume and overwrite:
        raise ConfigError("--resume and --overwrite contradict each other; pass one")
    open3d()  # at start-up: a missing system library is one line with its fix, not every shape skipped
    started = time.time()
    blocks, categories = plan(cfg)
    chash = config_hash(cfg)
    with write_lock(out):  # one writer per store: a second one, --resume included, is refused naming the first
        return _generate_locked(cfg, out, blocks, categories, chash, workers, executor, resume, overwrite, progress,
                                started)


def _generate_locked(cfg: DataConfig, out: str, blocks, categories, chash: str, workers: int, executor: str,
                     resume: bool, overwrite: bool, progress: bool, started: float) -> GenerationReport:
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
        ensemble = EnsemblePlan.from_config(cfg)
        if ensemble is not None:
            attrs["ensemble"] = ensemble.describe()
        writer = StoreWriter.create(out, attrs)
    if resume and writer.arrays_written:  # killed while it removed the parts: only marking it complete is left
        return _completed(writer, len(blocks), started)
    done = writer.done_blocks(len(blocks))
    work = [(b, tasks) for b, tasks in enumerate(blocks) if b not in done]
    sims_of = lambda tasks: sum(cfg.families[t.family].sims_per_shape for t in tasks)  # noqa: E731
    total = sum(sims_of(t) for t in blocks)
    bar = progress_bar(total, "simulate", "sim", enabled=progress, initial=total - sum(sims_of(t) for _, t in work))
    try:
        for block in simulate_blocks(cfg, work, workers, executor):
            writer.write_block(block.block_id, *block_part(block))
            bar.update(sims_of(blocks[block.block_id]))
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


def _completed(writer: StoreWriter, num_blocks: int, started: float) -> GenerationReport:
    writer.complete()
    group, attrs = writer.group, dict(writer.group.attrs)
    report = GenerationReport(
        out=writer.url, num_shapes=int(group["shapes/mass"].shape[0]), num_sims=int(group["sims/shape_id"].shape[0]),
        num_frames=int(group["sims/start"][-1]), skipped=attrs.get("skipped", []), warnings=attrs.get("notes", []),
    )
    report.seconds = time.time() - started
    report.blocks_resumed = num_blocks
    return report


def block_part(block: SimulatedBlock) -> tuple[dict[str, np.ndarray], dict]:
    """A simulated block as the store's part: its arrays (``sims/shape_local`` indexes the block's shapes,
    ``sims/length`` counts each simulation's frames; ``ensemble/`` its pushes' members, if any) and
    attributes (skipped shapes, notes)."""
    def stack(values, dtype, shape=()):
        return np.asarray(values, dtype=dtype).reshape((len(values),) + shape)

    shapes, pushes = block.shapes, block.pushes
    trajs = [p.trajectory for p in pushes]

    def cat(attr, width):
        return np.concatenate([getattr(t, attr) for t in trajs]) if trajs else np.zeros((0, width))

    arrays = {
        "shapes/points": np.stack([s.points for s in shapes]) if shapes else np.zeros((0, 1, 3), np.float32),
        "shapes/com_mesh": stack([s.com_mesh for s in shapes], np.float64, (3,)),
        "shapes/mass": stack([s.mass for s in shapes], np.float64),
        "shapes/inertia_diag": stack([s.inertia_diag for s in shapes], np.float64, (3,)),
        "shapes/inertia_orientation_xyzw": stack([s.inertia_orientation_xyzw for s in shapes], np.float64, (4,)),
        "shapes/category": stack([s.category for s in shapes], np.int32),
        "shapes/source": np.asarray([s.source for s in shapes], dtype=str),
        "shapes/volume": stack([s.volume for s in shapes], np.float64),
        "shapes/extents": stack([s.extents for s in shapes], np.float64, (3,)),
        "shapes/hull_mass": stack([s.hull_mass for s in shapes], bool),
        "shapes/exact_mass": stack([s.exact_mass for s in shapes], np.float64),
        "shapes/exact_inertia_diag": stack([s.exact_inertia_diag for s in shapes], np.float64, (3,)),
        "sims/shape_local": stack([p.shape for p in pushes], np.int64),
        "sims/length": stack([len(t) for t in trajs], np.int64),
        "sims/toppled": stack([t.topple_step >= 0 for t in trajs], bool),
        "sims/topple_step": stack([t.topple_step for t in trajs], np.int32),
        "sims/friction": stack([p.init.friction for p in pushes], np.float64),
        "sims/impulse": stack([p.init.impulse for p in pushes], np.float64, (3,)),
        "sims/impulse_point": stack([p.init.impulse_point for p in pushes], np.float64, (3,)),
        "sims/initial_orientation_xyzw": stack([p.init.orientation_xyzw for p in pushes], np.float64, (4,)),
        "sims/speed": stack([p.speed for p in pushes], np.float64),
        "sims/pose_index": stack([p.pose_index for p in pushes], np.int32),
        "frames/com_position": cat("com_position", 3),
        "frames/orientation_xyzw": cat("orientation_xyzw", 4),
        "frames/linear_velocity": cat("linear_velocity", 3),
        "frames/angular_velocity": cat("angular_velocity", 3),
        "frames/topple_label": np.concatenate([t.topple_label for t in trajs]) if trajs else np.zeros(0, bool),
    }
    if block.ensemble is not None:
        arrays.update(members_arrays(block.members, block.ensemble))
    return arrays, {"skipped": block.skipped, "notes": block.notes}


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


def _finalize(cfg: DataConfig, writer: StoreWriter, num_blocks: int, categories: list[str]) -> GenerationReport:
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
