"""Prediction files: one trajectory per file, JSON by default, .npz or .csv by the extension, with the same
keys (docs/conventions.md, "Prediction output"; layout in docs/predict.md). ``write_prediction`` writes one
whole or not at all; ``read_prediction`` reads any of the three back into the dict ``Predictor.predict`` returns.
A distribution (``Predictor.predict_distribution``: ``kind`` "distribution") is written and read by the same
two functions as .json or .npz (docs/distributions.md): nested figures as ``key.sub`` in .npz.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from physdyn.errors import PredictionError
from physdyn.files import atomic_output, check_writable, jsonable

OUTPUT_EXTENSIONS = (".json", ".npz", ".csv")
DISTRIBUTION_EXTENSIONS = (".npz", ".json")  # a distribution's (N, T, 3) arrays have no one-row-per-step table
STEP_KEYS = ("time", "com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability")
# CSV column suffixes of the per-step vectors.
_COMPONENTS = {"com_position": "xyz", "orientation_xyzw": "xyzw", "linear_velocity": "xyz", "angular_velocity": "xyz"}
_CSV_COLUMN_BASE = {"orientation_xyzw": "orientation"}
_CSV_SCALAR = re.compile(r"^# ([A-Za-z_]+): (.*)$")  # "# rate_hz: 15.0": a scalar key and its JSON value


def check_output_path(path: str | Path, overwrite: bool = False, extensions: Sequence[str] = OUTPUT_EXTENSIONS,
                      what: str = "output") -> Path:
    """Refuse an unsupported extension, or an existing file unless ``overwrite``, before any work is done."""
    path = Path(path).expanduser()
    ext = path.suffix.lower()
    if ext not in extensions:
        raise PredictionError(f"{what} {path}: unsupported extension '{ext or '(none)'}'; use one of {', '.join(extensions)}")
    if path.is_dir():
        raise PredictionError(f"{what} {path} is a folder; pass a file name such as {path / ('prediction' + extensions[0])}")
    if path.exists() and not overwrite:
        raise PredictionError(f"{what} {path} already exists; pass --overwrite (overwrite=True) to replace it")
    check_writable(path, what)
    return path


def _flat(result: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``simulated`` nested keys -> ``simulated_<key>`` (npz and CSV cannot nest)."""
    out: dict[str, Any] = {}
    for key, value in result.items():
        if key == "simulated" and isinstance(value, dict):
            out.update(_flat(value, prefix + "simulated_"))
        else:
            out[prefix + key] = value
    return out


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    sim: dict[str, Any] = {}
    for key, value in flat.items():
        if key.startswith("simulated_"):
            sim[key[len("simulated_"):]] = value
        else:
            out[key] = value
    if sim:
        out["simulated"] = sim
    return out


def write_prediction(result: dict[str, Any], path: str | Path, overwrite: bool = False) -> Path:
    """Write ``result`` to ``path``: JSON, or .npz / .csv by the extension (docs/predict.md).

    Written to a temporary file in the same folder and renamed into place, so a reader never sees half a
    file. Refuses an existing ``path`` unless ``overwrite``.
    """
    distribution = is_distribution(result)
    path = check_output_path(path, overwrite, DISTRIBUTION_EXTENSIONS if distribution else OUTPUT_EXTENSIONS,
                             "distribution output" if distribution else "output")
    path.parent.mkdir(parents=True, exist_ok=True)
    ext = path.suffix.lower()
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        if ext == ".json":
            fh.write(json.dumps(jsonable(result), indent=1).encode())
        elif ext == ".npz":
            np.savez(fh, **(_dotted(result) if distribution else _npz_arrays(result)))
        else:
            fh.write(_csv_text(result).encode())
        if not overwrite and path.exists():
            raise PredictionError(f"output {path} appeared while writing; pass --overwrite to replace it")
    return path


def _npz_arrays(result: dict[str, Any]) -> dict[str, np.ndarray]:
    arrays = {}
    for key, value in _flat(result).items():
        if value is None:  # a model without a topple head: NaN at every step (see docs/predict.md)
            value = np.full(len(result["time"]), np.nan)
        arrays[key] = np.asarray(value)
    return arrays


def _csv_columns(key: str) -> list[str]:
    """CSV columns of a per-step key: vectors get one column per component (``com_position_x``...,
    ``orientation_x``...``orientation_w``), scalars one column; a ``simulated_`` prefix is kept."""
    for name, comps in _COMPONENTS.items():
        if key == name or key.endswith("_" + name):
            stem = key[: -len(name)] + _CSV_COLUMN_BASE.get(name, name)
            return [f"{stem}_{c}" for c in comps]
    return [key]


def _csv_text(result: dict[str, Any]) -> str:
    flat = _flat(result)
    T = len(result["time"])
    lines = ["# physdyn prediction: one row per step; scalars in these comment lines as JSON values"]
    header: list[str] = []
    columns: list[np.ndarray] = []
    for key, value in flat.items():
        is_step = key.split("simulated_", 1)[-1] in STEP_KEYS
        if not is_step:
            lines.append(f"# {key}: {json.dumps(jsonable({key: value})[key])}")
            continue
        arr = (np.full(T, np.nan) if value is None else np.asarray(value, dtype=np.float64)).reshape(T, -1)
        header += _csv_columns(key)
        columns.append(arr)
    table = np.concatenate(columns, axis=1)
    lines.append(",".join(header))
    for row in table:
        lines.append(",".join("" if np.isnan(x) else repr(float(x)) for x in row))
    return "\n".join(lines) + "\n"


def read_prediction(path: str | Path) -> dict[str, Any]:
    """A prediction file (.json, .npz or .csv) -> the dict ``Predictor.predict`` returns (arrays as
    float64 numpy arrays, ``topple_probability`` None where the model has no topple head)."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".json":
        raw = json.loads(path.read_text())
        flat = _flat(raw)
    elif ext == ".npz":
        # allow_pickle=False: an array of Python objects is unpickled when read, running any code it carries.
        with np.load(path, allow_pickle=False) as data:
            try:
                flat = {k: data[k] for k in data.files}
            except ValueError as exc:
                if "allow_pickle" not in str(exc):
                    raise
                raise PredictionError(f"{path} holds Python objects that physdyn does not load (files are read "
                                      f"without running code; docs/security.md); write prediction files with "
                                      f"`physdyn predict ... --out FILE`") from None
        for key, value in list(flat.items()):
            if value.ndim == 0:
                flat[key] = value.item()
    elif ext == ".csv":
        flat = _read_csv(path)
    else:
        raise PredictionError(f"{path}: unsupported extension '{ext}'; use one of {', '.join(OUTPUT_EXTENSIONS)}")
    if str(flat.get("kind", "")) == "distribution":
        return _distribution(flat)
    out = {}
    for key, value in flat.items():
        base = key.split("simulated_", 1)[-1]
        if base == "topple_probability":
            arr = None if value is None else np.asarray(value, dtype=np.float64)
            out[key] = None if arr is None or np.isnan(arr).all() else arr
        elif base in STEP_KEYS or base == "com_mesh":
            out[key] = np.asarray(value, dtype=np.float64)
        elif base == "toppled":
            out[key] = bool(value)
        elif base in ("rate_hz", "mesh_scale"):
            out[key] = float(value)
        else:
            out[key] = str(value)
    return _nest(out)


def _read_csv(path: Path) -> dict[str, Any]:
    flat: dict[str, Any] = {}
    rows: list[list[str]] = []
    header: list[str] | None = None
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            match = _CSV_SCALAR.match(line)
            if match:
                flat[match.group(1)] = json.loads(match.group(2))
        elif header is None:
            header = line.split(",")
        elif line:
            rows.append(line.split(","))
    assert header is not None
    table = np.array([[float(x) if x else np.nan for x in row] for row in rows], dtype=np.float64).reshape(len(rows), len(header))
    index = {name: i for i, name in enumerate(header)}
    for prefix in ("", "simulated_"):
        for key in STEP_KEYS:
            cols = _csv_columns(prefix + key)
            if all(c in index for c in cols):
                arr = table[:, [index[c] for c in cols]]
                flat[prefix + key] = arr[:, 0] if len(cols) == 1 else arr
    return flat


def is_distribution(result: dict[str, Any]) -> bool:
    """Whether ``result`` is a distribution of ``Predictor.predict_distribution`` (N sampled trajectories)."""
    return str(result.get("kind", "")) == "distribution"


def _dotted(result: dict[str, Any], prefix: str = "") -> dict[str, np.ndarray]:
    """Nested figures -> one array per ``key.sub`` (npz cannot nest); a missing figure (None) is left out."""
    out: dict[str, np.ndarray] = {}
    for key, value in result.items():
        if isinstance(value, dict):
            out.update(_dotted(value, f"{prefix}{key}."))
        elif value is not None:
            out[f"{prefix}{key}"] = np.asarray(value)
    return out


_DISTRIBUTION_SCALARS = {"kind": str, "mesh": str, "checkpoint": str, "distribution": str, "rate_hz": float, "mesh_scale": float,
                         "samples": int, "seed": int, "turn_deg_mean": float}


def _distribution(flat: dict[str, Any]) -> dict[str, Any]:
    """A distribution file's keys (``key.sub`` from .npz, nested from .json) -> ``predict_distribution``'s dict:
    arrays float64 (``toppled`` bool), quantile levels as ints, a region left out as None."""

    def value(key: str, v: Any) -> Any:
        if isinstance(v, dict):
            return {int(k) if str(k).isdigit() else k: value(str(k), x) for k, x in v.items()}
        if key in _DISTRIBUTION_SCALARS:
            return _DISTRIBUTION_SCALARS[key](v)
        if key == "toppled":
            return np.asarray(v, dtype=bool)
        if key in ("angle_deg", "level") or np.ndim(v) == 0 and not isinstance(v, (list, np.ndarray)):
            return float(v)
        return np.asarray(v, dtype=np.float64)

    nested: dict[str, Any] = {}
    for key, v in flat.items():
        parts = key.split(".")
        where = nested
        for part in parts[:-1]:
            where = where.setdefault(part, {})
        where[parts[-1]] = v
    out = {key: value(key, v) for key, v in nested.items()}
    for key in ("region_50", "region_90"):
        out.setdefault(key, None)
    return out
