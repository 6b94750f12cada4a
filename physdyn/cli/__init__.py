"""The `physdyn` command. Thin: each subcommand module parses its arguments and calls the library.

Every module in this package that defines ``register(subparsers)`` adds one subcommand; ``ORDER`` (an int)
sorts them in ``--help``. A subcommand's handler returns an exit code; a ``PhysdynError`` becomes a one-line
message and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import warnings

from physdyn import __version__
from physdyn.errors import PhysdynError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="physdyn",
        description="Simulate, learn and evaluate the dynamics of rigid objects pushed on a plane.",
    )
    parser.add_argument("--version", action="version", version=f"physdyn {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    modules = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):  # __main__ runs the CLI when imported
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "register"):
            modules.append(module)
    for module in sorted(modules, key=lambda m: (getattr(m, "ORDER", 100), m.__name__)):
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except PhysdynError as exc:
        print(f"physdyn {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `physdyn components | head`: the reader left; not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt as exc:
        detail = f": {exc}" if str(exc) else ""
        print(f"physdyn {args.command}: interrupted{detail}", file=sys.stderr)
        return 130


def split_overrides(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """``key=value`` overrides collected in ``args.overrides``; anything else is a usage error."""
    bad = [o for o in args.overrides if "=" not in o]
    if bad:
        parser.error(f"unexpected argument '{bad[0]}' (overrides are key=value, e.g. seed=3)")
    return list(args.overrides)


if __name__ == "__main__":
    warnings.simplefilter("default")
    sys.exit(main())
