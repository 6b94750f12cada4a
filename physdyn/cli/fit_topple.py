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
            "With --pointnet, instead: small PointNets that read the cloud itself (hull_surface stores; "
            "physdyn/models/topple_pointnet.py), trained on every --data store's training split, one per "
            "--seeds; no simulator at prediction, and far more accurate on new meshes given thousands of "
            "training shapes (one network of the defaults: 17 minutes on a 2-core CPU; --device cuda for a GPU). "
            "Why and how well: docs/model-card.md (Toppling)."
        ),
        epilog="examples: physdyn fit-topple --checkpoint runs/quickstart/best.ckpt --out runs/quickstart/best_topple.ckpt; "
               "physdyn fit-topple --pointnet --checkpoint runs/quickstart_hull/best.ckpt --data data/quickstart_hull_many.zarr "
               "--data data/clusters_hull.zarr --device cuda --out runs/quickstart_hull/pointnet_topple.ckpt",
    )
    p.add_argument("--checkpoint", required=True, help="a .ckpt written by `physdyn fit`")
    p.add_argument("--data", action="append", help="store to fit on (default: the store the model was trained "
                                                    "on); with --pointnet, repeat it for several")
    p.add_argument("--out", required=True, help="the checkpoint to write (.ckpt; may be --checkpoint with --overwrite)")
    p.add_argument("--num-points", type=int, help="cloud size the classifier reads (default: all the store's points); "
                                                   "with --pointnet, each cloud thinned to it, its hull vertices first "
                                                   "(a push costs that fraction of the per-point layers)")
    p.add_argument("--physics", action="store_true",
                   help="also read a 1 s PyBullet roll-out of the cloud's hull per push (more accurate; a few ms "
                        "per prediction; docs/model-card.md, Toppling)")
    p.add_argument("--pointnet", action="store_true",
                   help="PointNets over the cloud instead of the logistic regression (no simulator; needs "
                        "hull_surface stores)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="--pointnet: one network per seed (averaged)")
    p.add_argument("--steps", type=int, default=3000, help="--pointnet: training steps per network")
    p.add_argument("--batch", type=int, default=256, help="--pointnet: pushes per step (defaults: 17 min on a 2-core CPU; "
                                                          "the H200 recipe: --seeds 0 1 2 --steps 10000 --batch 1024)")
    p.add_argument("--widths", type=int, nargs="+", default=[64, 128, 256],
                   help="--pointnet: the per-point layers' widths, the last also the head's (default 64 128 256; "
                        "each push pays the per-point layers: 32 64 128 costs a quarter)")
    p.add_argument("--device", default="cpu", help="--pointnet: torch device to train on (cpu, cuda)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.data.store import load_store
    from physdyn.eval.baselines import checkpoint_and_store
    from physdyn.models.topple_classifier import fit_topple_classifier

    out = checked_out(args.out, args.overwrite)
    if args.num_points is not None and args.num_points < 16:
        raise PhysdynError(f"--num-points must be at least 16, got {args.num_points}")
    if args.pointnet and args.physics:
        raise PhysdynError("--pointnet reads the stores' clouds and simulates nothing; drop --physics")
    if not args.pointnet and args.data and len(args.data) > 1:
        raise PhysdynError("the logistic regression fits on one store; pass --data once (or --pointnet for several)")
    if args.pointnet and (min(args.seeds) < 0 or args.steps < 20 or args.batch < 1):
        raise PhysdynError(f"--seeds must be >= 0, --steps at least 20 (the networks are checked 20 times) and --batch "
                           f"at least 1; got {args.seeds}, {args.steps}, {args.batch}")
    if args.pointnet and (len(args.widths) < 2 or min(args.widths) < 1):
        raise PhysdynError(f"--widths takes two or more layer widths of at least 1 (e.g. 64 128 256), got {args.widths}")
    if args.pointnet:
        _check_device(args.device)
    model, data = checkpoint_and_store(args.checkpoint, args.data[0] if args.data else None)
    stores = [load_store(d) for d in (args.data or [data])]
    for path, store in zip(args.data or [data], stores):
        if abs(float(model.data_info.get("rate_hz", store.rate_hz)) - store.rate_hz) > 1e-6:
            raise PhysdynError(f"the model was trained at {model.data_info['rate_hz']:g} Hz and {path} is recorded at "
                               f"{store.rate_hz:g} Hz; fit on a store of the model's rate")
    if args.pointnet:
        return _fit_pointnet(args, stores, out)
    store = stores[0]
    if args.physics:
        print(f"simulating the hull of each push's cloud for 1 s ({int((store.split <= 1).sum())} pushes, a few ms each)")
    classifier, report = fit_topple_classifier(store, args.num_points, friction=model.prior_friction,
                                               physics=args.physics)
    write_with_classifier(args.checkpoint, classifier, out)
    print(f"topple classifier on {data}: validation accuracy {report['val_accuracy']:.3f} (always 'no': "
          f"{report['val_majority']:.3f}), training {report['train_accuracy']:.3f}, over "
          f"{report['train_sequences']} training sequences")
    print(f"wrote {out}")
    return 0


def checked_out(out: str, overwrite: bool) -> Path:
    """--out as a path a checkpoint may be written to (a .ckpt, not there unless ``overwrite``, writable), or a
    one-line error; shared by the commands that add to a checkpoint."""
    from physdyn.files import check_writable

    path = Path(out)
    if path.suffix != ".ckpt":
        raise PhysdynError(f"--out {path}: write a .ckpt file")
    if path.exists() and not overwrite:
        raise PhysdynError(f"--out {path} already exists; pass --overwrite to replace it or choose another --out")
    check_writable(path, "--out")
    return path


def _check_device(name: str) -> None:
    """A one-line error for a --device torch cannot train on here."""
    import torch

    try:
        device = torch.device(name)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise PhysdynError(f"--device {name}: use cpu, cuda or cuda:N")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise PhysdynError(f"--device {name}: torch sees {torch.cuda.device_count()} CUDA device(s) here; "
                           "use --device cpu or one that exists")


def _fit_pointnet(args: argparse.Namespace, stores: list, out: Path) -> int:
    from physdyn.models.topple_pointnet import POINTS_METHOD, fit_pointnet_topple

    names = args.data or ["the model's store"]
    for name, store in zip(names, stores):
        if store.points_method != POINTS_METHOD:
            raise PhysdynError(f"--data {name} holds {store.points_method} clouds; --pointnet reads {POINTS_METHOD} "
                               f"ones (simulate with points_method: {POINTS_METHOD}, e.g. configs/data/quickstart_hull.yaml)")
        if not (store.split == 0).any() or not (store.split == 1).any():
            raise PhysdynError(f"--data {name} has no training or no validation split; --pointnet needs both")
    if len({s.points.shape[1] for s in stores}) > 1:
        raise PhysdynError(f"--data stores hold clouds of {sorted({s.points.shape[1] for s in stores})} points; use one size")
    held = int(stores[0].points.shape[1])
    if args.num_points is not None and args.num_points >= held:
        raise PhysdynError(f"--num-points {args.num_points}: the stores hold {held} points a cloud; pass fewer to thin "
                           "them, or drop --num-points to read them whole")
    pushes = sum(int((s.split == 0).sum()) for s in stores)
    print(f"training {len(args.seeds)} networks on {pushes} pushes of {len(stores)} store(s), {args.steps} steps each "
          f"on {args.device}")

    def progress(seed: int, step: int, accuracy: float) -> None:
        print(f"  network {seed}: step {step}/{args.steps}, validation accuracy {accuracy:.3f}", flush=True)

    classifier, report = fit_pointnet_topple(stores, tuple(args.seeds), args.steps, args.batch, width=args.widths[-1],
                                             device=args.device, point_widths=tuple(args.widths[:-1]),
                                             num_points=args.num_points, progress=progress)
    write_with_classifier(args.checkpoint, classifier, out)
    print(f"topple classifier (PointNets) on {', '.join(names)}: validation accuracy {report['val_accuracy']:.3f} "
          f"(always 'no': {report['val_majority']:.3f}; each network {', '.join(f'{a:.3f}' for a in report['network_val_accuracy'])}), "
          f"over {report['train_sequences']} training sequences")
    print(f"wrote {out}")
    return 0


def write_with_classifier(checkpoint: str | Path, classifier, out: Path) -> None:
    """``checkpoint`` with ``classifier`` as its topple classifier, written whole to ``out``."""
    from physdyn.models.checkpoint_file import read_checkpoint, write_torch_file

    raw = read_checkpoint(checkpoint)
    raw["topple_classifier"] = classifier.to_dict()
    out.parent.mkdir(parents=True, exist_ok=True)
    write_torch_file(raw, out)
