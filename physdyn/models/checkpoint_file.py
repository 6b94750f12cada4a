"""Reading a checkpoint of `physdyn fit` as a dict: the one place that turns a missing, unreadable or foreign
file into a one-line ``CheckpointError`` (loading the model, resuming, exporting, adding a topple classifier)."""

from __future__ import annotations

from pathlib import Path

import torch

from physdyn.errors import CheckpointError


def read_checkpoint(path: str | Path) -> dict:
    """The checkpoint's dict (weights, hyper-parameters, and whatever else it holds), on the CPU."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint file {path}; train one with `physdyn fit` (it writes best.ckpt and last.ckpt)")
    try:
        raw = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:
        raise CheckpointError(f"{path} is not a PyTorch checkpoint ({type(exc).__name__}); pass a .ckpt written by `physdyn fit`") from None
    hparams = raw.get("hyper_parameters") if isinstance(raw, dict) else None
    if not isinstance(hparams, dict) or not {"config", "normalization"} <= set(hparams) or "state_dict" not in raw:
        raise CheckpointError(f"{path} is not a physdyn DynamicsModel checkpoint (no physdyn config, normalisation and "
                              f"weights); pass best.ckpt or last.ckpt from a `physdyn fit` run")
    return raw
