"""`physdyn simulate`: procedural shapes or a folder of meshes -> a Zarr store of pushes."""

from __future__ import annotations

import argparse
import os

from physdyn.cli import split_overrides
from physdyn.config import DataConfig, load_config, preset_path
from physdyn.errors import ConfigError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 10


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="generate a dataset store of simulated pushes",
        description=(
            "Simulate pushes of procedural shapes or your own meshes in PyBullet and write a Zarr store "
            "(layout: docs/dataset-format.md). Overrides are key=value pairs checked against the schema, "
            "e.g. seed=3 families.bottles.shapes=20 meshes.dir=~/meshes rate_hz=30."
        ),
        epilog="example: physdyn simulate --config configs/data/quickstart.yaml --out data/quickstart.zarr --workers 2",
    )
    p.add_argument("--config", required=True, help="data preset: a name (quickstart; `physdyn configs data`) or a YAML file, e.g. configs/data/quickstart.yaml")
    p.add_argument("--out", required=True, help="store to write: a path or an fsspec URL (s3://..., file://...)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="worker processes, one PyBullet client each (default: %(default)s)")
    p.add_argument("--executor", choices=["process", "ray"], default="process",
                   help="'ray' runs blocks on a Ray cluster (RAY_ADDRESS) or a local one; needs physdyn[ray]")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run into the same --out")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store at --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides")
    p.set_defaults(func=run, parser=p)


def clamp_workers(workers: int, local: bool = True) -> int:
    """At least 1; for local processes at most the machine's cores (more only queue up and multiply
    memory), with a note. A Ray cluster may have more cores than this machine."""

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    cores = os.cpu_count() or 1
    if local and workers > cores:
        print(f"note: --workers {workers} is more than this machine's {cores} cores; using {cores}")
        return cores
    return workers


def run(args: argparse.Namespace) -> int:
    from physdyn.data.simulated_store import generate_dataset

    cfg = load_config(DataConfig, preset_path(args.config, "data"), split_overrides(args.parser, args))
    workers = clamp_workers(args.workers, local=args.executor == "process")
    report = generate_dataset(cfg, args.out, workers=workers, executor=args.executor,
                              resume=args.resume, overwrite=args.overwrite, progress=not args.quiet)
    rate = report.num_sims / max(report.seconds, 1e-9)
    print(f"wrote {report.out}: {report.num_shapes} shapes, {report.num_sims} simulations, "
          f"{report.num_frames} frames in {report.seconds:.1f} s ({rate:.0f} sims/s)")
    if report.blocks_resumed:
        print(f"resumed: {report.blocks_resumed} blocks were already done")
    for note in sorted(set(report.warnings))[:20]:
        print(f"warning: {note}")
    if report.skipped:
        print(f"skipped {len(report.skipped)} unusable shape(s):")
        for s in report.skipped:
            print(f"  {s['family']}[{s['index']}]: {s['reason']}")
    print(f"next: physdyn data info {report.out}")
    return 0
