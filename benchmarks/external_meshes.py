"""A model on meshes no procedural family made: objects shipped with pybullet_data, through `predict`'s path.

    python benchmarks/external_meshes.py                              # the bundled model
    python benchmarks/external_meshes.py --checkpoint runs/X/best.ckpt --pushes 10
    python benchmarks/external_meshes.py --work runs/external_val --random 60 --random-from 30 --no-named   # validation

1. Meshes: the named objects of pybullet_data (bunny, duck, teddy, mug, lego brick, domino, jenga block,
   torus, soccer ball) and its first ``--random`` "random_urdfs" objects (irregular household-like shapes),
   at the scale their URDF gives; a mesh whose largest extent falls outside the training shapes' 5-50 cm is
   scaled uniformly into [8, 40] cm. Copies go to ``--work/meshes``.
2. Simulation per the conventions: `physdyn simulate` with the ``meshes`` family (stable resting pose,
   a push over one physics step, 1/960 s, mu = 0.25, recorded at 15 Hz until at rest or 7 s).
3. Prediction through the public API, as a user would call it: ``Predictor.predict(prepare_body(mesh_file), lin_vel=v0,
   ang_vel=w0, orientation_xyzw=q0, seconds=...)`` with the simulated state right after the push.
4. Scores, over pushes (``--cloud-sim``: also PyBullet on each shape's cloud hull with its mass properties): final displacement error (the prediction starts where the object rests; the store
   one physics step after the push, so displacements from step 0 are compared) for the model, Coulomb
   sliding along v0 told mu, and staying put; final rotation error for the model and "no rotation"; topple
   accuracy against always answering the majority class.
"""

from __future__ import annotations

import argparse
import json
import re
import time
import warnings
from pathlib import Path

import numpy as np
import pybullet_data
import trimesh

from physdyn.config import DataConfig, load_config
from physdyn.data.simulated_store import generate_dataset
from physdyn.data.store import load_store
from physdyn.data.windows import store_world_inertia
from physdyn.errors import PhysdynError, PredictionWarning
from physdyn.eval.baselines import coulomb_slide
from physdyn.eval.metrics import rotation_angle_deg
from physdyn.predict.body import prepare_body
from physdyn.predict.predictor import load_predictor
from physdyn.sim.cloud_body import CloudSimulator
from physdyn.sim.trajectory import topple_labels

NAMED = {  # file under pybullet_data -> the URDF scale it is used at
    "bunny.obj": 1.0, "duck_vhacd.obj": 1.0, "teddy2_VHACD_CHs.obj": 1.0, "objects/mug.obj": 1.0,
    "lego/lego.obj": 1.0, "domino/domino.obj": 1.0, "jenga/jenga.obj": 1.0, "torus/torus.obj": 1.0,
    "soccerball.obj": 1.0,
}
SIZE_RANGE = (0.05, 0.5)  # m, the training shapes' largest extents
RESCALE_RANGE = (0.08, 0.4)


def urdf_scale(urdf: Path) -> float:
    match = re.search(r'scale="([0-9.eE+-]+)', urdf.read_text()) if urdf.is_file() else None
    return float(match.group(1)) if match else 1.0


def pybullet_sources(random_count: int, random_from: int = 0, named: bool = True) -> dict[str, tuple[Path, float]]:
    """name -> (mesh file, URDF scale): the named objects, then random_urdfs ``random_from`` onwards."""
    root = Path(pybullet_data.getDataPath())
    sources = {name: (root / name, scale) for name, scale in NAMED.items()} if named else {}
    for urdf_dir in sorted((root / "random_urdfs").iterdir())[random_from : random_from + random_count]:
        obj = urdf_dir / f"{urdf_dir.name}.obj"
        sources[f"random_urdfs/{urdf_dir.name}"] = (obj, urdf_scale(urdf_dir / f"{urdf_dir.name}.urdf"))
    return sources


def fit_training_size(mesh: trimesh.Trimesh) -> float:
    """Scale ``mesh`` in place so its largest extent lies in the training shapes' range (one outside
    ``SIZE_RANGE`` goes to the nearest end of ``RESCALE_RANGE``); returns the factor applied (1 if none)."""
    extent = float(mesh.extents.max())
    if SIZE_RANGE[0] <= extent <= SIZE_RANGE[1]:
        return 1.0
    factor = float(np.clip(extent, *RESCALE_RANGE)) / extent
    mesh.apply_scale(factor)
    return factor


def collect_meshes(folder: Path, random_count: int, random_from: int = 0, named: bool = True) -> dict[str, float]:
    """Write the scaled meshes into ``folder``; returns name -> scale applied. ``random_from``, ``named``:
    another set of meshes, e.g. random_urdfs 30-89 alone as an external validation set."""
    folder.mkdir(parents=True, exist_ok=True)
    applied = {}
    for name, (path, scale) in pybullet_sources(random_count, random_from, named).items():
        if not path.is_file():
            continue
        mesh = trimesh.load(path, force="mesh")
        if len(mesh.faces) == 0:  # random_urdfs/168 holds no faces trimesh reads
            print(f"skipped {name}: no faces")
            continue
        mesh.apply_scale(scale)
        scale *= fit_training_size(mesh)
        out = folder / (name.replace("/", "_").replace(".obj", "") + ".obj")
        mesh.export(out)
        applied[out.name] = scale
    return applied


def mesh_folder_store(meshes: Path, store_path: Path, pushes: int, workers: int = 2, overrides: tuple[str, ...] = ()):
    """The store of ``pushes`` simulations per mesh of the folder ``meshes`` (the ``meshes`` family, the
    conventions' physics), made at ``store_path`` on first use and read from there after."""
    try:
        return load_store(str(store_path))
    except PhysdynError:  # not made yet, or an interrupted run: make it afresh (it is this script's own)
        cfg = load_config(DataConfig, None, [f"families.meshes.sims_per_shape={pushes}", f"meshes.dir={meshes}",
                                             *overrides])
        generate_dataset(cfg, str(store_path), workers=workers, progress=False, overwrite=True)
        return load_store(str(store_path))


def external_store(work: Path, random_count: int, pushes: int, random_from: int = 0, no_named: bool = False):
    """The simulated store of these meshes under ``work`` (made on first use; ``pushes`` per mesh)."""
    which = f"external_{random_count}x{pushes}" + (f"_from{random_from}" if random_from else "") + ("_unnamed" if no_named else "")
    store_path = work / f"{which}.zarr"
    # another set of meshes gets a folder of its own (a folder is simulated whole)
    meshes = work / ("meshes" if not (random_from or no_named) else f"{which}_meshes")
    try:
        return load_store(str(store_path))
    except PhysdynError:  # not made yet, or an interrupted run: the meshes afresh, then the store
        collect_meshes(meshes, random_count, random_from, not no_named)
    return mesh_folder_store(meshes, store_path, pushes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default="bundled", help="default: the bundled model")
    parser.add_argument("--work", default="runs/external")
    parser.add_argument("--random", type=int, default=30, help="random_urdfs objects to add to the named ones")
    parser.add_argument("--pushes", type=int, default=10, help="pushes per mesh")
    parser.add_argument("--json", default=None, help="also write the figures here")
    parser.add_argument("--random-from", type=int, default=0,
                        help="first random_urdfs object to take (30 with --no-named: a validation set apart from the default's)")
    parser.add_argument("--no-named", action="store_true", help="leave out the named objects")
    parser.add_argument("--cloud-sim", action="store_true",
                        help="also score PyBullet on each shape's cloud hull with its mass properties (the cloud_sim "
                             "baseline of `physdyn test --cloud-sim`)")
    args = parser.parse_args()
    work = Path(args.work)
    store = external_store(work, args.random, args.pushes, args.random_from, args.no_named)
    predictor = load_predictor(args.checkpoint)
    rate = predictor.rate_hz
    if abs(rate - store.rate_hz) > 1e-9:
        raise SystemExit(f"the model predicts at {rate} Hz, the external store is recorded at {store.rate_hz} Hz")
    rows, bodies = [], {}
    simulator = CloudSimulator() if args.cloud_sim else None
    t0 = time.perf_counter()
    for i in range(store.num_sims):
        f = store.frames(i)
        p, q = store.com_position[f], store.orientation_xyzw[f]
        v0, w0 = store.linear_velocity[f.start], store.angular_velocity[f.start]
        T = len(p)
        path = str(store.source[store.shape_id[i]])
        if path not in bodies:  # the public API takes a prepared body: one preparation per mesh, as a user would
            bodies[path] = prepare_body(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PredictionWarning)
            pred = predictor.predict(bodies[path], lin_vel=v0, ang_vel=w0, orientation_xyzw=q[0],
                                     seconds=(T - 1) / rate)
        pp, pq = np.asarray(pred["com_position"]), np.asarray(pred["orientation_xyzw"])
        true_disp = p[-1] - p[0]
        slide = coulomb_slide(p[:1], q[:1], v0[None], w0[None], T - 1, store.friction[i], rate)
        rows.append({
            "mesh": Path(str(store.source[store.shape_id[i]])).stem,
            "moved_m": float(np.linalg.norm(true_disp[:2])),
            "model_m": float(np.linalg.norm((pp[-1] - pp[0]) - true_disp)),
            "slide_m": float(np.linalg.norm((slide.com_position[0, -1] - p[0]) - true_disp)),
            "stay_m": float(np.linalg.norm(true_disp)),
            "model_deg": float(rotation_angle_deg(pq[-1], q[-1])),
            "no_rotation_deg": float(rotation_angle_deg(q[0], q[-1])),
            "toppled": bool(store.toppled[i]),
            "predicted_topple": bool(pred["toppled"]),
        })
        if simulator is not None:
            inertia = store_world_inertia(store, np.array([i]), np.array([[0.0, 0.0, 0.0, 1.0]]))
            sim = simulator.trajectories(store.points[store.shape_id[i]][None], q[:1], p[:1], v0[None], w0[None],
                                         store.friction[i:i + 1], T - 1, rate, inertia)
            sp, sq = sim["com_position"][0], sim["orientation_xyzw"][0]
            rows[-1].update({"cloud_sim_m": float(np.linalg.norm((sp[-1] - sp[0]) - true_disp)),
                             "cloud_sim_deg": float(rotation_angle_deg(sq[-1], q[-1])),
                             "cloud_sim_topple": bool(topple_labels(sq)[1] >= 0)})
    seconds = time.perf_counter() - t0
    if simulator is not None:
        simulator.close()
    toppled = np.array([r["toppled"] for r in rows])
    correct = np.mean([r["toppled"] == r["predicted_topple"] for r in rows])
    nt = [r for r in rows if not r["toppled"]]
    med = lambda key, rs=nt: float(np.median([r[key] for r in rs]))  # noqa: E731
    figures = {
        "meshes": len({r["mesh"] for r in rows}), "pushes": len(rows), "non_toppling": len(nt),
        "final_position_cm": {k: 100 * med(f"{k}_m") for k in ("model", "slide", "stay")},
        "model_over_sliding": med("model_m") / med("slide_m"),
        "final_rotation_deg": {"model": med("model_deg"), "no_rotation": med("no_rotation_deg")},
        "topple_accuracy": float(correct), "majority_accuracy": float(max(toppled.mean(), 1 - toppled.mean())),
        "seconds": seconds, "checkpoint": args.checkpoint,
    }
    print(f"{figures['meshes']} external meshes, {len(rows)} pushes ({len(nt)} do not topple), predicted through "
          f"Predictor.predict in {seconds:.0f} s")
    fp = figures["final_position_cm"]
    print(f"  final position, median of non-toppling: model {fp['model']:.2f} cm, Coulomb sliding {fp['slide']:.2f} cm, "
          f"stay {fp['stay']:.2f} cm -> model / sliding {figures['model_over_sliding']:.2f}")
    fr = figures["final_rotation_deg"]
    print(f"  final rotation, median of non-toppling: model {fr['model']:.1f} deg, no rotation {fr['no_rotation']:.1f} deg")
    print(f"  topple accuracy {figures['topple_accuracy']:.3f} (majority answer {figures['majority_accuracy']:.3f})")
    if simulator is not None:
        sim_correct = np.mean([r["toppled"] == r["cloud_sim_topple"] for r in rows])
        figures["cloud_sim"] = {"final_position_cm": 100 * med("cloud_sim_m"), "final_rotation_deg": med("cloud_sim_deg"),
                                "topple_accuracy": float(sim_correct)}
        print(f"  PyBullet on the cloud's hull (cloud_sim): final position {100 * med('cloud_sim_m'):.2f} cm "
              f"({med('cloud_sim_m') / med('slide_m'):.2f} x sliding), final rotation {med('cloud_sim_deg'):.1f} deg, "
              f"topple accuracy {sim_correct:.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"figures": figures, "pushes": rows}, indent=1))


if __name__ == "__main__":
    main()
