"""`physdyn reproduce`: run the paper's experiments (resumable) and write the results page."""

from __future__ import annotations

import argparse
import shlex
import sys

from physdyn.errors import PhysdynError
from physdyn.experiments.suite import EXPERIMENT_HELP

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 60

EPILOG = """\
experiments (--only):
{experiments}

examples:
  physdyn reproduce --scale cpu --out runs/paper-cpu            # resumable; skips finished runs
  physdyn reproduce --scale paper --out runs/paper --only combined,leave-out
  physdyn reproduce --report-only --out runs/paper-cpu --results docs/results.md
details: docs/reproduce.md
"""


def register(sub: argparse._SubParsersAction) -> None:
    listing = "\n".join(f"  {name:<14} {text}" for name, text in EXPERIMENT_HELP.items())
    p = sub.add_parser(
        "reproduce",
        help="run the paper's experiments (resumable) and write their results page",
        description=(
            "Generate the datasets, train and evaluate every model of the paper's experiments at a scale, skipping "
            "finished runs and resuming interrupted ones, then write the results page (tables and plots)."
        ),
        epilog=EPILOG.format(experiments=listing),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--scale", default="cpu", metavar="{tiny,cpu,paper}",
                   help="tiny (tests, seconds per run), cpu (about 5 hours on one core; 0.6-0.7x that with --jobs 2), paper (the paper's sizes, a GPU), "
                        "or a YAML file like configs/reproduce/cpu.yaml (default: %(default)s)")
    p.add_argument("--out", required=True, help="folder for every dataset, run and evaluation, e.g. runs/paper-cpu")
    p.add_argument("--only", metavar="A,B", help="comma-separated experiments to run (default: all)")
    p.add_argument("--workers", type=int, help="simulation worker processes (default: the scale's)")
    p.add_argument("--jobs", type=int, default=1,
                   help="runs at once, each in its own process with the CPU cores shared out (default: %(default)s; "
                        "2 on a 2-core machine: the cpu scale's trainings in about 0.6-0.7x the time)")
    p.add_argument("--report-only", action="store_true", help="run nothing; write the results page from --out")
    p.add_argument("--results", metavar="PATH",
                   help="results page to write; its plots go to PATH's folder/<stem>/ (default: OUT/results.md; the "
                        "project's page is regenerated with --results docs/results.md)")
    p.add_argument("--no-results", action="store_true", help="do not write the results page after running")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.experiments.results_page import write_results
    from physdyn.experiments.runner import run_suite

    if args.workers is not None and args.workers < 1:
        raise PhysdynError(f"--workers must be at least 1, got {args.workers}")
    if args.jobs < 1:
        raise PhysdynError(f"--jobs must be at least 1, got {args.jobs}")
    # The page goes inside --out unless named: a run never replaces a results page it did not make.
    args.results = args.results or f"{args.out.rstrip('/')}/results.md"
    command = "physdyn " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["reproduce"] else \
        f"physdyn reproduce --scale {args.scale} --out {args.out}" + (f" --only {args.only}" if args.only else "")
    if args.report_only:
        path = write_results(args.out, args.results, command=command)
        print(f"physdyn reproduce: wrote {path}")
        return 0
    only = [e.strip() for e in args.only.split(",") if e.strip()] if args.only else None
    run_suite(args.scale, args.out, only=only, workers=args.workers,
              results=None if args.no_results else args.results, command=command, jobs=args.jobs)
    return 0
