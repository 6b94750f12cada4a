"""`physdyn pretrain`: train the shape encoder on shape classification."""

from __future__ import annotations

import argparse

from physdyn.cli import split_overrides
from physdyn.config import preset_path

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 29

EPILOG = """\
examples:
  physdyn pretrain --config configs/experiment/pretrain.yaml
  physdyn pretrain --config configs/experiment/pretrain.yaml data.modelnet_root=data/ModelNet40
  physdyn pretrain --config configs/experiment/pretrain.yaml data.families.mugs=20 data.families.bottles=20 trainer.max_epochs=5
then start a dynamics model from it:
  physdyn fit --config configs/experiment/paper.yaml model.encoder_init=runs/pretrain/encoder.pt
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "pretrain",
        help="pretrain the shape encoder on shape classification (for model.encoder_init)",
        description="Train a shape encoder to classify procedural shape families (default) or a "
        "ModelNet40-layout folder, and save its weights as <out_dir>/encoder.pt.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--config", metavar="FILE", help="pretraining YAML, e.g. configs/experiment/pretrain.yaml")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides (OmegaConf dotlist)")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.models.pretrain import load_pretrain_config, pretrain
    from physdyn.models.run_directory import is_global_zero_process

    config = load_pretrain_config(args.config and preset_path(args.config, "experiment"), split_overrides(args.parser, args))
    result = pretrain(config, overwrite=args.overwrite)
    if is_global_zero_process():
        acc = result.metrics.get("val/acc")
        print(f"physdyn pretrain: results in {result.out_dir}")
        print(f"  encoder weights: {result.encoder_path}" + (f" (val/acc {acc:.3f})" if acc is not None else ""))
        print(f"  use them with: physdyn fit --config ... model.encoder_init={result.encoder_path}")
    return 0
