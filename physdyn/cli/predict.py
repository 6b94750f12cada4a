"""`physdyn predict`: how does my mesh move after a push? One mesh, or a batch of requests from a JSONL file."""

from __future__ import annotations

import argparse
import sys

ORDER = 40

EXAMPLES = """\
examples:
  physdyn predict my_mug.obj --lin-vel 1.2 0 0 --ang-vel 0 0 3 --seconds 4 --out mug.json
  physdyn predict my_mug.obj --lin-vel 1.2 0 0 --ang-vel 0 0 3 --compare-sim --render mug.gif
  physdyn predict part.stl --scale 0.001 --lin-vel 0.8 0.2 0 --ang-vel 0 0 0 --checkpoint runs/quickstart/best.ckpt --out part.csv
  physdyn predict --batch requests.jsonl --out-dir predictions/

--batch reads one JSON object per line, e.g.
  {"mesh": "mug.obj", "lin_vel": [1.2, 0, 0], "ang_vel": [0, 0, 3], "seconds": 4, "out": "mug.json"}
(optional keys: orientation_xyzw, scale, compare_sim, render). Paths in a line are relative to the
requests file's folder (mesh) and to --out-dir (out, render). A bad line is reported with its number and
the others still run; the exit status is 2 if any line failed. Output format: docs/predict.md."""

BATCH_KEYS = {"mesh", "lin_vel", "ang_vel", "seconds", "out", "orientation_xyzw", "scale", "compare_sim", "render"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "predict",
        help="predict how a mesh slides, spins or topples after a push",
        description=(
            "Place MESH at rest on the ground (lowest point at z = 0, centre of mass above the origin, in the "
            "mesh's own orientation unless --orientation is given), give it the velocities right after a push "
            "and roll a trained model out. Writes the trajectory to --out (.json, .npz or .csv), or prints a "
            "summary. Units: metres, seconds, radians; z is up."
        ),
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("mesh", nargs="?", metavar="MESH", help="mesh file (.obj, .stl, .ply, .off, .glb), in metres unless --scale")
    p.add_argument("--lin-vel", nargs=3, type=float, metavar=("VX", "VY", "VZ"),
                   help="linear velocity of the centre of mass right after the push, m/s, world frame")
    p.add_argument("--ang-vel", nargs=3, type=float, metavar=("WX", "WY", "WZ"),
                   help="angular velocity right after the push, rad/s, world axes")
    p.add_argument("--seconds", type=float, default=3.0, help="how long to predict (default: %(default)s)")
    p.add_argument("--orientation", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                   help="resting orientation of the mesh frame, a quaternion (default: the mesh as it is)")
    p.add_argument("--scale", type=float, default=1.0, help="multiply the mesh's coordinates by this to get metres "
                   "(0.001 for millimetres; default: %(default)s)")
    p.add_argument("--checkpoint", metavar="CKPT", help="a .ckpt written by `physdyn fit` (default: the bundled model)")
    p.add_argument("--out", metavar="FILE", help="write the trajectory here: .json, .npz or .csv")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--compare-sim", action="store_true",
                   help="also simulate the same initial state in PyBullet (key 'simulated' in the output)")
    p.add_argument("--render", metavar="FILE", help="write an animation: .gif (or .mp4 if ffmpeg is installed)")
    p.add_argument("--fps", type=float, default=15.0, help="frames per second of --render (default: %(default)s)")
    p.add_argument("--batch", metavar="REQUESTS.jsonl", help="predict every request of a JSONL file (see below)")
    p.add_argument("--out-dir", metavar="DIR", help="with --batch: folder for the output files")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    if args.batch:
        clash = [flag for flag, value in (("MESH", args.mesh), ("--lin-vel", args.lin_vel), ("--ang-vel", args.ang_vel),
                                          ("--out", args.out), ("--render", args.render), ("--orientation", args.orientation))
                 if value]
        if clash:
            args.parser.error(f"--batch takes its requests from the file; drop {', '.join(clash)}")
        if not args.out_dir:
            args.parser.error("--batch needs --out-dir DIR for the output files")
        return run_batch(args)
    missing = [flag for flag, value in (("MESH", args.mesh), ("--lin-vel", args.lin_vel), ("--ang-vel", args.ang_vel)) if value is None]
    if missing:
        args.parser.error(f"missing {', '.join(missing)} (or use --batch REQUESTS.jsonl --out-dir DIR)")
    if args.out_dir:
        args.parser.error("--out-dir is for --batch; pass --out FILE for one mesh")
    return run_one(args)


def _warnings(notes: list, prefix: str = "") -> None:
    """Print the mesh notes a prediction raised (PredictionWarning), once each; other warnings are noise here."""
    for note in dict.fromkeys(str(n.message) for n in notes if n.category.__name__ == "PredictionWarning"):
        print(f"{prefix}warning: {note}", file=sys.stderr)


def run_one(args: argparse.Namespace) -> int:
    import warnings

    from physdyn.eval.predict import (as_vector, check_orientation, check_output_path, check_seconds, load_predictor,
                                      prepare_body, summary, write_prediction)

    # Every check that needs no model comes first, so bad input fails fast and writes nothing.
    lin = as_vector(args.lin_vel, "--lin-vel")
    ang = as_vector(args.ang_vel, "--ang-vel")
    check_seconds(args.seconds)
    orientation = check_orientation(args.orientation)
    if args.out:
        check_output_path(args.out, args.overwrite)
    if args.render:
        from physdyn.eval.render import check_animation_path

        check_animation_path(args.render, args.overwrite)
    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        body = prepare_body(args.mesh, args.scale)
        predictor = load_predictor(args.checkpoint)
        result = predictor.predict(body, lin, ang, seconds=args.seconds, orientation_xyzw=orientation,
                                   compare_sim=args.compare_sim)
    _warnings(notes)
    print(summary(result))
    if args.out:
        print(f"wrote {write_prediction(result, args.out, overwrite=args.overwrite)}")
    else:
        print("nothing written; pass --out FILE (.json, .npz or .csv) to save the trajectory")
    if args.render:
        from physdyn.eval.render import render_animation

        print(f"wrote {render_animation(body, result, args.render, fps=args.fps, overwrite=args.overwrite)}")
    return 0


def run_batch(args: argparse.Namespace) -> int:
    from pathlib import Path

    from physdyn.errors import PhysdynError
    from physdyn.eval.predict import load_predictor

    requests = Path(args.batch).expanduser()
    if not requests.is_file():
        raise PhysdynError(f"no requests file {requests}; pass a JSONL file with one request per line (see --help)")
    lines = requests.read_text().splitlines()
    out_dir = Path(args.out_dir).expanduser()
    predictor = load_predictor(args.checkpoint)
    out_dir.mkdir(parents=True, exist_ok=True)
    done, failed = 0, []
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            written = _run_request(predictor, line, number, requests.parent, out_dir, args)
        except PhysdynError as exc:
            failed.append(number)
            print(f"physdyn predict: line {number}: error: {exc}", file=sys.stderr)
        except Exception as exc:  # one broken request must not stop the others
            failed.append(number)
            print(f"physdyn predict: line {number}: error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
                  file=sys.stderr)
        else:
            done += 1
            print(f"line {number}: wrote {', '.join(str(p) for p in written)}")
    total = done + len(failed)
    print(f"{done} of {total} requests written to {out_dir}" + (f"; failed: line(s) {', '.join(map(str, failed))}" if failed else ""))
    return 2 if failed or total == 0 else 0


def _run_request(predictor, line: str, number: int, base, out_dir, args) -> list:
    import json
    import warnings
    from pathlib import Path

    from physdyn.errors import PhysdynError
    from physdyn.eval.predict import check_output_path, check_seconds, prepare_body, write_prediction

    try:
        req = json.loads(line)
    except json.JSONDecodeError as exc:
        raise PhysdynError(f"not valid JSON ({exc.msg} at column {exc.colno}); write one JSON object per line") from None
    if not isinstance(req, dict):
        raise PhysdynError(f"expected a JSON object like {{\"mesh\": ..., \"lin_vel\": [...], \"ang_vel\": [...]}}, got {type(req).__name__}")
    unknown = sorted(set(req) - BATCH_KEYS)
    if unknown:
        raise PhysdynError(f"unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(BATCH_KEYS))}")
    missing = [k for k in ("mesh", "lin_vel", "ang_vel") if k not in req]
    if missing:
        raise PhysdynError(f"missing key(s) {', '.join(missing)}")
    mesh = Path(str(req["mesh"])).expanduser()
    if not mesh.is_absolute() and (base / mesh).exists():
        mesh = base / mesh
    out = out_dir / str(req.get("out") or f"line{number}_{mesh.stem}.json")
    seconds = check_seconds(req.get("seconds", 3.0))
    check_output_path(out, args.overwrite)
    render = out_dir / str(req["render"]) if req.get("render") else None
    if render is not None:
        from physdyn.eval.render import check_animation_path

        check_animation_path(render, args.overwrite)
    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        body = prepare_body(mesh, float(req.get("scale", 1.0)))
        result = predictor.predict(body, req["lin_vel"], req["ang_vel"], seconds=seconds,
                                   orientation_xyzw=req.get("orientation_xyzw"),
                                   compare_sim=bool(req.get("compare_sim", args.compare_sim)))
    _warnings(notes, f"line {number}: ")
    written = [write_prediction(result, out, overwrite=args.overwrite)]
    if render is not None:
        from physdyn.eval.render import render_animation

        written.append(render_animation(body, result, render, fps=args.fps, overwrite=args.overwrite))
    return written
