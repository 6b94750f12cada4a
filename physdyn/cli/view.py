"""`physdyn view`: an interactive HTML page of predicted vs simulated motion (docs/viewer.md)."""

from __future__ import annotations

import argparse
import shutil
import webbrowser
from pathlib import Path

from physdyn.errors import PhysdynError

# Handlers import the library themselves, so `physdyn --help` stays light (see physdyn/cli/__init__.py).

ORDER = 55


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="write an interactive HTML page of predicted vs simulated motion",
        description=(
            "Write one self-contained HTML page (no server, no network: open it with a double click) that "
            "shows each object moving along its predicted trajectory beside the simulated one (ghosted), "
            "with play/pause, a time slider, orbit and zoom, the centre-of-mass paths, the topple probability "
            "over time and the error at the cursor. SOURCE is one or more prediction files of `physdyn "
            "predict` (made with --compare-sim to see the simulation), or a report folder of `physdyn test` "
            "(it holds viewer.html), or, with --checkpoint, simulation ids of a store."
        ),
        epilog=("examples:\n"
                "  physdyn view mug.json                 # writes mug.html\n"
                "  physdyn view a.json b.json --out both.html\n"
                "  physdyn view reports/quickstart       # the test report's page\n"
                "  physdyn view --checkpoint runs/quickstart/best.ckpt --data data/quickstart.zarr --sims 5 17 --out sims.html"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("source", nargs="*", metavar="SOURCE", help="prediction files (.json, .npz, .csv) or a test report folder")
    p.add_argument("--out", help="the page to write (.html; default: the prediction file's name with .html)")
    p.add_argument("--mesh", help="the mesh of the prediction, where the path recorded in the file has moved")
    p.add_argument("--scale", type=float, help="the mesh's scale to metres (default: the one recorded in the file, else 1)")
    p.add_argument("--checkpoint", help="with --data and --sims: roll this model out on simulations of a store")
    p.add_argument("--data", help="the store of --sims (default: the store the checkpoint was trained on)")
    p.add_argument("--sims", type=int, nargs="+", metavar="ID", help="simulation ids of the store (see metrics.json per_sequence.sim)")
    p.add_argument("--title", default="physdyn viewer", help="the page's title (default: %(default)s)")
    p.add_argument("--open", action="store_true", help="open the page in the default web browser")
    p.add_argument("--overwrite", action="store_true", help="replace an existing page")
    p.set_defaults(func=run, parser=p)


def run(args: argparse.Namespace) -> int:
    if args.checkpoint or args.sims:
        if args.source:
            raise PhysdynError("pass either SOURCE files or --checkpoint with --sims, not both")
        page = _from_store(args)
    elif not args.source:
        raise PhysdynError("nothing to show: pass prediction files, a test report folder, or --checkpoint with --sims")
    elif len(args.source) == 1 and Path(args.source[0]).is_dir():
        page = _from_report(args)
    else:
        page = _from_predictions(args)
    if args.open:
        webbrowser.open(page.resolve().as_uri())
    return 0


def _from_report(args: argparse.Namespace) -> Path:
    folder = Path(args.source[0])
    page = folder / "viewer.html"
    if not page.is_file():
        raise PhysdynError(f"{folder} holds no viewer.html; run `physdyn test ... --out {folder} --overwrite` to write one, "
                           "or pass prediction files")
    if args.out:
        from physdyn.viz.viewer import check_viewer_path

        out = check_viewer_path(args.out, args.overwrite)
        shutil.copyfile(page, out)
        print(f"wrote {out}")
        return out
    print(f"{page} (open it in a web browser: {page.resolve().as_uri()})")
    return page


def _find_mesh(recorded: str, prediction: Path) -> Path | None:
    for candidate in (Path(recorded).expanduser(), prediction.parent / recorded):
        if candidate.is_file():
            return candidate
    return None


def _from_predictions(args: argparse.Namespace) -> Path:
    from physdyn.geometry.mesh_io import load_mesh
    from physdyn.predict.prediction_files import read_prediction
    from physdyn.viz.viewer import check_viewer_path, scene_from_prediction, write_viewer

    files = [Path(s) for s in args.source]
    if args.out is None and len(files) > 1:
        raise PhysdynError("several prediction files make one page: pass --out PAGE.html")
    if args.mesh and len(files) > 1:
        raise PhysdynError("--mesh names the mesh of one prediction; pass one file with it")
    out = check_viewer_path(args.out or files[0].with_suffix(".html"), args.overwrite)
    scenes = []
    for path in files:
        if not path.is_file():
            raise PhysdynError(f"prediction file {path} does not exist")
        try:
            result = read_prediction(path)
        except PhysdynError:
            raise
        except Exception as exc:  # noqa: BLE001 - a truncated or foreign file
            raise PhysdynError(f"{path} is not a readable prediction file ({type(exc).__name__}: {exc}); "
                               "write one with `physdyn predict ... --out FILE`") from None
        missing = [k for k in ("rate_hz", "com_position", "orientation_xyzw", "com_mesh") if k not in result]
        if missing:
            raise PhysdynError(f"{path} is not a prediction file (no {missing[0]}); write one with `physdyn predict ... --out FILE`")
        mesh = Path(args.mesh) if args.mesh else _find_mesh(str(result.get("mesh", "")), path)
        if mesh is None:
            raise PhysdynError(f"{path} was predicted for mesh '{result.get('mesh')}', which is not found; pass --mesh PATH")
        scale = args.scale if args.scale is not None else float(result.get("mesh_scale", 1.0))
        scenes.append(scene_from_prediction(result, load_mesh(mesh, scale), title=path.name))
    page = write_viewer(scenes, out, title=args.title, overwrite=args.overwrite)
    print(f"wrote {page}")
    return page


def _from_store(args: argparse.Namespace) -> Path:
    import numpy as np

    from physdyn.data.store import load_store
    from physdyn.eval.baselines import checkpoint_and_store
    from physdyn.viz.store_scenes import rollout_scenes
    from physdyn.viz.viewer import check_viewer_path, write_viewer

    if not (args.checkpoint and args.sims):
        raise PhysdynError("--checkpoint and --sims go together: the model to roll out and the simulations to show")
    if not args.out:
        raise PhysdynError("pass --out PAGE.html for the page")
    out = check_viewer_path(args.out, args.overwrite)
    model, data = checkpoint_and_store(args.checkpoint, args.data, stages=True)
    store = load_store(data)
    sims = np.asarray(args.sims, dtype=np.int64)
    bad = sims[(sims < 0) | (sims >= store.num_sims)]
    if len(bad):
        raise PhysdynError(f"simulation {int(bad[0])} is not in {data}: ids run from 0 to {store.num_sims - 1}")
    page = write_viewer(rollout_scenes(model, store, sims), out, title=args.title, overwrite=args.overwrite)
    print(f"wrote {page}")
    return page
