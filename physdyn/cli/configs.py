"""`physdyn configs`: the presets shipped with physdyn, usable by name with --config."""

from __future__ import annotations

import argparse

from physdyn.config import PRESET_KINDS, PRESETS, list_presets

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 95


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "configs",
        help="list the shipped presets (use them by name: --config quickstart)",
        description=("List the presets shipped inside the package (the repository's configs/ folder). Pass a "
                     "name to the command of its kind: `physdyn simulate --config quickstart`, `physdyn fit "
                     "--config quickstart`, `physdyn reproduce --scale tiny`; or copy a file to start your own "
                     "(--path prints where they are)."),
    )
    p.add_argument("kind", nargs="?", choices=["data", "experiment", "model", "trainer", "reproduce", "predictor"],
                   help="only this kind")
    p.add_argument("--path", action="store_true", help="print the folder holding the presets and exit")
    p.set_defaults(func=run, parser=p)


USED_BY = {"data": "physdyn simulate --config NAME", "experiment": "physdyn fit --config NAME",
           "model": "defaults of experiment presets", "trainer": "defaults of experiment presets",
           "reproduce": "physdyn reproduce --scale NAME",
           "predictor": "physdyn predict --checkpoint NAME; load_predictor(NAME)"}


def run(args: argparse.Namespace) -> int:
    if args.path:
        print(PRESETS.resolve())
        return 0
    # the predictor presets (a pipeline of stages each: physdyn.pipeline.presets) beside the config kinds
    kinds = [args.kind] if args.kind else list(dict.fromkeys([*PRESET_KINDS, "predictor"]))
    for kind, entries in ((k, list_presets(k)[k]) for k in kinds):
        print(f"{kind} ({USED_BY[kind]}):")
        width = max((len(name) for name, _ in entries), default=0)
        for name, summary in entries:
            print(f"  {name.ljust(width)}  {summary}")
    return 0
