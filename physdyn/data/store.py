"""The dataset store: a Zarr v3 group laid out as in docs/dataset-format.md.

Writing happens in two phases so an interrupted run is never mistaken for a finished one: each block of
work lands in ``_parts/<block>`` (marked done only once fully written), and ``finalize`` concatenates the
parts in block order into the final arrays, then sets the root attribute ``complete``. Readers refuse a
store whose ``complete`` is not true.
"""

from __future__ import annotations

import contextlib
import os

import shutil
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import fsspec
import numpy as np
import zarr
from zarr.core.sync import sync  # zarr's internal API, for a store's repair path (_delete)

from physdyn.data import SPLIT_NAMES  # noqa: F401 - re-exported: readers import it from here
from physdyn.errors import StoreError
from physdyn.files import jsonable

FORMAT_VERSION = 1
PARTS = "_parts"
CHUNK_BYTES = 32 << 20

# name -> (trailing shape, dtype); the leading dimension is S (shapes), M (sims) or F (frames).
SCHEMA: dict[str, tuple[tuple[int, ...], str]] = {
    "shapes/points": ((None, 3), "float32"),  # type: ignore[dict-item]
    "shapes/com_mesh": ((3,), "float64"),
    "shapes/mass": ((), "float64"),
    "shapes/inertia_diag": ((3,), "float64"),
    "shapes/inertia_orientation_xyzw": ((4,), "float64"),
    "shapes/category": ((), "int32"),
    "shapes/source": ((), "str"),
    "sims/shape_id": ((), "int64"),
    "sims/start": ((), "int64"),
    "sims/split": ((), "int8"),
    "sims/toppled": ((), "bool"),
    "sims/topple_step": ((), "int32"),
    "sims/friction": ((), "float64"),
    "sims/impulse": ((3,), "float64"),
    "sims/impulse_point": ((3,), "float64"),
    "frames/com_position": ((3,), "float64"),
    "frames/orientation_xyzw": ((4,), "float64"),
    "frames/linear_velocity": ((3,), "float64"),
    "frames/angular_velocity": ((3,), "float64"),
    "frames/topple_label": ((), "bool"),
}


def _is_url(url: str) -> bool:
    return "://" in str(url)


def _open(url: str | Path, mode: str, attributes: dict | None = None) -> zarr.Group:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # fsspec's local filesystem does not create parent folders unless asked.
            options = {"auto_mkdir": True} if str(url).startswith("file://") else None
            return zarr.open_group(str(url), mode=mode, zarr_format=3, storage_options=options, attributes=attributes)
    except (FileNotFoundError, zarr.errors.GroupNotFoundError):
        raise StoreError(f"no dataset store at {url}; create one with `physdyn simulate`") from None
    except Exception as exc:
        raise StoreError(f"cannot open dataset store {url}: {type(exc).__name__}: {exc}") from None


def store_exists(url: str | Path) -> bool:
    if _is_url(str(url)):
        fs, path = fsspec.core.url_to_fs(str(url))
        return fs.exists(path)
    return Path(url).exists()


def remove_store(url: str | Path) -> None:
    if _is_url(str(url)):
        fs, path = fsspec.core.url_to_fs(str(url))
        if fs.exists(path):
            fs.rm(path, recursive=True)
    elif Path(url).is_dir():
        shutil.rmtree(url)
    elif Path(url).exists():
        Path(url).unlink()


@contextlib.contextmanager
def replacing_store(url: str | Path, overwrite: bool):
    """Where to write a store that may replace one at ``url``: yields the path to write to.

    Replacing a local physdyn store (``overwrite``) writes beside it (``.NAME.physdyn-new``) and swaps the
    new store in only when the body of the ``with`` succeeds, so a failed or interrupted run leaves the old
    store exactly as it was. Anything else (no store there, a remote URL) is written in place, as
    ``StoreWriter.create`` rules."""
    if not (overwrite and not _is_url(str(url)) and store_exists(url)):
        yield str(url)
        return
    target = Path(url)
    if not _is_physdyn_store(target):
        raise StoreError(f"{url} exists and is not a physdyn store; refusing to delete it, choose another --out")
    staged = target.with_name(f".{target.name}.physdyn-new")
    remove_store(staged)  # an earlier interrupted replacement: ours to drop
    try:
        yield str(staged)
    except BaseException:
        remove_store(staged)
        raise
    retired = target.with_name(f".{target.name}.physdyn-old")
    remove_store(retired)
    os.replace(target, retired)
    os.replace(staged, target)
    remove_store(retired)


def _is_physdyn_store(url: str | Path) -> bool:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            group = zarr.open_group(str(url), mode="r", zarr_format=3)
        return group.attrs.get("physdyn_format") is not None
    except Exception:
        return False


def _write_array(group: zarr.Group, name: str, data: np.ndarray) -> None:
    data = np.asarray(data)
    kind = SCHEMA.get(name, ((), str(data.dtype)))[1]
    # at most 64k rows and 32 MiB a chunk: an ensemble's row (K members x T steps) is tens of kB
    rows = max(1, min(len(data), 1 << 16, CHUNK_BYTES // max(1, data[:1].nbytes))) if data.ndim else 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # variable-length strings are "not yet in the v3 spec"
        if kind == "str" or data.dtype.kind in "UO":
            arr = group.create_array(name, shape=data.shape, dtype=str, chunks=(rows,), overwrite=True)
            if data.size:
                arr[...] = _as_unicode(data)
        else:
            arr = group.create_array(
                name, shape=data.shape, dtype=data.dtype, chunks=(rows,) + data.shape[1:], overwrite=True
            )
            if data.size:
                arr[...] = data


class StoreWriter:
    """Writes a store block by block; see the module docstring for the protocol."""

    def __init__(self, group: zarr.Group, url: str):
        self.group = group
        self.url = url

    @classmethod
    def create(cls, url: str | Path, attrs: dict, overwrite: bool = False) -> "StoreWriter":
        if store_exists(url):
            if not overwrite:
                raise StoreError(
                    f"{url} already exists; pass --resume to continue an interrupted run, "
                    f"--overwrite to replace it, or choose another --out"
                )
            if not _is_physdyn_store(url):
                raise StoreError(f"{url} exists and is not a physdyn store; refusing to delete it, choose another --out")
            remove_store(url)
        # The attributes go into the group's first metadata write: a run killed at once leaves a store that
        # --resume and --overwrite recognise as physdyn's, never a bare group that both refuse.
        group = _open(url, "w", {**jsonable(attrs), "physdyn_format": FORMAT_VERSION, "complete": False})
        return cls(group, str(url))

    @classmethod
    def resume(cls, url: str | Path, config_hash: str) -> "StoreWriter":
        group = _open(url, "r+")
        attrs = dict(group.attrs)
        if attrs.get("physdyn_format") is None:
            raise StoreError(f"{url} is not a physdyn store; choose another --out")
        if attrs.get("complete"):
            raise StoreError(f"{url} is already complete; nothing to resume (use --overwrite to regenerate)")
        if attrs.get("config_hash") != config_hash:
            raise StoreError(
                f"{url} was started with a different config; resume with the same config and overrides, "
                f"or pass --overwrite to start over"
            )
        return cls(group, str(url))

    def done_blocks(self, num_blocks: int) -> set[int]:
        """Blocks whose part is fully written. A part a killed run left half-written (even with truncated
        metadata, which zarr's local writes do not prevent) counts as not done."""
        done = set()
        for block in range(num_blocks):
            try:
                if self.group[f"{PARTS}/{block:06d}"].attrs.get("done"):
                    done.add(block)
            except Exception:
                continue
        return done

    def _delete(self, name: str) -> None:
        try:
            if name in self.group:
                del self.group[name]
        except Exception:  # unreadable metadata: remove the node's keys directly
            sync(self.group.store.delete_dir(name))

    def write_block(self, block: int, arrays: dict[str, np.ndarray], attrs: dict | None = None) -> None:
        name = f"{PARTS}/{block:06d}"
        self._delete(name)
        part = self.group.require_group(name)
        for key, value in arrays.items():
            _write_array(part, key, value)
        part.attrs.update({**jsonable(attrs or {}), "done": True})  # last: marks the part complete

    def read_block(self, block: int) -> tuple[dict[str, np.ndarray], dict]:
        part = self.group[f"{PARTS}/{block:06d}"]
        arrays = {}
        for path in _array_paths(part):
            arrays[path] = _read(part[path])
        return arrays, dict(part.attrs)

    def finalize(self, arrays: dict[str, np.ndarray], attrs: dict, group_attrs: dict[str, dict] | None = None) -> None:
        """Write the final arrays and attributes, drop the parts, then mark the store complete."""
        for key, value in arrays.items():
            _write_array(self.group, key, value)
        for name, extra in (group_attrs or {}).items():
            self.group[name].attrs.update(jsonable(extra))
        # A missing chunk reads back as fill values without any error: checksums make corruption visible.
        checksums = {key: checksum(value) for key, value in arrays.items()}
        self.group.attrs.update({**jsonable(attrs), "checksums": checksums, "arrays_written": True})
        self.complete()

    @property
    def arrays_written(self) -> bool:
        """Whether ``finalize`` wrote every final array (and their checksums): a run killed after that, while
        it removed the parts, is finished by ``complete`` alone. Its parts may be half-deleted by then."""
        return bool(self.group.attrs.get("arrays_written"))

    def complete(self) -> None:
        """Drop the parts, then mark the store complete (only after ``finalize`` wrote the final arrays)."""
        self._delete(PARTS)
        self.group.attrs["complete"] = True
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            zarr.consolidate_metadata(self.group.store)


def checksum(data: np.ndarray) -> str:
    """CRC-32 of an array's values (strings by their UTF-8 text), as 8 hex digits."""
    data = np.asarray(data)
    if data.dtype.kind in "UOT":
        raw = "\x00".join(str(v) for v in data.ravel()).encode()
    else:
        raw = np.ascontiguousarray(data).tobytes()
    return f"{zlib.crc32(raw):08x}"


def _as_unicode(data: np.ndarray) -> np.ndarray:
    """Plain fixed-width unicode, whatever string dtype zarr handed back (it may be numpy's StringDType)."""
    return np.array([str(v) for v in np.asarray(data).ravel()], dtype=str).reshape(np.shape(data))


def _read(array: zarr.Array) -> np.ndarray:
    data = array[...]
    return _as_unicode(data) if data.dtype.kind not in "biufc?" else data


def _array_paths(group: zarr.Group, prefix: str = "") -> Iterable[str]:
    for name, arr in group.arrays():
        yield f"{prefix}{name}"
    for name, sub in group.groups():
        if name != PARTS:
            yield from _array_paths(sub, f"{prefix}{name}/")


@dataclass
class StoreData:
    """A whole store in memory. Arrays follow docs/dataset-format.md; extra arrays land in ``extra``."""

    url: str
    attrs: dict
    category_names: list[str]
    points: np.ndarray  # (S, N, 3) float32, body frame
    com_mesh: np.ndarray  # (S, 3)
    mass: np.ndarray  # (S,)
    inertia_diag: np.ndarray  # (S, 3)
    inertia_orientation_xyzw: np.ndarray  # (S, 4)
    category: np.ndarray  # (S,) int
    source: np.ndarray  # (S,) str
    shape_id: np.ndarray  # (M,)
    start: np.ndarray  # (M + 1,)
    split: np.ndarray  # (M,) 0 train, 1 val, 2 test
    toppled: np.ndarray  # (M,) bool
    topple_step: np.ndarray  # (M,) -1 if none
    friction: np.ndarray  # (M,)
    impulse: np.ndarray  # (M, 3)
    impulse_point: np.ndarray  # (M, 3)
    com_position: np.ndarray  # (F, 3)
    orientation_xyzw: np.ndarray  # (F, 4)
    linear_velocity: np.ndarray  # (F, 3)
    angular_velocity: np.ndarray  # (F, 3)
    topple_label: np.ndarray  # (F,) bool
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def num_shapes(self) -> int:
        return len(self.mass)

    @property
    def num_sims(self) -> int:
        return len(self.shape_id)

    @property
    def rate_hz(self) -> float:
        return float(self.attrs["rate_hz"])

    @property
    def points_method(self) -> str:
        """How ``shapes/points`` were drawn (the generation config's ``points_method``; stores made before it
        existed, and imported ones, hold the paper's ``surface`` clouds)."""
        return str(self.attrs.get("config", {}).get("points_method", "surface"))

    def lengths(self) -> np.ndarray:
        return np.diff(self.start)

    def frames(self, sim: int) -> slice:
        return slice(int(self.start[sim]), int(self.start[sim + 1]))

    def sim_category(self) -> np.ndarray:
        return self.category[self.shape_id]


def load_store(url: str | Path) -> StoreData:
    """Read a complete store into memory; raises ``StoreError`` with the fix for anything else."""
    if not _is_url(str(url)) and not Path(url).exists():
        raise StoreError(f"no dataset store at {url}; create one with `physdyn simulate --out {url}`")
    group = _open(url, "r")
    attrs = dict(group.attrs)
    if attrs.get("physdyn_format") is None:
        raise StoreError(f"{url} is not a physdyn dataset store (no 'physdyn_format' attribute)")
    if not attrs.get("complete"):
        raise StoreError(
            f"{url} is incomplete (an interrupted `physdyn simulate`); finish it with the same command "
            f"plus --resume, or regenerate it with --overwrite"
        )
    data: dict[str, np.ndarray] = {}
    try:
        for name in _array_paths(group):
            data[name] = _read(group[name])
    except Exception as exc:
        raise StoreError(f"{url} is corrupt ({type(exc).__name__}: {exc}); regenerate it with --overwrite") from None
    missing = [k for k in SCHEMA if k not in data]
    if missing:
        raise StoreError(f"{url} is corrupt: missing arrays {', '.join(missing)}; regenerate it with --overwrite")
    for name, expected in attrs.get("checksums", {}).items():
        if name not in data:
            raise StoreError(f"{url} is corrupt: array {name} is missing; regenerate it with --overwrite")
        if checksum(data[name]) != expected:
            raise StoreError(f"{url} is corrupt: array {name} does not match its checksum; regenerate it with --overwrite")
    shapes_attrs = dict(group["shapes"].attrs)
    out = StoreData(
        url=str(url),
        attrs=attrs,
        category_names=list(shapes_attrs.get("category_names", [])),
        **{k.split("/", 1)[1]: data.pop(k) for k in list(SCHEMA)},
        extra=data,
    )
    _check_consistent(out)
    return out


def _check_consistent(d: StoreData) -> None:
    S, M, F = d.num_shapes, d.num_sims, len(d.com_position)
    problems = []
    for name in ("points", "com_mesh", "inertia_diag", "inertia_orientation_xyzw", "category", "source"):
        if len(getattr(d, name)) != S:
            problems.append(f"shapes/{name} has {len(getattr(d, name))} rows, expected {S}")
    for name in ("split", "toppled", "topple_step", "friction", "impulse", "impulse_point"):
        if len(getattr(d, name)) != M:
            problems.append(f"sims/{name} has {len(getattr(d, name))} rows, expected {M}")
    if len(d.start) != M + 1 or (M and (d.start[0] != 0 or d.start[-1] != F or np.any(np.diff(d.start) < 1))):
        problems.append("sims/start is not a non-decreasing offset table from 0 to the frame count")
    for name in ("orientation_xyzw", "linear_velocity", "angular_velocity", "topple_label"):
        if len(getattr(d, name)) != F:
            problems.append(f"frames/{name} has {len(getattr(d, name))} rows, expected {F}")
    if M and (d.shape_id.min() < 0 or d.shape_id.max() >= S):
        problems.append("sims/shape_id points outside shapes/")
    if problems:
        raise StoreError(f"{d.url} is corrupt: {problems[0]}; regenerate it with --overwrite")
