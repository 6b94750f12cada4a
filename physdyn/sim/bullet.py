"""PyBullet, imported once and quietly: its C extension prints a build banner to the terminal on import,
which would break the CLI's promise of one-line errors."""

from __future__ import annotations

import os
import sys


def _quiet_import():
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        import pybullet  # inside: its import prints a build banner, silenced here
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [devnull]:
            os.close(fd)
    return pybullet


pb = _quiet_import()
