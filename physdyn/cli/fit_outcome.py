"""`physdyn fit-outcome`: give a model (or the contact prior alone) a learned correction of where pushes end."""

from __future__ import annotations

import argparse
from pathlib import Path

from physdyn.errors import PhysdynError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 32
PRIOR = "contact_prior"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit-outcome",
        help="fit a correction of where each push comes to rest into a checkpoint (minutes; nothing simulated at prediction)",
        description=(
            "Roll the model out on every non-toppling push of the --data stores, then train small networks "
            "that read the push (step-0 velocity and spin in the frame of its travel, I_zz / m) and where the "
            "roll-out came to rest, and give the truth minus that resting pose (displacement along and across "
            "the travel, turn about the vertical); one network per --seeds, averaged, chosen on the stores' "
            "validation splits; with --pointnet the networks also read each push's step-0 cloud in the frame of "
            "its travel. Predictions of the written checkpoint then end at the corrected pose, the "
            "correction spread over the trajectory (physdyn/models/outcome_correction.py). --checkpoint "
            f"{PRIOR} starts from the contact prior alone (no network). Why and how well: docs/model-card.md."
        ),
        epilog=f"example: physdyn fit-outcome --checkpoint {PRIOR} --data data/quickstart_hull_many.zarr "
               "--data data/clusters_hull.zarr --out runs/outcome/prior_outcome.ckpt",
    )
    p.add_argument("--checkpoint", required=True,
                   help=f"a .ckpt written by `physdyn fit`, or '{PRIOR}' for the contact prior alone")
    p.add_argument("--data", action="append", help="store to fit on, repeatable (default: the store the model was "
                                                    "trained on; required with " + PRIOR + ")")
    p.add_argument("--out", required=True, help="the checkpoint to write (.ckpt)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="one network per seed (averaged)")
    p.add_argument("--steps", type=int, default=6000, help="training steps per network (default 6000: ~30 s each on one core; "
                                                               "--pointnet networks take ~0.4 s a step on the CPU)")
    p.add_argument("--batch", type=int, default=1024, help="pushes per training step")
    p.add_argument("--pointnet", action="store_true",
                   help="networks that also read each push's step-0 cloud (a PointNet; the stores' hull_surface clouds): "
                        "more accurate on irregular meshes, minutes on a GPU, an hour or more on the CPU")
    p.add_argument("--num-points", type=int, default=None,
                   help="with --pointnet: read each cloud thinned to this many points, hull vertices first (the "
                        "per-push cost scales with it); default: the stores' clouds whole")
    p.add_argument("--widths", type=int, nargs="+", default=None,
                   help="--pointnet: the per-point layers' widths, the last also the head's (default 64 128 256; the "
                        "shipped fast's: 32 64 128, a quarter of the per-push cost)")
    p.add_argument("--device", default=None, help="where --pointnet networks train: cpu (default), cuda or cuda:N")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.cli.fit_topple import _check_device, checked_out
    from physdyn.data.store import load_store
    from physdyn.eval.baselines import checkpoint_and_store
    from physdyn.eval.outcome_fit import fit_outcome_correction
    from physdyn.models.checkpoint_file import read_checkpoint, write_torch_file
    from physdyn.models.topple_pointnet import MIN_STEPS

    out = checked_out(args.out, args.overwrite)
    if min(args.seeds) < 0 or args.steps < MIN_STEPS or args.batch < 1:
        raise PhysdynError(f"--seeds must be >= 0, --steps at least {MIN_STEPS} (the networks are checked 20 times) "
                           f"and --batch at least 1; got {args.seeds}, {args.steps}, {args.batch}")
    for flag, value in (("--num-points", args.num_points), ("--widths", args.widths), ("--device", args.device)):
        if value is not None and not args.pointnet:
            raise PhysdynError(f"{flag} is for --pointnet networks, which read the cloud; add --pointnet or drop it")
    args.widths = args.widths or [64, 128, 256]
    if len(args.widths) < 2 or min(args.widths) < 1:
        raise PhysdynError(f"--widths takes two or more layer widths of at least 1 (e.g. 64 128 256), got {args.widths}")
    if args.num_points is not None and args.num_points < 4:
        raise PhysdynError(f"--num-points must be at least 4 (a cloud with volume), got {args.num_points}")
    args.device = args.device or "cpu"
    _check_device(args.device)
    if args.checkpoint == PRIOR and not Path(PRIOR).is_file():  # a file of that name comes first, as for 'fast'
        if not args.data:
            raise PhysdynError(f"--checkpoint {PRIOR} has no store of its own; pass --data STORE")
        stores = [load_store(d) for d in args.data]
        model, raw = _prior(stores[0].rate_hz, stores[0].points.shape[1]), None
    else:
        model, data = checkpoint_and_store(args.checkpoint, args.data[0] if args.data else None)
        stores = [load_store(d) for d in (args.data or [data])]
        raw = read_checkpoint(args.checkpoint)
    names = args.data or [str(model.data_info.get("store"))]
    for name, store in zip(names, stores):
        if abs(float(model.data_info.get("rate_hz", store.rate_hz)) - store.rate_hz) > 1e-6:
            raise PhysdynError(f"the model runs at {model.data_info['rate_hz']:g} Hz and {name} is recorded at "
                               f"{store.rate_hz:g} Hz; fit on stores of the model's rate")
        method = model.data_info.get("points_method") or "surface"
        if store.points_method != method or store.points.shape[1] != int(model.data_info.get("num_points") or store.points.shape[1]):
            raise PhysdynError(f"--data {name} holds {store.points_method} clouds of {store.points.shape[1]} points; the "
                               f"model reads {method} ones of {model.data_info.get('num_points')}: fit on stores of its kind")
        if not (store.split == 0).any() or not (store.split == 1).any():
            raise PhysdynError(f"--data {name} has no training or no validation split; fit-outcome needs both")
        if args.pointnet and args.num_points is not None and store.points_method != "hull_surface":
            raise PhysdynError(f"--data {name} holds {store.points_method} clouds; --num-points thins hull_surface ones "
                               "(hull vertices first): drop --num-points, or fit on hull_surface stores")
        if args.pointnet and args.num_points is not None and args.num_points >= store.points.shape[1]:
            raise PhysdynError(f"--num-points {args.num_points} is not below --data {name}'s {store.points.shape[1]} "
                               "points; drop --num-points to read the clouds whole")
    print(f"rolling the model out on {sum(int((s.topple_step < 0).sum()) for s in stores)} non-toppling pushes of "
          f"{len(stores)} store(s), then training {len(args.seeds)} network(s) of {args.steps} steps")
    seen: dict[str, int] = {}

    def progress(message: str) -> None:
        """Every fifth report of each kind (roll-out chunks, each network's checks) and the last."""
        kind = message.split(":")[0] if message.startswith("network") else "roll-out"
        seen[kind] = seen.get(kind, 0) + 1
        head = message.split(",")[0]
        total = head.rsplit("/", 1)[-1].split(" ")[0]
        if seen[kind] % 5 == 0 or head.split("/")[0].endswith(" " + total):
            print(f"  {message}", flush=True)

    correction, report = fit_outcome_correction(model, stores, tuple(args.seeds), args.steps, args.batch, progress=progress,
                                                width=args.widths[-1] if args.pointnet else 256, pointnet=args.pointnet,
                                                num_points=args.num_points, device=args.device,
                                                point_widths=tuple(args.widths[:-1]))
    if raw is None:
        raw = {"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}
    raw["outcome_correction"] = correction.to_dict()
    out.parent.mkdir(parents=True, exist_ok=True)
    write_torch_file(raw, out)
    print(f"outcome correction over {report['train_pushes']} training pushes ({report['not_at_rest']} left out: the "
          "roll-out had not come to rest); median error of the resting pose, the model's -> corrected:")
    for name, row in report["splits"].items():
        print(f"  {name} ({row['pushes']} pushes): position {row['position_cm'][0]:.2f} -> {row['position_cm'][1]:.2f} cm, "
              f"turn {row['yaw_deg'][0]:.1f} -> {row['yaw_deg'][1]:.1f} deg")
    print(f"wrote {out}")
    return 0


def _prior(rate_hz: float, num_points: int):
    """The contact prior alone at the first store's rate and cloud size (it reads hull_surface clouds)."""
    from physdyn.predict.predictor import contact_prior_predictor

    return contact_prior_predictor(rate_hz=rate_hz, num_points=num_points).model.network
