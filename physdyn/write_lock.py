"""One writer per store and per run folder: an advisory lock that a second writer is refused by, in one line
naming the holder.

The lock for ``PATH`` is the file ``.NAME.physdyn-lock`` beside it (``NAME`` = ``PATH``'s last part), held
with ``fcntl.flock`` for as long as the writer runs. It lives *beside* the store or run folder, not inside,
because writers replace what they guard: ``--overwrite`` deletes a run folder and swaps a new store in, and a
lock file inside would go with it while still held. The file records who holds it (host, pid, since when,
the command) as JSON, for the refusal message; the lock itself is the kernel's, so a writer that dies, even by
``kill -9`` or a power cut, releases it, and the next writer takes it over and rewrites the record.

- Readers never take the lock.
- Only the process that took it holds it: child processes (``--workers`` pools, data-loader workers) close
  their inherited copy at fork, so a worker outliving a killed parent cannot keep a store locked.
- Local paths only (``file://`` URLs included). For remote fsspec URLs (s3://, gs://...) nothing is locked.
  On network file systems (NFS, SMB) ``flock`` may not be enforced between machines.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
import sys
import time
from pathlib import Path
from typing import Iterator

from physdyn.errors import WriterBusyError

SUFFIX = ".physdyn-lock"

_held: dict[int, Path] = {}  # fd -> lock file, in this process


def lock_path(target: str | Path) -> Path:
    target = Path(target).expanduser()
    return target.with_name(f".{target.name}{SUFFIX}")


def local_path(url: str | Path) -> Path | None:
    """The local path of ``url``, or None for a remote fsspec URL (which is not locked)."""
    text = str(url)
    if text.startswith("file://"):
        return Path(text[len("file://"):])
    if "://" in text:
        return None
    return Path(text)


@contextlib.contextmanager
def write_lock(target: str | Path, command: str | None = None) -> Iterator[Path | None]:
    """Hold the writer's lock on ``target`` (a store path or URL, a run folder) for the ``with`` block.

    Raises ``WriterBusyError`` at once (never waits) when another live process holds it. Yields the lock
    file, or None where nothing is locked (a remote URL)."""
    path = local_path(target)
    if path is None:
        yield None
        return
    fd, lock = _acquire(path, command)
    try:
        yield lock
    finally:
        _release(fd, lock)


def refuse_if_busy(target: str | Path) -> None:
    """Raise ``WriterBusyError`` now if another process holds ``target``'s lock; takes nothing and creates
    nothing. For a writer's first lines: refused before it spends minutes loading its inputs (the lock itself
    is taken later, where writing starts)."""
    path = local_path(target)
    if path is None:
        return
    try:
        fd = os.open(lock_path(path), os.O_RDONLY)
    except OSError:
        return  # no lock file: nobody is writing (or we cannot tell; taking the lock will say)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise WriterBusyError(f"{path} is being written by {_holder(lock_path(path))}; wait for it or stop it") from None
    finally:
        os.close(fd)  # closing drops the probe's lock, if it got one


def _acquire(target: Path, command: str | None) -> tuple[int, Path]:
    lock = lock_path(target)
    lock.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)  # not inherited by exec'd children (PEP 446)
        if not _try_lock(fd):
            os.close(fd)
            raise WriterBusyError(f"{target} is being written by {_holder(lock)}; wait for it or stop it")
        # The holder before us may have removed the file on release after we opened it: then we hold a lock on
        # a file no one else can find. Try again on the file now at that path.
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    record = {"pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%d %H:%M:%S"),
              "command": command or _command_line()}
    data = json.dumps(record).encode()
    os.ftruncate(fd, 0)  # a dead writer's record is simply replaced: the kernel released its lock
    os.pwrite(fd, data, 0)
    _held[fd] = lock
    return fd, lock


def _command_line(limit: int = 100) -> str:
    if not sys.argv or not sys.argv[0]:
        return ""
    program = "physdyn" if "physdyn" in sys.argv[0] else Path(sys.argv[0]).name  # `python -m physdyn.cli` too
    line = " ".join([program] + sys.argv[1:])
    return line if len(line) <= limit else line[: limit - 3] + "..."


def _try_lock(fd: int, tries: int = 10) -> bool:
    """Take the lock without waiting for a writer; a few short retries ride out another process's
    ``refuse_if_busy`` probe, which holds it for microseconds."""
    for attempt in range(tries):
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            if attempt < tries - 1:
                time.sleep(0.02)
    return False


def _release(fd: int, lock: Path) -> None:
    _held.pop(fd, None)
    with contextlib.suppress(OSError):
        os.unlink(lock)  # while still holding it; see the inode check in _acquire
    os.close(fd)


def _holder(lock: Path) -> str:
    """'pid 1234 on host X since 2026-11-25 18:00:00', from the holder's record. The holder writes it just after
    taking the lock, so an empty record is given a moment to appear."""
    for _ in range(20):
        try:
            record = json.loads(lock.read_text() or "null")
        except (OSError, ValueError):
            record = None
        if isinstance(record, dict) and "pid" in record:
            what = f" ({record['command']})" if record.get("command") else ""
            return f"pid {record['pid']} on host {record.get('host', '?')} since {record.get('since', '?')}{what}"
        time.sleep(0.05)
    return f"another process (its record in {lock} is unreadable)"


def _close_in_child() -> None:
    # A forked child shares the parent's open lock: closing its copy leaves the parent's lock held but lets the
    # lock go as soon as the parent dies, whatever the children do.
    for fd in list(_held):
        with contextlib.suppress(OSError):
            os.close(fd)
    _held.clear()


os.register_at_fork(after_in_child=_close_in_child)
