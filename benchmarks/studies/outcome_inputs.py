"""What should the outcome correction (``physdyn fit-outcome``) read? Where the contact prior's final position
goes wrong, and the correction's inputs compared: the 13 it ships with (the push and the roll-out's resting
state) against those plus the roll-out's state at 2/15 s and 0.4 s, how long and how far it moved and the
centre of mass's height. Three seeds of each, trained as ``fit-outcome`` trains (``train_outcome_network``)
on the same three stores; scored on their validation and test splits, random_urdfs 100-159 and a third set
of new meshes, robosuite 1.5.2's robot links, gripper parts, bases and objects
(docs/research/outcome-correction.md).

    python benchmarks/studies/outcome_inputs.py decompose             # the prior's error on the pybullet frontier set
    python benchmarks/studies/outcome_inputs.py robosuite             # the third set (downloads the wheel, ~1 min)
    python benchmarks/studies/outcome_inputs.py compare               # both inputs (about 10 min on the CPU)

``decompose`` needs the frontier's truth store (``python benchmarks/frontier.py --work runs/frontier`` makes
it); ``compare`` the three stores ``physdyn fit-outcome`` trains on (``impact_pointnet.py``'s docstring
makes them) and ``robosuite``'s.
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
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))

from physdyn.geometry.rotations import wrap_angle  # noqa: E402
from physdyn.models import outcome_correction as oc  # noqa: E402

STORES = ["data/quickstart_hull_many.zarr", "data/clusters_hull.zarr", "runs/urdf_train/urdf_160_999_hull256.zarr"]
EXTERNAL = {"random_urdfs 100-159": "runs/external_val_100/urdf_100_159_hull256.zarr",
            "robosuite": "runs/robosuite/robosuite_60_hull256.zarr"}
ROBOSUITE = "robosuite==1.5.2"
EARLY_STEPS = (2, 6)  # 2/15 s and 0.4 s at 15 Hz


def decompose(work: Path) -> None:
    """The contact prior's final position error on the frontier's pybullet set, along and across the travel."""
    import trimesh
    from frontier_sets import requests_from_store

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
    from external_meshes import mesh_folder_store
    from frontier_sets import spread_order, usable_mesh

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


def features(paths: list[str]) -> dict[str, np.ndarray]:
    """Every non-toppling push's inputs (the shipped 13, then the 15 more), targets and group (0-2 the
    stores' splits, 3+ the external sets in order)."""
    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia, world_oriented_points
    from physdyn.eval.rollout import rollout
    from physdyn.predict.predictor import contact_prior_predictor

    model = contact_prior_predictor().model
    parts: dict[str, list[np.ndarray]] = {"inputs": [], "extra": [], "targets": [], "group": []}
    for source, path in enumerate(paths):
        store = load_store(path)
        sims, lengths = np.flatnonzero(store.topple_step < 0), store.lengths()
        for part in np.array_split(sims, max(1, len(sims) // 2048)):
            first, last = store.start[part], store.start[part] + lengths[part] - 1
            q0, p0 = store.orientation_xyzw[first], store.com_position[first]
            v0, w0 = store.linear_velocity[first], store.angular_velocity[first]
            spin = store_spin_inertia(store, part, q0)
            out = rollout(model, store.points[store.shape_id[part]], q0, p0, v0, w0,
                          int(lengths[part].max()) - 1 + oc.EXTRA_STEPS, spin_inertia=spin)
            P, Q, V, W = out.com_position, out.orientation_xyzw, out.linear_velocity, out.angular_velocity
            inputs, turn = oc.outcome_inputs(v0, w0, spin, p0, q0, P[:, -1], Q[:, -1], V[:, -1], W[:, -1])
            truth = oc.resting_state(turn, p0, q0, store.com_position[last], store.orientation_xyzw[last],
                                     store.linear_velocity[last], store.angular_velocity[last])
            target = truth[:, 3:] - inputs[:, 9:12]
            target[:, 2] = wrap_angle(target[:, 2])
            early = [oc.resting_state(turn, p0, q0, P[:, k], Q[:, k], V[:, k], W[:, k]) for k in EARLY_STEPS]
            moving = (np.linalg.norm(V[:, 1:, :2], axis=-1) > 1e-3).sum(axis=1) / 15.0
            path_length = np.linalg.norm(np.diff(P[..., :2], axis=1), axis=-1).sum(axis=1)
            height = -world_oriented_points(store.points[store.shape_id[part]], q0)[..., 2].min(axis=1)
            parts["inputs"].append(inputs)
            parts["extra"].append(np.concatenate([*early, np.stack([moving, path_length, height], 1)], axis=1))
            parts["targets"].append(target)
            parts["group"].append(np.asarray(store.split[part]) if source < len(STORES) else np.full(len(part), source))
        print(f"  {path}: {len(sims)} non-toppling pushes", flush=True)
    return {k: np.concatenate(v) for k, v in parts.items()}


def compare(cache: Path) -> None:
    if not cache.is_file():
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache, **features(STORES + list(EXTERNAL.values())))
    d = np.load(cache)
    torch.set_num_threads(1)
    state = [1, -1, -1, 1, -1, -1]
    variants = {"shipped (13 inputs)": (d["inputs"], oc.MIRROR_INPUTS),
                "richer (28 inputs)": (np.concatenate([d["inputs"], d["extra"]], axis=1),
                                       np.concatenate([oc.MIRROR_INPUTS, state * len(EARLY_STEPS) + [1, 1, 1]]))}
    groups = {"validation": 1, "test": 2, **{name: len(STORES) + i for i, name in enumerate(EXTERNAL)}}
    y, group = d["targets"], d["group"]
    train, val = np.flatnonzero(group == 0), np.flatnonzero(group == 1)
    print("\nthe correction's median error as a fraction of the prior's: position (distance), turn")
    for name, (x, mirror) in variants.items():
        saved, oc.MIRROR_INPUTS = oc.MIRROR_INPUTS, mirror  # what train_outcome_network mirrors with
        try:
            runs = [oc.train_outcome_network(x, y, train, val, seed=seed) for seed in (0, 1, 2)]
        finally:
            oc.MIRROR_INPUTS = saved
        fixes = []
        for run in runs:
            net = oc.OutcomeNet(256, x.shape[1])
            net.load_state_dict(run["state_dict"])
            net.eval()
            with torch.no_grad():
                fixes.append(net(torch.tensor((x - run["inputs_mean"]) / run["inputs_std"], dtype=torch.float32)).numpy())
        fix = np.mean(fixes, axis=0) * runs[0]["targets_std"] + runs[0]["targets_mean"]
        for label, g in groups.items():
            idx = np.flatnonzero(group == g)
            rest = y[idx] - fix[idx]
            position = np.median(np.hypot(rest[:, 0], rest[:, 1])) / np.median(np.hypot(y[idx, 0], y[idx, 1]))
            turn = np.median(np.abs(wrap_angle(rest[:, 2]))) / np.median(np.abs(y[idx, 2]))
            print(f"| {name} | {label} ({len(idx)}) | {position:.3f} | {turn:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("step", choices=["decompose", "robosuite", "compare"])
    ap.add_argument("--work", type=Path, default=Path("runs/frontier"), help="decompose: the frontier's --work")
    args = ap.parse_args()
    if args.step == "decompose":
        decompose(args.work)
    elif args.step == "robosuite":
        robosuite(Path("runs/robosuite"))
    else:
        compare(Path("runs/outcome/inputs.npz"))


if __name__ == "__main__":
    main()
