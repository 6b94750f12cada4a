"""`physdyn plan`: which push slides my mesh to a goal? A search over pushes with the model in the loop."""

from __future__ import annotations

import argparse
import warnings

from physdyn.errors import PredictionError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 45

EXAMPLES = """\
examples:
  physdyn plan my_box.obj --goal 0.3 0.1 --out plan.json
  physdyn plan my_box.obj --goal 0.3 0.1 --goal-yaw 30 --upright --budget 2 --verify --render plan.html
  physdyn plan part.stl --scale 0.001 --goal 0.2 0 --search model --checkpoint runs/quickstart/best.ckpt --out plan.json

The goal is the displacement of the centre of mass on the plane (m, world frame, z up) from where the
object rests, and optionally its turn about the vertical between the rest poses (deg, counter-clockwise
seen from above positive). A goal the search does not meet within the budget is still answered with the
best push found and its predicted miss. Output keys: docs/plan.md."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plan",
        help="find the push that slides a mesh to a goal (position, turn, upright)",
        description=(
            "Place MESH at rest on the ground as `physdyn predict` does and search, within a wall-clock budget, "
            "for the push (a horizontal impulse at a point of its surface) whose predicted outcome moves the "
            "centre of mass by --goal DX DY. Prints a one-line summary; writes the plan to --out (.json)."
        ),
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("mesh", metavar="MESH", help="mesh file (.obj, .stl, .ply, .off, .glb), in metres unless --scale")
    p.add_argument("--goal", nargs=2, type=float, required=True, metavar=("DX", "DY"),
                   help="displacement of the centre of mass on the plane, m, world frame")
    p.add_argument("--goal-yaw", type=float, metavar="DEG",
                   help="turn about the vertical between the rest poses, degrees, counter-clockwise from above positive (default: any)")
    p.add_argument("--upright", action="store_true", help="the object must not topple")
    p.add_argument("--budget", type=float, default=1.0, metavar="SECONDS",
                   help="wall-clock seconds the search may take (default: %(default)s)")
    p.add_argument("--scale", type=float, default=1.0, help="multiply the mesh's coordinates by this to get metres (default: %(default)s)")
    p.add_argument("--orientation", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                   help="resting orientation of the mesh frame, a quaternion (default: the mesh as it is)")
    p.add_argument("--checkpoint", metavar="CKPT", help="a .ckpt written by `physdyn fit`, or 'fast' / 'bundled' (default: fast)")
    p.add_argument("--out", metavar="FILE", help="write the plan here (.json)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--verify", action="store_true",
                   help="re-simulate the planned push in PyBullet at the conventions' step (key 'verified'; a check, not used by the search)")
    p.add_argument("--render", metavar="FILE", help="write the viewer page (.html): the answering trajectory (by default the final check's PyBullet "
                        "run), with --verify's run as the ghost")
    p.add_argument("--seed", type=int, default=0, help="seed of the search (default: %(default)s)")
    p.add_argument("--speed-min", type=float, default=None, metavar="M_PER_S",
                   help="slowest push, speed change of the free body (default: the training pushes' 0.5)")
    p.add_argument("--speed-max", type=float, default=None, metavar="M_PER_S", help="fastest push (default: 2.0)")
    p.add_argument("--height-fraction", type=float, default=None, metavar="F",
                   help="push points within the centre-of-mass height +/- F x the object's height (default: 0.25)")
    p.add_argument("--lateral-fraction", type=float, default=None, metavar="F",
                   help="push points up to F x the half-width sideways of the centre of mass (default: 0.5)")
    p.add_argument("--search", choices=("screened", "model", "pybullet"), default="screened",
                   help="what rolls out the candidates: 'screened' (default): a fast model screens 16x as many as "
                        "PyBullet at --pybullet-step ranks; 'model': the checkpoint's model alone; 'pybullet': "
                        "PyBullet at --pybullet-step alone")
    p.add_argument("--screen", choices=("prior", "model"), default="prior",
                   help="the fast model of a screened search: 'prior' (default): the contact prior, no network; "
                        "'model': the checkpoint's networks without simulator")
    p.add_argument("--pybullet-step", type=float, default=1.0 / 240.0, metavar="DT",
                   help="time step (s) of PyBullet in a screened or pybullet search (default: 1/240 = 0.004167)")
    p.add_argument("--no-check", action="store_true",
                   help="skip the final check (the best 8 candidates rolled out again at the conventions' step "
                        "in the last fifth of the budget; the best by it answers)")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.cli.predict import print_mesh_notes
    from physdyn.config import PhysicsConfig
    from physdyn.plan import PlanOptions, PushBounds, plan_push
    from physdyn.plan.files import check_plan_path, plan_summary, write_plan, write_plan_viewer
    from physdyn.plan.goal import check_budget, check_goal
    from physdyn.plan.planner import check_search
    from physdyn.predict.body import prepare_body
    from physdyn.predict.predictor import check_orientation, load_predictor

    # Every check that needs no model comes first, so a bad goal fails fast and writes nothing.
    bounds = PushBounds(args.speed_min, args.speed_max, args.height_fraction, args.lateral_fraction)
    _, speed_max, _, _ = bounds.resolved()
    check_goal(args.goal, args.goal_yaw, args.upright, speed_max, PhysicsConfig())
    check_budget(args.budget)
    check_search(args.search, args.pybullet_step, args.screen)
    if args.render and args.search != "model" and args.no_check and not args.verify:
        raise PredictionError("--render needs a trajectory: a plan ranked by PyBullet keeps none without its final "
                              "check; drop --no-check or pass --verify")
    orientation = check_orientation(args.orientation)
    if args.out:
        check_plan_path(args.out, args.overwrite)
    if args.render:
        from physdyn.viz.viewer import check_viewer_path

        check_viewer_path(args.render, args.overwrite)
    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        body = prepare_body(args.mesh, args.scale)
        predictor = load_predictor(args.checkpoint)
        options = PlanOptions(search=args.search, screen=args.screen, pybullet_step=args.pybullet_step,
                              check=not args.no_check, seed=args.seed, verify=args.verify, bounds=bounds)
        result = plan_push(predictor, body, args.goal, args.goal_yaw, args.upright, args.budget, orientation, options)
    print_mesh_notes(notes)
    print(plan_summary(result))
    if args.out:
        print(f"wrote {write_plan(result, args.out, overwrite=args.overwrite)}")
    if args.render:
        print(f"wrote {write_plan_viewer(result, body, args.render, overwrite=args.overwrite)}")
    return 0
