"""Slim a training checkpoint for shipping: weights, config and normalisation, no optimiser state.

    python -m physdyn.models.export runs/quickstart/best.ckpt physdyn/assets/bundled.ckpt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from physdyn.errors import PhysdynError
from physdyn.files import atomic_output

# What DynamicsModel.load_from_checkpoint needs; the optimiser, loops and callbacks are only for resuming.
KEEP = ("state_dict", "hyper_parameters", "hparams_name", "pytorch-lightning_version", "epoch", "global_step",
        "topple_classifier")


def export_checkpoint(src: str | Path, dst: str | Path, overwrite: bool = False) -> Path:
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise PhysdynError(f"no checkpoint at {src}; train one with `physdyn fit`")
    if dst.exists() and not overwrite:
        raise PhysdynError(f"{dst} exists; pass --overwrite to replace it")
    checkpoint = torch.load(src, map_location="cpu", weights_only=False)
    if "state_dict" not in checkpoint or "hyper_parameters" not in checkpoint:
        raise PhysdynError(f"{src} is not a `physdyn fit` checkpoint")
    slim = {key: checkpoint[key] for key in KEEP if key in checkpoint}
    dst.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(dst) as tmp:  # never a half-written checkpoint under the final name
        torch.save(slim, tmp)
    return dst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src")
    parser.add_argument("dst")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args()
    try:
        out = export_checkpoint(args.src, args.dst, args.overwrite)
    except PhysdynError as exc:  # one line, like the physdyn command
        print(f"export: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
