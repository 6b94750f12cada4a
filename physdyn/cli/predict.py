"""`physdyn predict`: how does my mesh move after a push? One mesh, or a batch of requests from a JSONL file."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Any

from physdyn.errors import PhysdynError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 40

EXAMPLES = """\
examples:
  physdyn predict my_mug.obj --lin-vel 1.2 0 0 --ang-vel 0 0 3 --seconds 4 --out mug.json
  physdyn predict my_mug.obj --lin-vel 1.2 0 0 --ang-vel 0 0 3 --compare-sim --render mug.gif
  physdyn predict part.stl --scale 0.001 --lin-vel 0.8 0.2 0 --ang-vel 0 0 0 --checkpoint runs/quickstart/best.ckpt --out part.csv
  physdyn predict my_mug.obj --lin-vel 1.2 0 0 --ang-vel 0 0 3 --samples 32 --out mug.npz --plot mug.png
  physdyn predict --batch requests.jsonl --out-dir predictions/

--batch reads one JSON object per line, e.g.
  {"mesh": "mug.obj", "lin_vel": [1.2, 0, 0], "ang_vel": [0, 0, 3], "seconds": 4, "out": "mug.json"}
(optional keys: orientation_xyzw, scale, friction (default: --friction), compare_sim, render; for a distribution samples, uncertainty (a
preset name or a mapping such as {"speed_rel": 0.05}), seed, plot). Paths in a line are relative to the
requests file's folder (mesh) and to --out-dir (out, render). A bad line is reported with its number and
the others still run; the exit status is 2 if any line failed. Output format: docs/predict.md."""

BATCH_KEYS = {"mesh", "lin_vel", "ang_vel", "seconds", "out", "orientation_xyzw", "scale", "friction", "compare_sim",
              "render", "samples", "uncertainty", "seed", "plot"}
# --*-sd flag -> UncertaintyConfig key (docs/conventions.md, "Uncertainty of a push")
SPREAD_FLAGS = (("speed_sd", "speed_rel"), ("direction_sd_deg", "direction_deg"), ("spin_sd", "spin_rel"),
                ("spin_sd_abs", "spin_abs"), ("friction_sd", "friction_rel"))


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
    p.add_argument("--friction", type=float, metavar="MU", help="the effective Coulomb coefficient of the object on "
                   "the ground (default: the model's own, 0.25 for the shipped ones; the product of the two lateral "
                   "frictions in PyBullet); fast and contact_prior slide at it, other models refuse it")
    p.add_argument("--scale", type=float, default=1.0, help="multiply the mesh's coordinates by this to get metres "
                   "(0.001 for millimetres; default: %(default)s)")
    p.add_argument("--checkpoint", metavar="CKPT", help="a .ckpt written by `physdyn fit`, or a shipped model: 'fast' "
                   "(the default: nothing simulated) or 'bundled' (simulates its first 0.4 s and a topple roll-out; "
                   "docs/model-card.md)")
    p.add_argument("--out", metavar="FILE", help="write the trajectory here: .json, .npz or .csv")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--compare-sim", action="store_true",
                   help="also simulate the same initial state in PyBullet (key 'simulated' in the output)")
    p.add_argument("--render", metavar="FILE", help="write an animation: .gif (or .mp4 if ffmpeg is installed), or .html for the interactive viewer")
    p.add_argument("--fps", type=float, default=15.0, help="frames per second of --render (default: %(default)s)")
    p.add_argument("--batch", metavar="REQUESTS.jsonl", help="predict every request of a JSONL file (see below)")
    p.add_argument("--out-dir", metavar="DIR", help="with --batch: folder for the output files")
    d = p.add_argument_group("a distribution of outcomes (docs/distributions.md)")
    d.add_argument("--samples", type=int, metavar="N", help="N outcomes of the push known only roughly, made by the model's "
                   "distribution stage (fast: drawn around one roll-out with a fitted spread), and write their "
                   "distribution (.npz or .json): topple probability, final position and turn quantiles, regions")
    d.add_argument("--uncertainty", metavar="PRESET", help="how well the push is known: none, low or default (3 %%; "
                   "the default with --samples)")
    d.add_argument("--speed-sd", type=float, metavar="X", help="relative spread of the post-push speed (instead of a preset; "
                   "unset spreads from 'default')")
    d.add_argument("--direction-sd-deg", type=float, metavar="X", help="spread of its direction about the vertical, degrees")
    d.add_argument("--spin-sd", type=float, metavar="X", help="relative spread of each angular velocity axis, times |w|")
    d.add_argument("--spin-sd-abs", type=float, metavar="X", help="absolute spread of each angular velocity axis, rad/s")
    d.add_argument("--friction-sd", type=float, metavar="X", help="relative spread of friction (widens fast's spread along "
                   "the travel; sampled pushes draw it where the model takes friction: fast, contact_prior)")
    d.add_argument("--seed", type=int, default=0, help="seed of the samples (default: %(default)s)")
    d.add_argument("--plot", metavar="FILE.png", help="with --samples: a plot of the final positions with their 50 %% and 90 %% regions")
    p.add_argument("--device", default="cpu", help="where the model runs: cpu, cuda or auto (default: %(default)s)")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    from physdyn.predict.body import check_friction

    check_friction(args.friction)  # before any mesh is read: a bad value fails at once
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
    if args.samples is not None:
        return run_distribution(args, uncertainty_from_flags(args))
    given = [f"--{name.replace('_', '-')}" for name in ("uncertainty", "plot", *(f for f, _ in SPREAD_FLAGS))
             if getattr(args, name) is not None]
    if given:
        args.parser.error(f"{', '.join(given)} describe a distribution: add --samples N")
    return run_one(args)


def uncertainty_from_flags(args: argparse.Namespace):
    """--uncertainty PRESET, or the --*-sd flags as a mapping (unset keys from 'default'); checked here, so a
    bad spread fails before any work: a one-line ConfigError."""
    from physdyn.config.uncertainty import resolve_uncertainty

    spreads = {key: getattr(args, flag) for flag, key in SPREAD_FLAGS if getattr(args, flag) is not None}
    if spreads and args.uncertainty is not None:
        raise PhysdynError("pass --uncertainty PRESET or the --*-sd spreads, not both")
    flags = {f"config key 'uncertainty.{key}'": f"--{flag.replace('_', '-')}" for flag, key in SPREAD_FLAGS}
    flags["config key '--uncertainty'"] = "--uncertainty"
    try:
        return resolve_uncertainty(spreads or args.uncertainty or "default", "--uncertainty" if not spreads else "uncertainty")
    except PhysdynError as exc:  # name the flag the user typed, not the config key
        text = str(exc)
        for key, flag in flags.items():
            text = text.replace(key, flag)
        raise PhysdynError(text) from None


def print_mesh_notes(notes: list, prefix: str = "") -> None:
    """Print the mesh notes a prediction raised (PredictionWarning), once each; other warnings are noise here."""
    for note in dict.fromkeys(str(n.message) for n in notes if n.category.__name__ == "PredictionWarning"):
        print(f"{prefix}warning: {note}", file=sys.stderr)


def run_one(args: argparse.Namespace) -> int:
    from physdyn.predict.body import prepare_body
    from physdyn.predict.prediction_files import check_output_path, write_prediction
    from physdyn.predict.predictor import as_vector, check_orientation, check_seconds, load_predictor, summary

    # Every check that needs no model comes first, so bad input fails fast and writes nothing.
    lin = as_vector(args.lin_vel, "--lin-vel")
    ang = as_vector(args.ang_vel, "--ang-vel")
    check_seconds(args.seconds)
    orientation = check_orientation(args.orientation)
    if args.out:
        check_output_path(args.out, args.overwrite)
    if args.render:
        from physdyn.viz.render import check_animation_path

        check_animation_path(args.render, args.overwrite)
    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        body = prepare_body(args.mesh, args.scale).with_friction(args.friction)
        predictor = load_predictor(args.checkpoint, device=args.device)
        result = predictor.predict(body, lin, ang, seconds=args.seconds, orientation_xyzw=orientation,
                                   compare_sim=args.compare_sim)
    print_mesh_notes(notes)
    print(summary(result))
    if args.out:
        print(f"wrote {write_prediction(result, args.out, overwrite=args.overwrite)}")
    else:
        print("nothing written; pass --out FILE (.json, .npz or .csv) to save the trajectory")
    if args.render:
        from physdyn.viz.render import render_animation

        print(f"wrote {render_animation(body, result, args.render, fps=args.fps, overwrite=args.overwrite)}")
    return 0


def run_distribution(args: argparse.Namespace, uncertainty: Any) -> int:
    from physdyn.cli.predict_distribution import check_outputs, write_outputs
    from physdyn.pipeline.distribution import check_samples, describe
    from physdyn.predict.body import prepare_body
    from physdyn.predict.predictor import as_vector, check_orientation, check_seconds, load_predictor

    # Every check that needs no model comes first, so bad input fails fast and writes nothing.
    samples = check_samples(args.samples)
    lin = as_vector(args.lin_vel, "--lin-vel")
    ang = as_vector(args.ang_vel, "--ang-vel")
    check_seconds(args.seconds)
    orientation = check_orientation(args.orientation)
    if args.compare_sim:
        raise PhysdynError("--compare-sim simulates one push; drop it with --samples (benchmarks/distributions.py "
                           "compares distributions with PyBullet ensembles)")
    check_outputs(args.out, args.render, args.plot, args.overwrite)
    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always")
        body = prepare_body(args.mesh, args.scale).with_friction(args.friction)
        predictor = load_predictor(args.checkpoint, device=args.device)
        result = predictor.predict_distribution(body, lin, ang, args.seconds, uncertainty, samples, args.seed, orientation)
    print_mesh_notes(notes)
    print(describe(result))
    for path in write_outputs(result, body, (args.out, args.render, args.plot), args.overwrite):
        print(f"wrote {path}")
    if not args.out:
        print("nothing written; pass --out FILE (.npz or .json) to save the samples and the summary")
    return 0


def run_batch(args: argparse.Namespace) -> int:
    """Three passes: read and check every line (a bad line is reported and skipped), roll the good ones out
    together (``Predictor.predict_many``: one batch, meshes prepared once), write each line's files."""

    from physdyn.cli.predict_distribution import predict_request, write_outputs
    from physdyn.predict.prediction_files import write_prediction
    from physdyn.predict.predictor import load_predictor

    requests = Path(args.batch).expanduser()
    if not requests.is_file():
        raise PhysdynError(f"no requests file {requests}; pass a JSONL file with one request per line (see --help)")
    try:
        lines = requests.read_text().splitlines()
    except UnicodeDecodeError:
        raise PhysdynError(f"{requests} is not a text file; pass a JSONL file with one request per line (see --help)") from None
    out_dir = Path(args.out_dir).expanduser()
    predictor = load_predictor(args.checkpoint, device=args.device)
    failed: list[int] = []

    def report(number: int, exc: Exception) -> None:
        failed.append(number)
        text = str(exc) if isinstance(exc, PhysdynError) else f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        print(f"physdyn predict: line {number}: error: {text}", file=sys.stderr)

    good, bodies = [], {}  # bodies: (mesh path, scale) -> PreparedBody, each mesh prepared once
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            good.append(_read_request(line, number, requests.parent, out_dir, args, bodies))
        except Exception as exc:  # one broken request must not stop the others
            report(number, exc)
    results: dict[int, dict] = {}
    with warnings.catch_warnings(record=True):  # mesh notes were printed per line as each mesh was read
        warnings.simplefilter("always")
        for r in [r for r in good if "samples" in r]:  # each line's samples are one batch of their own
            try:
                results[r["number"]] = predict_request(predictor, r)
            except Exception as exc:
                report(r["number"], exc)
    good = [r for r in good if r["number"] in results or "samples" not in r]
    plain = [r for r in good if "samples" not in r]
    if plain:
        with warnings.catch_warnings(record=True):  # mesh notes were printed per line as each mesh was read
            warnings.simplefilter("always")
            try:
                batch = predictor.predict_many([r["body"] for r in plain], [r["lin_vel"] for r in plain],
                                               [r["ang_vel"] for r in plain], [r["seconds"] for r in plain],
                                               [r["orientation"] for r in plain], compare_sim=[r["compare_sim"] for r in plain])
                results.update({r["number"]: res for r, res in zip(plain, batch)})
            except Exception:  # a request the batch cannot take: predict each on its own to name it
                for r in plain:
                    try:
                        results[r["number"]] = predictor.predict(r["body"], r["lin_vel"], r["ang_vel"], r["seconds"],
                                                                 r["orientation"], compare_sim=r["compare_sim"])
                    except Exception as exc:
                        report(r["number"], exc)
    out_dir.mkdir(parents=True, exist_ok=True)
    done = 0
    for r in good:
        if r["number"] not in results:
            continue
        try:
            if "samples" in r:
                written = write_outputs(results[r["number"]], r["body"], (r["out"], r["render"], r["plot"]), args.overwrite)
            else:
                written = [write_prediction(results[r["number"]], r["out"], overwrite=args.overwrite)]
            if r["render"] is not None and "samples" not in r:
                from physdyn.viz.render import render_animation

                written.append(render_animation(r["body"], results[r["number"]], r["render"], fps=args.fps, overwrite=args.overwrite))
        except Exception as exc:
            report(r["number"], exc)
        else:
            done += 1
            print(f"line {r['number']}: wrote {', '.join(str(p) for p in written)}")
    total = done + len(failed)
    print(f"{done} of {total} requests written to {out_dir}"
          + (f"; failed: line(s) {', '.join(map(str, sorted(failed)))}" if failed else ""))
    return 2 if failed or total == 0 else 0


def _inside(folder, name: str, key: str, number: int):
    """``folder / name``, refusing a name that leads outside ``folder`` (``../x.json``, an absolute path)."""

    path = (folder / name).resolve()
    if not path.is_relative_to(Path(folder).resolve()):
        raise PhysdynError(f"\"{key}\": {name!r} leads outside --out-dir; give a name inside it")
    return folder / name


def _read_request(line: str, number: int, base, out_dir, args, bodies: dict) -> dict:
    """One JSONL line checked and its mesh prepared: everything ``predict_many`` and the writers need."""

    from physdyn.predict.body import prepare_body
    from physdyn.predict.prediction_files import check_output_path
    from physdyn.predict.predictor import as_vector, check_orientation, check_seconds

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
    compare = req.get("compare_sim", args.compare_sim)
    if not isinstance(compare, bool):
        raise PhysdynError(f"\"compare_sim\" must be true or false, got {compare!r}")
    scale = req.get("scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)):
        raise PhysdynError(f"\"scale\" must be a number, got {scale!r}")
    mesh = Path(str(req["mesh"])).expanduser()
    if not mesh.is_absolute() and (base / mesh).exists():
        mesh = base / mesh
    out = _inside(out_dir, str(req.get("out") or f"line{number}_{mesh.stem}.json"), "out", number)
    check_output_path(out, args.overwrite)
    render = _inside(out_dir, str(req["render"]), "render", number) if req.get("render") else None
    if render is not None:
        from physdyn.viz.render import check_animation_path

        check_animation_path(render, args.overwrite)
    request = {
        "number": number, "out": out, "render": render, "compare_sim": compare,
        "lin_vel": as_vector(req["lin_vel"], "lin_vel"), "ang_vel": as_vector(req["ang_vel"], "ang_vel"),
        "seconds": check_seconds(req.get("seconds", 3.0)),
        "orientation": check_orientation(req.get("orientation_xyzw")),
    }
    if "samples" in req:
        from physdyn.cli.predict_distribution import read_distribution_request

        plot = _inside(out_dir, str(req["plot"]), "plot", number) if req.get("plot") else None
        read_distribution_request(req, request, plot, args.overwrite)
    elif {"uncertainty", "seed", "plot"} & set(req):
        raise PhysdynError(f"{', '.join(sorted({'uncertainty', 'seed', 'plot'} & set(req)))} describe a distribution: add \"samples\"")
    key = (str(mesh.resolve()), float(scale))
    if key not in bodies:
        with warnings.catch_warnings(record=True) as notes:
            warnings.simplefilter("always")
            bodies[key] = prepare_body(mesh, float(scale))
        print_mesh_notes(notes, f"line {number}: ")
    request["body"] = bodies[key].with_friction(req.get("friction", args.friction))
    return request
