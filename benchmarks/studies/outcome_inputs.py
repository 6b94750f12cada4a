"""What should the outcome correction (``physdyn fit-outcome``) read? Where the contact prior's final position
goes wrong, and a third set of new meshes to score it on, robosuite 1.5.2's robot links, gripper parts, bases
and objects (docs/research/outcome-correction.md).

    python -m benchmarks.studies.outcome_inputs decompose             # the prior's error on the pybullet frontier set
    python -m benchmarks.studies.outcome_inputs robosuite             # the third set (downloads the wheel, ~1 min)

``decompose`` needs the frontier's truth store (``python benchmarks/frontier.py --work runs/frontier`` makes
it).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path

for _threads in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_threads] = "1"

import numpy as np  # noqa: E402

from physdyn.models import outcome_correction as oc  # noqa: E402

ROBOSUITE = "robosuite==1.5.2"


def decompose(work: Path) -> None:
    """The contact prior's final position error on the frontier's pybullet set, along and across the travel."""
    import trimesh
    from benchmarks.frontier_sets import requests_from_store

    from physdyn.data.store import load_store
    from physdyn.predict.predictor import contact_prior_predictor

    store = load_store(str(work / "pybullet" / "meshes_60_truth_x5.zarr"))
    req = requests_from_store(store)
    meshes = {k: trimesh.load(k, force="mesh", process=False) for k in dict.fromkeys(req.mesh)}
    prior = contact_prior_predictor()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = prior.predict_many([meshes[k] for k in req.mesh], req.v0, req.w0, seconds=list(req.steps / prior.rate_hz),
                                 orientation_xyzw=req.q0)
    disp = np.array([r["com_position"][-1] - r["com_position"][0] for r in res])
    keep = ~req.toppled
    u = oc.travel_turn(req.v0)[:, 0, :2]
    n = np.stack([-u[:, 1], u[:, 0]], 1)
    ta, tc = (req.true_disp[:, :2] * u).sum(1), (req.true_disp[:, :2] * n).sum(1)
    pa, pc = (disp[:, :2] * u).sum(1), (disp[:, :2] * n).sum(1)
    slide = np.median(np.linalg.norm((req.slide_disp - req.true_disp)[:, :2], axis=1)[keep])

    def ratio(error: np.ndarray) -> float:
        return float(np.median(error[keep]) / slide)

    print(f"pybullet set, {keep.sum()} non-toppling pushes: prior {ratio(np.hypot(pa - ta, pc - tc)):.3f} x sliding")
    print(f"  median |error| along the travel {1000 * np.median(np.abs(pa - ta)[keep]):.1f} mm, "
          f"across {1000 * np.median(np.abs(pc - tc)[keep]):.1f} mm")
    print(f"  along right (across as is): {ratio(np.abs(pc - tc)):.3f}; across right: {ratio(np.abs(pa - ta)):.3f}")
    q = np.percentile((pa / ta)[keep], [25, 50, 75])
    print(f"  the prior's distance along / the truth's: median {q[1]:.3f} (quartiles {q[0]:.3f}-{q[2]:.3f})")
    for s in (0.95, 1.05):
        print(f"  its distance along scaled by {s}: {ratio(np.hypot(s * pa - ta, pc - tc)):.3f}")


def robosuite(work: Path) -> None:
    """60 meshes of robosuite's wheel spread over its sorted list, scaled as the frontier's sets, simulated."""
    from benchmarks.external_meshes import mesh_folder_store
    from benchmarks.frontier_sets import spread_order, usable_mesh

    from physdyn.errors import PhysdynError

    download, folder = work / "download", work / "meshes"
    if not folder.is_dir():
        wheels = sorted(download.glob("robosuite-*.whl"))
        if not wheels:
            subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "-d", str(download), ROBOSUITE], check=True)
            wheels = sorted(download.glob("robosuite-*.whl"))
        z = zipfile.ZipFile(wheels[0])
        names = sorted(n for n in z.namelist() if n.lower().endswith((".stl", ".obj"))
                       and n.split("/")[3] in ("robots", "grippers", "objects", "bases"))
        raw = work / "raw"
        raw.mkdir(parents=True, exist_ok=True)
        folder.mkdir(parents=True)
        seen, kept, skipped = set(), {}, []
        for i in spread_order(60, len(names)):
            if len(kept) == 60:
                break
            path = raw / names[i].replace("/", "__")
            path.write_bytes(z.read(names[i]))
            try:
                mesh = usable_mesh(path, 1.0)
            except (PhysdynError, ValueError) as exc:
                skipped.append([names[i], str(exc).splitlines()[0][:100]])
                continue
            digest = hashlib.sha256(np.round(mesh.vertices, 6).tobytes() + mesh.faces.tobytes()).hexdigest()
            if digest in seen:
                skipped.append([names[i], "a copy of a mesh already in the set"])
                continue
            seen.add(digest)
            name = f"{len(kept):03d}_" + "_".join(names[i].split("/")[3:]).rsplit(".", 1)[0] + ".obj"
            mesh.export(folder / name)
            kept[name] = names[i]
        (work / "manifest.json").write_text(json.dumps({"kept": kept, "skipped": skipped}, indent=1))
    store = mesh_folder_store(folder, work / "robosuite_60_hull256.zarr", 10,
                              overrides=("points_method=hull_surface", "num_points=256"))
    print(f"{store.num_sims} pushes of {store.num_shapes} meshes; {int((store.topple_step < 0).sum())} do not topple")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("step", choices=["decompose", "robosuite"])
    ap.add_argument("--work", type=Path, default=Path("runs/frontier"), help="decompose: the frontier's --work")
    args = ap.parse_args()
    if args.step == "decompose":
        decompose(args.work)
    else:
        robosuite(Path("runs/robosuite"))


if __name__ == "__main__":
    main()
