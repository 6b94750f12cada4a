"""Motion-capture trials -> a dataset store (docs/real-world.md; supplement, "Real-world Data Experiments").

Every CSV trial of the given files and folders is read, checked and converted by ``import_trial``
(``physdyn/data/mocap_trials.py``, where the steps are listed); a trial that fails a check is reported (file
and reason) and skipped; the rest are split by trial and written into one store of one shape.
"""

from __future__ import annotations

import time as _time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from physdyn.data.mocap_trials import (ImportedTrial, ImportSettings, TrialError,  # noqa: F401
                                       average_quaternions, import_trial)
from physdyn.data.store import StoreWriter, store_exists
from physdyn.errors import PhysdynError, StoreError
from physdyn.sim.synthetic_trials import CSV_HEADER, TrackedShape
from physdyn.write_lock import write_lock

FORMAT_NOTE = "physdyn dataset imported from motion capture; layout in docs/dataset-format.md, import in docs/real-world.md"


@dataclass
class ImportReport:
    out: str
    trials: list[dict]  # per imported trial: file, frames, split, rate, floor offset, trim time, peak speed
    skipped: list[dict]  # {"file", "reason"}
    rate_hz: float
    input_rates_hz: list[float]
    num_frames: int
    seconds: float = 0.0


# --------------------------------------------------------------------------------------------------
# A folder of trials -> a store
# --------------------------------------------------------------------------------------------------
def trial_files(inputs: list[str | Path]) -> list[Path]:
    """CSV files named directly or found (sorted, not recursively) in the given folders."""
    files: list[Path] = []
    for item in inputs:
        item = Path(item)
        if item.is_dir():
            files += sorted(p for p in item.iterdir() if p.suffix.lower() == ".csv" and p.is_file())
        elif item.is_file():
            files.append(item)
        else:
            raise PhysdynError(f"no trial file or folder at {item}; pass a folder of CSV trials or CSV files")
    if not files:
        raise PhysdynError(f"no .csv trials in {', '.join(str(i) for i in inputs)}; each trial is one CSV with header {CSV_HEADER}")
    return files


def split_trials(num_trials: int, settings: ImportSettings) -> np.ndarray:
    """Split by trial, from the seed: round(test_fraction x n) test (>= 1 from three trials), then
    val_fraction of the rest validation (>= 1 from two), the remainder train. (M,) int8: 0/1/2."""
    rng = np.random.default_rng(np.random.SeedSequence([settings.seed, zlib.crc32(b"mocap-split")]))
    order = rng.permutation(num_trials)
    n_test = max(int(round(settings.test_fraction * num_trials)), 1 if num_trials >= 3 else 0) if settings.test_fraction > 0 else 0
    rest = num_trials - n_test
    n_val = max(int(round(settings.val_fraction * rest)), 1 if rest >= 2 else 0) if settings.val_fraction > 0 else 0
    split = np.zeros(num_trials, dtype=np.int8)
    split[order[:n_test]] = 2
    split[order[n_test:n_test + n_val]] = 1
    return split


def import_mocap(inputs: list[str | Path] | str | Path, out: str | Path, shape: TrackedShape,
                 settings: ImportSettings = ImportSettings(), overwrite: bool = False) -> ImportReport:
    """Import every trial into a new store at ``out``. Bad trials are skipped and listed in the report;
    if none is usable nothing is written. The store is complete only once everything is in it."""

    started = _time.time()
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    if store_exists(out) and not overwrite:
        raise StoreError(f"{out} already exists; pass --overwrite to replace it, or choose another --out")
    files = trial_files(list(inputs))
    trials, skipped = [], []
    for path in files:
        try:
            trials.append(import_trial(path, shape, settings))
        except TrialError as exc:
            skipped.append({"file": str(path), "reason": str(exc)})
    if not trials:
        first = f" (first: {Path(skipped[0]['file']).name}: {skipped[0]['reason']})" if skipped else ""
        raise PhysdynError(f"none of the {len(files)} trial(s) could be imported{first}; nothing written")
    split = split_trials(len(trials), settings)
    arrays = store_arrays(trials, shape, split, settings)
    rates = sorted({round(t.input_rate_hz, 3) for t in trials})
    per_trial = [
        {"file": t.name, "frames": len(t), "split": int(s), "input_rate_hz": round(t.input_rate_hz, 4),
         "floor_offset_m": t.floor_offset, "trim_time_s": float(t.time[0]), "peak_speed": t.peak_speed,
         "toppled": t.topple_step >= 0, "notes": t.notes}
        for t, s in zip(trials, split)
    ]
    attrs = {
        "format_note": FORMAT_NOTE,
        "rate_hz": settings.rate_hz,
        "source": "mocap",
        "shape": shape.source,
        "import": asdict(settings),
        "input_rates_hz": rates,
        "trials": per_trial,
        "skipped": skipped,
    }
    with write_lock(out):  # one writer per store: a second import (or simulate) to ``out`` is refused meanwhile
        writer = StoreWriter.create(out, attrs, overwrite=overwrite)
        writer.finalize(arrays, {}, group_attrs={"shapes": {"category_names": [settings.category]}})
    return ImportReport(out=str(out), trials=per_trial, skipped=skipped, rate_hz=settings.rate_hz, input_rates_hz=rates,
                        num_frames=int(arrays["sims/start"][-1]), seconds=_time.time() - started)


def store_arrays(trials: list[ImportedTrial], shape: TrackedShape, split: np.ndarray, settings: ImportSettings) -> dict[str, np.ndarray]:
    """The store's arrays (docs/dataset-format.md) for one shape and its trials."""
    M = len(trials)
    spec = shape.spec
    lengths = np.array([len(t) for t in trials], dtype=np.int64)
    cat = lambda name: np.concatenate([getattr(t, name) for t in trials])  # noqa: E731
    return {
        "shapes/points": shape.surface_points(settings.num_points, settings.oversample, seed=settings.seed)[None],
        "shapes/com_mesh": shape.com_mesh[None].astype(np.float64),
        "shapes/mass": np.array([spec.mass]),
        "shapes/inertia_diag": np.asarray(spec.inertia_diag, np.float64)[None],
        "shapes/inertia_orientation_xyzw": spec.principal_quat_xyzw[None],
        "shapes/category": np.zeros(1, np.int32),
        "shapes/source": np.array([shape.source], dtype=str),
        "shapes/volume": np.array([shape.volume]),
        "shapes/extents": np.asarray(shape.mesh.extents, np.float64)[None],
        "shapes/split": np.zeros(1, np.int8),  # one shape, split by trial: see sims/split
        "sims/shape_id": np.zeros(M, np.int64),
        "sims/start": np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        "sims/split": split.astype(np.int8),
        "sims/toppled": np.array([t.topple_step >= 0 for t in trials], bool),
        "sims/topple_step": np.array([t.topple_step for t in trials], np.int32),
        "sims/friction": np.full(M, settings.friction, np.float64),
        "sims/impulse": np.full((M, 3), np.nan),  # unknown: a hand push
        "sims/impulse_point": np.full((M, 3), np.nan),
        "sims/trial": np.array([t.name for t in trials], dtype=str),
        "sims/floor_offset": np.array([t.floor_offset for t in trials], np.float64),
        "sims/trim_time": np.array([t.time[0] for t in trials], np.float64),
        "sims/peak_speed": np.array([t.peak_speed for t in trials], np.float64),
        "sims/input_rate_hz": np.array([t.input_rate_hz for t in trials], np.float64),
        "frames/com_position": cat("com_position"),
        "frames/orientation_xyzw": cat("orientation_xyzw"),
        "frames/linear_velocity": cat("linear_velocity"),
        "frames/angular_velocity": cat("angular_velocity"),
        "frames/topple_label": cat("topple_label").astype(bool),
        "frames/time": cat("time"),
    }
