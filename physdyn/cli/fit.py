"""`physdyn fit`: train the dynamics model on a dataset store."""

from __future__ import annotations

import argparse

from physdyn.cli import split_overrides
from physdyn.config import preset_path

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 30

EPILOG = """\
overrides are key=value pairs checked against the config schema, e.g.
  physdyn fit --config configs/experiment/quickstart.yaml
  physdyn fit --config configs/experiment/paper.yaml data.store=data/speakers.zarr
  physdyn fit --config configs/experiment/quickstart.yaml data.exclude_categories=[mugs]
  physdyn fit --config configs/experiment/quickstart.yaml trainer.max_epochs=50 trainer.accelerator=gpu
trainer.* keys go straight to lightning.Trainer (accelerator, devices, strategy, num_nodes, max_epochs,
max_steps, precision, limit_train_batches, ...). Results go to out_dir (default runs/<name>):
best.ckpt, last.ckpt, config.yaml, csv/metrics.csv, tensorboard/.
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit",
        help="train the dynamics model (PointNet + LSTM) on a dataset store",
        description="Train a dynamics model on random windows of a store's training split, keeping the "
        "checkpoint with the lowest validation loss.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--config", metavar="FILE", help="experiment: a preset name (quickstart; `physdyn configs experiment`) or a YAML file, e.g. configs/experiment/quickstart.yaml")
    p.add_argument("--resume", action="store_true", help="continue the run in out_dir from its last.ckpt")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides (OmegaConf dotlist)")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.models.run_directory import is_global_zero_process
    from physdyn.models.training import fit, load_experiment_config

    if args.resume and args.overwrite:
        args.parser.error("--resume and --overwrite exclude each other")
    config = load_experiment_config(args.config and preset_path(args.config, "experiment"), split_overrides(args.parser, args))
    result = fit(config, resume=args.resume, overwrite=args.overwrite)
    if is_global_zero_process():
        best = result.metrics.get("best_val_loss")
        print(f"physdyn fit: results in {result.out_dir}")
        print(f"  best checkpoint: {result.best_checkpoint}" + (f" (val/loss {best:.4f})" if best is not None else ""))
        print(f"  last checkpoint: {result.last_checkpoint}")
        print(f"  logs: {result.out_dir / 'csv' / 'metrics.csv'}, tensorboard --logdir {result.out_dir / 'tensorboard'}")
    return 0
