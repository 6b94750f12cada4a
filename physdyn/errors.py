"""User-facing errors: raised where bad input enters, printed by the CLI as one line."""

from __future__ import annotations

from pathlib import Path


class PhysdynError(Exception):
    """An error the user can fix. The message names the problem and the fix, on one line."""


class ConfigError(PhysdynError):
    """A malformed config file or override."""


class ShapeError(PhysdynError):
    """A mesh that cannot be used: empty, degenerate, unreadable, NaN vertices..."""


class StoreError(PhysdynError):
    """A dataset store that is missing, incomplete, corrupt or would be overwritten."""


class PredictionError(PhysdynError):
    """Bad input to a prediction: a vector, a duration, an output path."""


class PredictionWarning(UserWarning):
    """Something the user should know about a prediction that still runs (e.g. an open mesh)."""


class CheckpointError(PhysdynError):
    """A checkpoint path that is missing or does not hold a physdyn DynamicsNetwork."""


class OutputWriteError(PhysdynError, OSError):
    """An output that could not be written (a full disk, an I/O error); the message names the user's path
    and says that the previous file, if any, is unchanged. Still an ``OSError`` for code that catches those."""

    @classmethod
    def of(cls, exc: OSError, path) -> OutputWriteError:
        path = Path(path)
        kept = "the previous file is unchanged" if path.exists() else "nothing was written"
        err = cls(f"cannot write {path}: {exc.strerror or exc}; {kept}")
        err.errno, err.strerror, err.filename = exc.errno, exc.strerror, str(path)
        return err

    def __str__(self) -> str:
        return str(self.args[0])


class WriterBusyError(PhysdynError):
    """Another live process is writing the same store or run folder (see physdyn/write_lock.py)."""
