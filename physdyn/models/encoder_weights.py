"""Starting a network's encoder from an encoder file of `physdyn pretrain`."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from physdyn.errors import CheckpointError, ConfigError
from physdyn.models.checkpoint_file import read_torch_file


def load_encoder_weights(network: Any, path: str | Path) -> int:
    """Copy the tensors of an encoder file from `physdyn pretrain` whose names and shapes match.

    Returns how many were copied; raises ConfigError for a missing file, another encoder kind, or no
    matching tensor at all. (The paper initialised only the PointNet part: layers whose widths differ,
    like a different feature size, keep their fresh weights.)
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config key 'model.encoder_init': no file {path}; run `physdyn pretrain` first")
    try:
        saved = read_torch_file(path, "an encoder.pt written by `physdyn pretrain`")
    except CheckpointError as exc:
        raise ConfigError(f"config key 'model.encoder_init': {exc}") from None
    name = saved.get("encoder") if isinstance(saved, dict) else None
    if name != network.config.model.encoder.name:
        raise ConfigError(
            f"config key 'model.encoder_init': {path} holds a '{name}' encoder, the model uses "
            f"'{network.config.model.encoder.name}'"
        )
    own = network.encoder.state_dict()
    matched = {k: v for k, v in saved["state_dict"].items() if k in own and own[k].shape == v.shape}
    if not any(not k.endswith("num_batches_tracked") for k in matched):
        raise ConfigError(f"config key 'model.encoder_init': no tensor of {path} fits this encoder's layer sizes")
    network.encoder.load_state_dict(matched, strict=False)
    skipped = len(own) - len(matched)
    if skipped:
        warnings.warn(f"{path}: {skipped} encoder tensors differ in size and keep their initial values", stacklevel=2)
    return len(matched)
