"""The `physdyn` command. Thin: each subcommand module parses its arguments and calls the library.

Every module in this package that defines ``register(subparsers)`` adds one subcommand; ``ORDER`` (an int)
sorts them in ``--help``. A subcommand's handler returns an exit code. ``main`` is the one error boundary: a ``PhysdynError``
or an operating-system error (a missing, unwritable or full place) becomes one line
``physdyn CMD: error: ...`` and exit status 2; anything unexpected says so in one line with a pointer to
``--debug``, which shows the traceback instead.

Every subcommand module is imported to build the parser, so they import the library inside their handlers:
``physdyn --help`` and argument errors answer in a third of a second instead of loading torch, Lightning,
PyBullet and trimesh first. At their top they import only what building the parser loads anyway: the standard
library, this package's helpers, ``physdyn.errors``, ``physdyn.data``'s constants and ``physdyn.config``
(omegaconf: mocap's defaults and reproduce's list of experiments need it).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import re
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
    parser.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
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
    for p in [parser, *sub.choices.values()]:
        # argparse reads "-1.5e-05" as an option name; numbers in scientific notation are values here
        p._negative_number_matcher = NEGATIVE_NUMBER
    return parser


NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)


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
    except OSError as exc:  # a missing folder, no permission, a full disk: the user's to fix, not a bug
        if args.debug:
            raise
        where = f": {exc.filename}" if exc.filename else ""
        print(f"physdyn {args.command}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        detail = f": {exc}" if str(exc) else ""
        print(f"physdyn {args.command}: interrupted{detail}", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the boundary: one line, the traceback on request
        if args.debug:
            raise
        first = str(exc).splitlines()[0] if str(exc) else ""
        print(f"physdyn {args.command}: unexpected error: {type(exc).__name__}: {first} "
              f"(this is a bug; `physdyn --debug {args.command} ...` shows the traceback)", file=sys.stderr)
        return 2


def split_overrides(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """``key=value`` overrides collected in ``args.overrides``; anything else is a usage error."""
    bad = [o for o in args.overrides if "=" not in o]
    if bad:
        parser.error(f"unexpected argument '{bad[0]}' (overrides are key=value, e.g. seed=3)")
    return list(args.overrides)


if __name__ == "__main__":
    warnings.simplefilter("default")
    sys.exit(main())
