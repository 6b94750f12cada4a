"""Reading the files physdyn writes with ``torch.save`` without running any code they carry (and writing them
whole or not at all: ``write_torch_file``), and a checkpoint
of `physdyn fit` as a dict: the one place that turns a missing, unreadable, foreign or code-carrying file into a
one-line ``CheckpointError`` (loading the model, resuming, exporting, adding a topple classifier, starting from
a pretrained encoder). Why and what is read: docs/security.md."""

from __future__ import annotations

import io
import pickle
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import torch

from physdyn.errors import CheckpointError
from physdyn.files import write_bytes_atomic

# The types a file may hold beyond torch's weights-only set (tensors, dicts, lists, tuples, strings, numbers,
# OrderedDict, torch dtypes and devices). None: physdyn writes hyper-parameters as plain dicts
# (DynamicsModel.save_hyperparameters), the topple classifier as lists (ToppleClassifier.to_dict) or lists and
# tensors (PointNetToppleClassifier.to_dict), and
# Lightning's loop, optimiser, scheduler and callback states are dicts of numbers, strings and tensors; every
# checkpoint the bundled model ever shipped as holds nothing else. Anything outside this list, a function
# such as os.system or a class whose unpickling would call one, is refused before it is built.
ALLOWED_TYPES: list[Any] = []

_GLOBAL = re.compile(r"GLOBAL ([\w.]+)")

# The models shipped with physdyn, by name: a checkpoint argument of one of these names that is not a file
# reads the shipped one (docs/model-card.md): "fast", nothing simulated, the default; "bundled", the hybrid.
ASSETS = Path(__file__).resolve().parents[1] / "assets"
SHIPPED = {"bundled": ASSETS / "bundled.ckpt", "fast": ASSETS / "fast.ckpt"}


def shipped_or_path(path: str | Path) -> Path:
    """``path``, or the shipped model of that name when no such file exists (a one-line error when this
    installation lacks it)."""
    if str(path) in SHIPPED and not Path(path).is_file():
        shipped = SHIPPED[str(path)]
        if not shipped.is_file():
            raise CheckpointError(f"no shipped model '{path}' in this installation ({shipped} is missing); reinstall "
                                  "physdyn, or pass a checkpoint of `physdyn fit`")
        return shipped
    return Path(path)


def read_torch_file(path: str | Path, expected: str) -> Any:
    """What ``torch.save`` wrote to ``path``, on the CPU, read without running code: only tensors, containers,
    numbers and strings (and ``ALLOWED_TYPES``) are built. ``expected`` says what to pass instead (e.g. "a
    .ckpt written by `physdyn fit`"). Raises ``CheckpointError`` naming the file."""
    path = Path(path)
    try:
        with torch.serialization.safe_globals(ALLOWED_TYPES), warnings.catch_warnings():
            # torch notes a pickle protocol it does not write; such a file loads or is refused in one line below
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            # weights_only given explicitly: TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD overrides only torch's default.
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if not _is_pickled(path):
            raise CheckpointError(f"{path} is not a PyTorch checkpoint (UnpicklingError); pass {expected}") from None
        raise CheckpointError(f"{path} {_refusal(str(exc))} that physdyn does not load (files are read without "
                              f"running code; docs/security.md); pass {expected}") from None
    except Exception as exc:
        raise CheckpointError(f"{path} is not a PyTorch checkpoint ({type(exc).__name__}); pass {expected}") from None


def _is_pickled(path: Path) -> bool:
    """Whether ``path`` is torch's zip archive or a pickle (torch's old format starts with one)."""
    try:
        with path.open("rb") as f:
            return f.read(1) == b"\x80" or zipfile.is_zipfile(path)  # \x80: the pickle PROTO opcode
    except OSError:
        return False


def _refusal(message: str) -> str:
    """What torch's weights-only unpickler refused, from its message: a type or function by name, or an
    instruction it does not run."""
    found = _GLOBAL.search(message)
    if found:
        return f"holds a Python object of type '{found.group(1).rstrip('.')}'"
    detail = message.split("WeightsUnpickler error:", 1)[-1].strip().splitlines()
    return f"holds pickled data ({detail[0].strip()[:120] if detail else 'unreadable'})"


def read_checkpoint(path: str | Path) -> dict:
    """The checkpoint's dict (weights, hyper-parameters, and whatever else it holds), on the CPU. ``path`` may
    name a shipped model (``SHIPPED``)."""
    path = shipped_or_path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint file {path}; train one with `physdyn fit` (it writes best.ckpt and last.ckpt)")
    raw = read_torch_file(path, "a .ckpt written by `physdyn fit`")
    hparams = raw.get("hyper_parameters") if isinstance(raw, dict) else None
    if not isinstance(hparams, dict) or not {"config", "normalization"} <= set(hparams) or "state_dict" not in raw:
        raise CheckpointError(f"{path} is not a physdyn DynamicsModel checkpoint (no physdyn config, normalisation and "
                              f"weights); pass best.ckpt or last.ckpt from a `physdyn fit` run")
    return raw


def write_torch_file(obj: Any, path: str | Path) -> None:
    """``torch.save(obj, path)``, whole or not at all (``physdyn.files.atomic_output``). Serialised in memory
    first: torch's own file writer turns a full disk into "RuntimeError: basic_ios::clear: iostream error",
    while a plain write gives an OSError that names the file and the cause."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    write_bytes_atomic(path, buffer.getbuffer())
