"""`physdyn data info STORE`: what a dataset store holds."""

from __future__ import annotations

import argparse
import json

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 20


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="inspect dataset stores", description="Inspect dataset stores.")
    dsub = p.add_subparsers(dest="data_command", metavar="SUBCOMMAND", required=True)
    info = dsub.add_parser(
        "info",
        help="counts per category and split, topple share, lengths, speeds, physics",
        description="Summarise a store: counts per category and split, topple fraction, trajectory "
        "lengths, initial speeds, physics settings, and the voxel-vs-exact mass error when voxel mass was used.",
    )
    info.add_argument("store", help="path or fsspec URL of a store written by `physdyn simulate`")
    info.add_argument("--json", action="store_true", help="print the summary as JSON")
    info.set_defaults(func=run_info)


def run_info(args: argparse.Namespace) -> int:
    from physdyn.data.info import format_summary, summarize
    from physdyn.data.store import load_store

    summary = summarize(load_store(args.store))
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0
