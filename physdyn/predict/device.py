"""Where a predictor's networks run: a device name checked against what torch sees."""

from __future__ import annotations

import torch

from physdyn.errors import PhysdynError


def resolve_device(device: str) -> str:
    """"cpu", "cuda" (or "cuda:N"), or "auto" (the GPU when torch sees one) -> a torch device name."""

    name = str(device).lower()
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise PhysdynError(f"device '{device}': torch sees no CUDA GPU here; use --device cpu (or auto)")
        return name
    if name != "cpu":
        raise PhysdynError(f"device '{device}': use cpu, cuda or auto")
    return name
