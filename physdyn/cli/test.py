"""`physdyn test`: roll a trained model out on a store's split, beside the baselines, and write a report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from physdyn.data import SPLITS  # a constant of a package whose __init__ imports nothing heavy
from physdyn.errors import PhysdynError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 40


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "test",
        help="evaluate a checkpoint against the baselines and write metrics and plots",
        description=(
            "Roll a trained model out on every simulation of a split, beside the stay-put and Coulomb-sliding "
            "baselines (and optionally another checkpoint such as the MLP baseline), and write metrics.json, "
            "report.md, PNG plots and viewer.html (an interactive page of the best, median and worst sequence "
            "of each category: docs/viewer.md) to --out. Definitions: docs/evaluation.md."
        ),
        epilog="example: physdyn test --checkpoint runs/quickstart/best.ckpt --data data/quickstart.zarr --out runs/quickstart/test",
    )
    p.add_argument("--checkpoint", required=True, help="a .ckpt written by `physdyn fit`")
    p.add_argument("--data", help="store to evaluate on (default: the store the model was trained on)")
    p.add_argument("--out", required=True, help="folder for metrics.json, report.md, the plots and viewer.html")
    p.add_argument("--no-viewer", action="store_true", help="do not write viewer.html (a few MB)")
    p.add_argument("--split", choices=list(SPLITS), default="test", help="default: %(default)s")
    p.add_argument("--warm-start", type=int, default=0, metavar="K",
                   help="feed the true velocities of steps 1..K before rolling out (default: %(default)s)")
    p.add_argument("--categories", nargs="+", metavar="NAME", help="evaluate only these categories")
    p.add_argument("--baseline-checkpoint", action="append", default=[], metavar="CKPT",
                   help="another model checkpoint to compare with, e.g. the MLP baseline (repeatable)")
    p.add_argument("--cloud-sim", action="store_true",
                   help="also compare with PyBullet run on the convex hull of each shape's point cloud, with the "
                        "body's mass properties (the cloud_sim baseline: 'just running the simulator' on what the "
                        "model sees; about a minute for 1,200 pushes, plus its one-step errors)")
    p.add_argument("--overwrite", action="store_true", help="replace a report already in --out")
    d = p.add_argument_group("distribution scores (a store with an ensemble: docs/evaluation.md)")
    d.add_argument("--samples", type=int, metavar="N", help="outcomes the forecast makes of each push (default: 32)")
    d.add_argument("--uncertainty", metavar="PRESET",
                   help="what the samples are drawn from: none, low or default (default: the store's ensemble's)")
    d.add_argument("--no-distribution", action="store_true", help="skip the distribution scores")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.eval.baselines import checkpoint_and_store, load_checkpoint
    from physdyn.eval.evaluate import compare
    from physdyn.eval.report import VIEWER_FILE, check_report_target, write_report

    if args.warm_start < 0:
        raise PhysdynError(f"--warm-start must be >= 0, got {args.warm_start}")
    check_report_target(args.out, args.overwrite)
    distribution = None if args.no_distribution else _distribution_options(args)
    model, data = checkpoint_and_store(args.checkpoint, args.data, stages=True)
    baselines = ["stay_put", "coulomb_slide", *(["cloud_sim"] if args.cloud_sim else []),
                 *(load_checkpoint(c) for c in args.baseline_checkpoint)]
    result = compare(model, data, baselines, split=args.split, warm_start=args.warm_start, categories=args.categories,
                     keep_trajectories=not args.no_viewer, progress=lambda line: print(f"test: {line}", file=sys.stderr, flush=True))
    kept = result["results"][result["model"]].pop("trajectories", None)
    block = None if distribution is None else _distribution(model, data, args, distribution)
    if block is not None:
        result["distribution"] = block
    paths = write_report(result, args.out, overwrite=args.overwrite)
    if kept is not None:
        paths["viewer"] = _write_viewer(result, kept, data, f"{args.out}/{VIEWER_FILE}", args.overwrite)
    else:
        _drop_stale_viewer(Path(args.out) / VIEWER_FILE)
    head = result["results"][result["model"]]["headline"]
    print(f"{result['model']} on {head['count']} non-toppling {args.split} sequences: "
          f"position {head['position']:.4g} m/step, final position (median) {head['final_position_m_median']:.4g} m")
    print(result["verdict"])
    if block is not None:
        f, d = block["forecast"], block["deterministic"]
        print(f"distribution ({block['distribution']}) of {block['samples']} samples on {block['pushes']} pushes: final position energy score "
              f"{f['position_es_cm']:.3g} cm (one roll-out {d['position_es_cm']:.3g}, floor {f['position_floor_cm']:.3g}), "
              f"orientation {f['orientation_es_deg']:.3g} deg (floor {f['orientation_floor_deg']:.3g}), "
              f"topple Brier {f['brier']:.3g} (floor {f['brier_floor']:.3g}), ECE {f['ece']:.3g}")
    print(f"wrote {', '.join(str(p) for p in paths.values())}")
    return 0


def _distribution_options(args: argparse.Namespace) -> dict:
    """--samples and --uncertainty, checked before anything runs."""
    from physdyn.config.uncertainty import resolve_uncertainty
    from physdyn.eval.distribution_eval import DEFAULT_SAMPLES
    from physdyn.pipeline.distribution import check_samples

    return {"samples": check_samples(DEFAULT_SAMPLES if args.samples is None else args.samples),
            "uncertainty": None if args.uncertainty is None else resolve_uncertainty(args.uncertainty, "--uncertainty")}


def _distribution(model, data: str, args: argparse.Namespace, options: dict) -> dict | None:
    """The distribution block on an ensemble store; None, with a line where one was asked for, on another."""
    from physdyn.data.store import load_store
    from physdyn.eval.distribution_eval import evaluate_distribution, has_ensemble

    store = load_store(data)
    if not has_ensemble(store):
        if args.samples is not None or args.uncertainty is not None:
            print(f"test: no distribution scores: {data} holds no ensemble (`physdyn simulate` with ensemble.members=K "
                  "writes one)", file=sys.stderr)
        return None
    print(f"test: scoring the distribution forecast ({options['samples']} samples a push) against the ensemble",
          file=sys.stderr, flush=True)
    return evaluate_distribution(model, store, args.split, args.categories, options["samples"], options["uncertainty"])


def _write_viewer(result: dict, kept: dict, data: str, path: str, overwrite: bool):
    """The page of the best, median and worst final position error of each category: the very roll-outs
    that were scored."""
    from physdyn.data.store import load_store
    from physdyn.viz.store_scenes import pick_sequences, store_scenes
    from physdyn.viz.viewer import write_viewer

    model_result = result["results"][result["model"]]
    picked = pick_sequences(model_result["per_sequence"])
    scenes = store_scenes(load_store(data), kept["sims"], kept["predicted"], kept["truth"],
                          [i for i, _ in picked], [label for _, label in picked])
    title = f"{result['model']} on {model_result['store']} ({model_result['split']} split)"
    return write_viewer(scenes, path, title=title, overwrite=overwrite)


def _drop_stale_viewer(page: Path) -> None:
    """A report replaced with --no-viewer must not keep the page of the evaluation it replaced; only a
    physdyn viewer page is removed (anything else of that name is the user's)."""
    from physdyn.viz.viewer import ViewerError, read_viewer_data

    if page.is_file():
        try:
            read_viewer_data(page)
        except (ViewerError, UnicodeDecodeError, ValueError):
            return
        page.unlink()
        print(f"removed {page}: it showed the evaluation this report replaces")

