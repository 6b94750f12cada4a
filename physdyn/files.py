"""Writing a user's output file so that it is whole or absent, never half-written; JSON values for it."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Iterator

from tqdm import tqdm

from physdyn.errors import OutputWriteError, PhysdynError


@contextlib.contextmanager
def atomic_output(path: str | Path, suffix: str = ".part") -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder for the block to write; when the block ends the file is
    flushed to disk (fsync) and replaces ``path`` in one rename, and the folder's entry is synced too. A crash
    or a full disk at any moment leaves the previous ``path`` (or none), never a half-written one; if the block
    raises, the temporary file is deleted. ``suffix`` lets writers that go by the extension (GIF, MP4) see it.

    An ``OSError`` (a full disk, an I/O error) comes out as ``OutputWriteError``, naming ``path``, not the
    temporary file."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    except OSError as exc:
        raise OutputWriteError.of(exc, path) from None
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it owner-only; the output should read like any new file
    try:
        yield Path(tmp)
        _fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, OutputWriteError):
            raise OutputWriteError.of(exc, path) from None
        raise
    _fsync_folder(path.parent)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """``Path(path).write_bytes(data)``, but whole or not at all (see ``atomic_output``)."""
    with atomic_output(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """``Path(path).write_text(text)`` (UTF-8), but whole or not at all (see ``atomic_output``)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def save_figure_atomic(fig, path: str | Path, **kwargs: Any) -> None:
    """``fig.savefig(path)``, whole or not at all; the format comes from ``path``'s extension."""
    path = Path(path)
    with atomic_output(path, suffix=path.suffix) as tmp:
        fig.savefig(tmp, **kwargs)


def remove_stale_temporaries(folder: str | Path, names: tuple[str, ...]) -> None:
    """Delete what ``atomic_output`` left of ``names`` in ``folder`` when a writer was killed mid-write
    (``.NAME.XXXXXXXX<suffix>``). Only for a writer that holds the folder's lock (physdyn.write_lock): another
    writer's temporary file could otherwise be in use."""
    for name in names:
        for leftover in Path(folder).glob(f".{name}.*"):
            if leftover.is_file():
                leftover.unlink(missing_ok=True)


def _fsync_file(name: str | Path) -> None:
    fd = os.open(name, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable. Some file systems cannot sync a folder: the rename still happened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(path: str | Path, what: str = "output") -> None:
    """Before long work: refuse an output whose place cannot be written (a parent that is a file, a folder
    without write permission), as a one-line ``PhysdynError`` naming the place."""

    path = Path(path).expanduser()
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing != path and not existing.is_dir():
        raise PhysdynError(f"{what} {path}: {existing} is a file, not a folder; choose another place")
    folder = existing if existing.is_dir() else existing.parent
    try:  # a real probe: permission bits say nothing for root, or for read-only and virtual file systems
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise PhysdynError(f"{what} {path}: cannot write in {folder} ({exc.strerror}); choose another place") from None


class _PlainLines:
    """A stream for tqdm when the output is a file or a CI log: each refresh becomes one plain line instead
    of a carriage-return redraw (which a log keeps as hundreds of joined fragments)."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> None:
        text = text.replace("\r", "").replace("\x1b[A", "").strip()
        if text:
            self.stream.write(text + "\n")

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(total: int, desc: str, unit: str, enabled: bool = True, initial: int = 0, stream=None):
    """A tqdm bar on a terminal; elsewhere one plain line every 30 s (and at the end)."""

    stream = stream or sys.stderr
    terminal = hasattr(stream, "isatty") and stream.isatty()
    return tqdm(total=total, initial=initial, unit=unit, desc=desc, disable=not enabled, smoothing=0.1,
                file=stream if terminal else _PlainLines(stream), mininterval=0.1 if terminal else 30.0,
                dynamic_ncols=terminal, ncols=None if terminal else 100, ascii=not terminal)


def jsonable(obj: Any, nan_as_null: bool = False) -> Any:
    """``obj`` as plain JSON values, the one conversion every JSON file and attribute of physdyn goes
    through: numpy arrays and scalars become lists and numbers, tuples lists, keys strings, any other
    object its ``str``; with ``nan_as_null``, NaN and infinite numbers become null (strict JSON)."""
    def default(o: Any) -> Any:
        return o.tolist() if hasattr(o, "tolist") else str(o)

    plain = json.loads(json.dumps(obj, default=default))
    return _finite_or_none(plain) if nan_as_null else plain


def _finite_or_none(obj: Any) -> Any:
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_none(v) for v in obj]
    return obj

