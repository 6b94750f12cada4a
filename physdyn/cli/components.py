"""`physdyn components`: what is registered, where it came from, and (``--options``) the settings each takes."""

from __future__ import annotations

import argparse
import dataclasses

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 90


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "components",
        help="list registered shape families, encoders, predictors and heads (built-in and plugins)",
        description="List every registered component by kind, with the package it came from.",
    )
    p.add_argument("--options", action="store_true",
                   help="also list each component's settings (the keys of its params in a config) and their defaults")
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
            if args.options:
                for line in _options(e.config_class):
                    print(f"  {'':<{width}}    {line}")
    return 0


def _options(config: type | None) -> list[str]:
    """``key: type = default`` for each field of a component's typed config (none: it takes no settings)."""
    if config is None:
        return ["(no settings)"]
    lines = []
    for f in dataclasses.fields(config):
        if f.default is not dataclasses.MISSING:
            default = repr(f.default)
        elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            default = repr(f.default_factory())  # type: ignore[misc]
        else:
            default = "(required)"
        kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        lines.append(f"{f.name}: {kind} = {default}")
    return lines or ["(no settings)"]
