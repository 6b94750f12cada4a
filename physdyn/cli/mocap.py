"""`physdyn import-mocap` (motion-capture trials -> a store) and `physdyn simulate-mocap` (synthetic trials)."""

from __future__ import annotations

import argparse

from physdyn.config import MassConfig  # the datasets' density is the default here too
from physdyn.errors import PhysdynError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 15


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import-mocap",
        help="import motion-capture trials (CSV) into a dataset store",
        description=(
            "Read one CSV per trial (header time,x,y,z,qx,qy,qz,qw: seconds, metres, the tracked body's "
            "unit quaternion in the world frame, z up, constant rate), down-sample to --rate by averaging, "
            "derive velocities, trim each trial to start at its peak speed, put the floor at z = 0 and write "
            "a store. The tracked body frame is taken as the shape's mesh frame. Bad trials are listed with "
            "the reason and skipped. Details: docs/real-world.md."
        ),
        epilog="example: physdyn import-mocap trials/ --shape box:0.073,0.060,0.170 --out data/box_real.zarr",
    )
    p.add_argument("trials", nargs="+", help="folder(s) of .csv trials, or .csv files")
    shape = p.add_mutually_exclusive_group(required=True)
    shape.add_argument("--shape", metavar="box:W,D,H", help="a box of these sizes (m), centred at the mesh origin")
    shape.add_argument("--mesh", metavar="FILE", help="the tracked object's mesh, in the tracked body frame")
    p.add_argument("--scale", type=float, default=1.0, help="multiply --mesh coordinates by this to get metres")
    p.add_argument("--out", required=True, help="store to write (a path or an fsspec URL)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store at --out")
    p.add_argument("--rate", type=float, default=30.0, help="output rate in Hz; the input rate must be a multiple (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the train/val/test split and the point cloud")
    p.add_argument("--friction", type=float, default=float("nan"),
                   help="effective Coulomb coefficient to record in sims/friction (default: NaN, unknown)")
    p.add_argument("--category", default="real", help="category name of the shape (default: %(default)s)")
    p.add_argument("--density", type=float, default=MassConfig.density,
                   help="kg/m^3 for the shape's mass properties (default: %(default)s, as the simulated datasets)")
    p.add_argument("--min-frames", type=int, default=5, help="shortest trial kept, in output frames (default: %(default)s)")
    p.add_argument("--fix-sign-flips", action="store_true",
                   help="re-align quaternion sign jumps (q -> -q) instead of skipping those trials")
    p.set_defaults(func=run_import, parser=p)

    s = sub.add_parser(
        "simulate-mocap",
        help="write motion-capture-like CSV trials from the simulator (to check import-mocap)",
        description=(
            "Simulate hand-like pushes of a box (rest, a horizontal force ramped over 0.15-0.3 s at the "
            "centre-of-mass height, release, slide to rest) and write them as a tracker would: 120 Hz CSV "
            "trials with 0.5 mm / 0.5 deg noise, plus <trial>.truth.npz with the simulator's true poses, "
            "velocities and release time."
        ),
        epilog="example: physdyn simulate-mocap --out trials/ --trials 66 --seed 0",
    )
    s.add_argument("--out", required=True, help="folder for trial_NNN.csv and trial_NNN.truth.npz")
    s.add_argument("--trials", type=int, default=66, help="number of trials (default: %(default)s, as the paper)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--shape", metavar="box:W,D,H", default="box:0.073,0.060,0.170", help="default: the paper's box")
    s.add_argument("--floor-offset", type=float, default=0.0, help="m added to every z, as a tracker origin off the floor")
    s.add_argument("--overwrite", action="store_true", help="replace CSV trials already in --out")
    s.set_defaults(func=run_simulate, parser=s)


def run_import(args: argparse.Namespace) -> int:
    from physdyn.data.mocap_import import ImportSettings, import_mocap
    from physdyn.sim.synthetic_trials import tracked_shape

    if args.rate <= 0 or args.min_frames < 1:
        raise PhysdynError("--rate must be positive and --min-frames at least 1")
    shape = tracked_shape(box=args.shape, mesh_path=args.mesh, scale=args.scale, density=args.density)
    settings = ImportSettings(rate_hz=args.rate, seed=args.seed, friction=args.friction, category=args.category,
                              min_frames=args.min_frames, fix_sign_flips=args.fix_sign_flips)
    report = import_mocap(args.trials, args.out, shape, settings, overwrite=args.overwrite)
    rates = ", ".join(f"{r:g}" for r in report.input_rates_hz)
    splits = [sum(t["split"] == s for t in report.trials) for s in (0, 1, 2)]
    offsets = [t["floor_offset_m"] * 1e3 for t in report.trials]
    print(f"input rate {rates} Hz, no gaps in the imported trials; down-sampled to {report.rate_hz:g} Hz")
    print(f"floor offset (subtracted from z): median {sorted(offsets)[len(offsets) // 2]:.2f} mm, "
          f"range {min(offsets):.2f} to {max(offsets):.2f} mm")
    for t in report.trials:
        for note in t["notes"]:
            print(f"note: {t['file']}: {note}")
    if report.skipped:
        print(f"skipped {len(report.skipped)} trial(s):")
        for s in report.skipped:
            print(f"  {s['file']}: {s['reason']}")
    print(f"wrote {report.out}: {len(report.trials)} trials ({splits[0]} train, {splits[1]} val, {splits[2]} test), "
          f"{report.num_frames} frames, shape {shape.source}")
    print(f"next: physdyn fit --config configs/experiment/realworld.yaml data.store={report.out}")
    return 0


def run_simulate(args: argparse.Namespace) -> int:
    from physdyn.sim.synthetic_trials import SyntheticSettings, simulate_mocap_trials

    settings = SyntheticSettings(floor_offset_m=args.floor_offset)
    paths = simulate_mocap_trials(args.out, trials=args.trials, seed=args.seed, box=args.shape,
                                  settings=settings, overwrite=args.overwrite)
    print(f"wrote {len(paths)} trials to {args.out} (120 Hz CSV + .truth.npz with the simulator's values)")
    print(f"next: physdyn import-mocap {args.out} --shape {args.shape} --out data/box_real.zarr")
    return 0
