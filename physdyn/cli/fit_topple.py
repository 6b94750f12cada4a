"""`physdyn fit-topple`: give a trained model a classifier of whether a push topples the object."""

from __future__ import annotations

import argparse
from pathlib import Path

from physdyn.errors import PhysdynError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 31


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit-topple",
        help="fit a step-0 topple classifier into a checkpoint (seconds; ~40 s with --physics; raises topple accuracy)",
        description=(
            "Fit a logistic regression that says, from the point cloud in its step-0 orientation and the "
            "step-0 velocities, whether the push topples the object (footprint edges, tipping energies, "
            "kinetic energies: physdyn/models/topple_classifier.py), on the store's training split, with "
            "its threshold chosen on the validation split; write the checkpoint with it to --out. Roll-outs "
            "of that checkpoint then report its per-step topple probabilities instead of the head's. "
            "Why and how well: docs/model-card.md (Toppling)."
        ),
        epilog="example: physdyn fit-topple --checkpoint runs/quickstart/best.ckpt --out runs/quickstart/best_topple.ckpt",
    )
    p.add_argument("--checkpoint", required=True, help="a .ckpt written by `physdyn fit`")
    p.add_argument("--data", help="store to fit on (default: the store the model was trained on)")
    p.add_argument("--out", required=True, help="the checkpoint to write (.ckpt; may be --checkpoint with --overwrite)")
    p.add_argument("--num-points", type=int, help="cloud size the classifier reads (default: all the store's points)")
    p.add_argument("--physics", action="store_true",
                   help="also read a 1 s PyBullet roll-out of the cloud's hull per push (more accurate; a few ms "
                        "per prediction; docs/model-card.md, Toppling)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.data.store import load_store
    from physdyn.eval.baselines import checkpoint_and_store
    from physdyn.files import check_writable
    from physdyn.models.checkpoint_file import read_checkpoint, write_torch_file
    from physdyn.models.topple_classifier import fit_topple_classifier

    out = Path(args.out)
    if out.suffix != ".ckpt":
        raise PhysdynError(f"--out {out}: write a .ckpt file")
    if out.exists() and not args.overwrite:
        raise PhysdynError(f"--out {out} already exists; pass --overwrite to replace it or choose another --out")
    check_writable(out, "--out")
    if args.num_points is not None and args.num_points < 16:
        raise PhysdynError(f"--num-points must be at least 16, got {args.num_points}")
    model, data = checkpoint_and_store(args.checkpoint, args.data)
    store = load_store(data)
    if abs(float(model.data_info.get("rate_hz", store.rate_hz)) - store.rate_hz) > 1e-6:
        raise PhysdynError(f"the model was trained at {model.data_info['rate_hz']:g} Hz and {data} is recorded at "
                           f"{store.rate_hz:g} Hz; fit on a store of the model's rate")
    if args.physics:
        print(f"simulating the hull of each push's cloud for 1 s ({int((store.split <= 1).sum())} pushes, a few ms each)")
    classifier, report = fit_topple_classifier(store, args.num_points, friction=model.prior_friction,
                                               physics=args.physics)
    raw = read_checkpoint(args.checkpoint)
    raw["topple_classifier"] = classifier.to_dict()
    out.parent.mkdir(parents=True, exist_ok=True)
    write_torch_file(raw, out)
    print(f"topple classifier on {data}: validation accuracy {report['val_accuracy']:.3f} (always 'no': "
          f"{report['val_majority']:.3f}), training {report['train_accuracy']:.3f}, over "
          f"{report['train_sequences']} training sequences")
    print(f"wrote {out}")
    return 0
