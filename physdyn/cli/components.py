"""`physdyn components`: what is registered, and where it came from."""

from __future__ import annotations

import argparse

ORDER = 90


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "components",
        help="list registered shape families, encoders, predictors and heads (built-in and plugins)",
        description="List every registered component by kind, with the package it came from.",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from physdyn.registry import ALL_REGISTRIES

    for group, registry in ALL_REGISTRIES.items():
        print(f"{group} (entry-point group {registry.group}):")
        entries = registry.entries()
        if not entries:
            print("  (none)")
        width = max([len(e.name) for e in entries] + [4])
        for e in entries:
            doc = (e.cls.__doc__ or "").strip().splitlines()
            print(f"  {e.name:<{width}}  {e.source:<24} {doc[0] if doc else ''}")
    return 0
