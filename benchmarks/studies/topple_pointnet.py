"""Can a network read toppling from the step-0 cloud alone, given thousands of shapes? Toppling is the one
target that needs no precision in the physics (docs/research/friction-and-sensitivity.md:
the simulator with its friction or its push 10 % off still scores 0.97-1.00), yet classifiers of step-0
features without a simulator stay below 0.95 (the step-0 logistic regression 0.89-0.90, a small MLP on its
features 0.90-0.91). This asks impact_pointnet.py's PointNet (the cloud turned to its step-0 orientation in
the frame of the travel, the step-0 velocities and spins in that frame, I_zz / m) for the topple label of
every push, toppling or not, trained on growing sets of shapes and scored on shapes it never saw.

    python -m benchmarks.studies.topple_pointnet export data/quickstart_hull_many.zarr data/clusters_hull.zarr \\
        runs/urdf_train/urdf_160_999_hull256.zarr --external runs/external_val_100/urdf_100_159_hull256.zarr \\
        runs/external_wheel/wheel_60_hull256.zarr --out runs/impact/topple.npz
    python -m benchmarks.studies.topple_pointnet train runs/impact/topple.npz --runs 0,1,2:all --mirror --device cuda

The stores are those of impact_pointnet.py (its docstring makes them). docs/research/topple-from-cloud.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.studies.common import parse_run

from physdyn.models.topple_pointnet import (PointNetToppleClassifier, ToppleNet, TrainingSet,  # noqa: E402
                                            store_training_set, train_network)


def export(stores: list[str], externals: list[str], out: Path) -> None:
    """Every push of the stores as the package's training reads it (``store_training_set``), the external
    stores' as group 3, into one .npz."""
    from physdyn.data.store import load_store

    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("clouds", "frame", "scalars", "label", "group", "shape", "source")}
    offset = 0
    for source, (path, is_external) in enumerate([(s, False) for s in stores] + [(s, True) for s in externals]):
        data = store_training_set([load_store(path)])
        parts["clouds"].append(data.clouds)
        parts["frame"].append(data.turn.reshape(-1, 9))
        parts["scalars"].append(data.scalars)
        parts["label"].append(data.label)
        parts["group"].append(np.full(len(data.label), 3) if is_external else data.split)
        parts["shape"].append(data.shape + offset)
        parts["source"].append(np.full(len(data.label), source))
        offset += len(data.clouds)
        print(f"{path}: {len(data.label)} pushes, {data.label.mean():.3f} topple", file=sys.stderr)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, names=np.array([Path(p).stem for p in stores]),
                        external_names=np.array([Path(p).stem for p in externals]),
                        **{k: np.concatenate(v).astype(np.int64 if k in ("group", "shape", "source") else np.float32)
                           for k, v in parts.items()})
    print(f"wrote {out}", file=sys.stderr)


def train(data_path: Path, specs: list[str], steps: int, device: str, batch: int, out: Path | None, minutes: float,
          width: int = 256, seed: int = 0, mirror: bool = False, save: Path | None = None) -> None:
    """The runs ``specs`` (impact_pointnet.py's STORES:SHAPES) with the package's own training of one
    network (physdyn.models.topple_pointnet.train_network: what `physdyn fit-topple --pointnet` runs)."""
    torch.set_float32_matmul_precision("high")
    d = dict(np.load(data_path))
    group, shape, source, label = d["group"], d["shape"], d["source"], d["label"]
    names, external_names = [str(n) for n in d["names"]], [str(n) for n in d["external_names"]]
    data = TrainingSet(d["clouds"], shape, d["frame"].reshape(-1, 3, 3), d["scalars"], label, group)
    groups = {f"{g} {names[k]}": np.flatnonzero((group == gi) & (source == k))
              for k in range(len(names)) for gi, g in ((1, "val"), (2, "test"))}
    for k, name in enumerate(external_names):
        groups[f"external {name}"] = np.flatnonzero((group == 3) & (source == len(names) + k))
    print("the majority answer (never topples) per group:")
    for name, idx in groups.items():
        print(f"  {name} ({len(idx)}): {1 - label[idx].mean():.3f}")
    results = []
    for spec in specs:
        stores, n, _ = parse_run(spec)
        tr_all, in_stores = group == 0, np.isin(source, stores)
        first = np.random.default_rng(0).permutation(np.unique(shape[tr_all & (source == stores[0])]))
        keep = np.concatenate([first[:n] if n else first, np.unique(shape[tr_all & in_stores & (source != stores[0])])])
        tr, va = np.flatnonzero(tr_all & np.isin(shape, keep)), np.flatnonzero((group == 1) & in_stores)
        started = time.time()
        run = train_network(data, tr, va, steps, batch, width, seed, mirror, device, minutes)
        net = ToppleNet(width).to(device)
        net.load_state_dict(run["state_dict"])
        net.eval()
        frame, clouds = torch.tensor(data.turn, dtype=torch.float32), torch.tensor(data.clouds)
        scalars = torch.tensor((data.scalars - run["scalars_mean"]) / run["scalars_std"], dtype=torch.float32)

        def accuracy(idx: np.ndarray) -> float:
            with torch.no_grad():
                logits = torch.cat([net(torch.einsum("bij,bnj->bni", frame[part], clouds[shape[part]]).to(device),
                                        scalars[part].to(device)).cpu()
                                    for part in torch.tensor(idx).split(8192)])
            return float(np.mean((logits.numpy() > 0) == (label[idx] > 0.5)))

        row = {"run": spec, "seed": seed, "mirror": mirror, "train_shapes": int(len(keep)), "train_pushes": int(len(tr)),
               "steps": run["steps"], "capped": run["steps"] < steps, "seconds": round(time.time() - started, 1),
               "accuracy": {}}
        for name, idx in {"train": tr, **groups}.items():
            if len(idx):
                row["accuracy"][name] = {"accuracy": accuracy(idx), "majority": float(max(label[idx].mean(), 1 - label[idx].mean())),
                                         "n": int(len(idx))}
        results.append(row)
        print(json.dumps(row), flush=True)
        if save:  # the weights and what they need: the scalars' standardisation, the network's size
            save.mkdir(parents=True, exist_ok=True)
            torch.save({"state_dict": run["state_dict"], "scalars_mean": np.asarray(run["scalars_mean"], np.float64).tolist(),
                        "scalars_std": np.asarray(run["scalars_std"], np.float64).tolist(), "width": width, "run": spec, "seed": seed, "mirror": mirror,
                        "stores": [names[k] for k in stores]},
                       save / f"topple_{spec.replace(':', '_').replace(',', '')}_s{seed}{'_m' if mirror else ''}.pt")
        if out:
            out.write_text(json.dumps(results, indent=1))
    print("\n| run | mirror | training shapes (pushes) | steps | scored on | accuracy | majority |\n|---|---|---|---|---|---|---|")
    for row in results:
        for name, r in row["accuracy"].items():
            print(f"| {row['run']} | {'yes' if row['mirror'] else ''} | {row['train_shapes']} ({row['train_pushes']}) | "
                  f"{row['steps']}{' (capped)' if row['capped'] else ''} | {name} ({r['n']}) | {r['accuracy']:.3f} | {r['majority']:.3f} |")


def frontier(weights: list[Path], work: Path, sets: list[str]) -> None:
    """The saved classifiers, alone and averaged, on the frontier's own pushes (benchmarks/frontier.py's truth
    stores, every push to its own length), each mesh prepared as ``predict`` prepares it (its `hull_surface`
    256 points, its mass properties): the topple accuracy of the frontier's tables, with no simulator."""
    import warnings

    from benchmarks.frontier_sets import collect_set, requests_from_store, truth_store

    from physdyn.geometry.mass import vertical_inertia
    from physdyn.geometry.mesh_io import load_mesh
    from physdyn.geometry.rotations import quat_to_matrix
    from physdyn.predict.body import prepare_body

    classifiers = [(path.stem, saved_classifier([path])) for path in weights]
    if len(weights) > 1:
        classifiers.append((f"the {len(weights)} averaged", saved_classifier(weights)))
    for set_name in sets:
        req = requests_from_store(truth_store(collect_set(set_name, work, 60), 5))
        clouds, izz = np.zeros((len(req), 256, 3), np.float32), np.zeros(len(req))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for key, idx in req.by_mesh().items():
                body = prepare_body(load_mesh(key))
                clouds[idx] = body.points_body(256, "hull_surface")
                spec = body.spec
                izz[idx] = vertical_inertia(spec.inertia_diag, spec.principal_axes, spec.mass, req.q0[idx])
        points = np.einsum("bij,bnj->bni", quat_to_matrix(req.q0), clouds)
        for name, classifier in classifiers:
            p = classifier.probability(points, req.v0, req.w0, izz)
            print(f"{set_name}: {name}: topple accuracy {np.mean((p > 0.5) == req.toppled):.3f} ({len(req)} pushes, "
                  f"{req.toppled.sum()} topple; the majority answer {1 - req.toppled.mean():.3f})")


def saved_classifier(weights: list[Path], stores: list[str] = ()) -> PointNetToppleClassifier:
    """The package's classifier from networks saved by ``train --save`` (their first file's standardisation:
    every run on the same stores has the same), its F(t) from ``stores`` (else "by the first step")."""
    from physdyn.data.store import load_store
    from physdyn.models.topple_classifier import topple_timing

    saved = [torch.load(path, weights_only=True) for path in weights]
    loaded = [load_store(s) for s in stores]
    timing = topple_timing(loaded) if loaded else np.array([0.0, 1.0])
    rate = float(loaded[0].rate_hz) if loaded else 15.0  # the conventions' rate where no store is given
    return PointNetToppleClassifier([s["state_dict"] for s in saved], np.asarray(saved[0]["scalars_mean"]),
                                    np.asarray(saved[0]["scalars_std"]), timing, rate, int(saved[0]["width"]))


def embed(checkpoint: str, weights: list[Path], stores: list[str], out: Path) -> None:
    """``checkpoint`` with the saved networks as its topple classifier (what `physdyn fit-topple --pointnet`
    writes, from networks trained here, e.g. on a GPU), written to ``out``."""
    from physdyn.cli.fit_topple import write_with_classifier

    write_with_classifier(checkpoint, saved_classifier(weights, stores), out)
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export", help="the inputs and topple labels of every push, as one .npz")
    e.add_argument("stores", nargs="+")
    e.add_argument("--external", nargs="+", default=[], help="stores of meshes new to every model, each scored apart")
    e.add_argument("--out", type=Path, required=True)
    t = sub.add_parser("train", help="train a topple classifier per run; print the accuracies")
    t.add_argument("data", type=Path)
    t.add_argument("--runs", nargs="+", default=["0:all"], help="STORES:SHAPES as impact_pointnet.py's")
    t.add_argument("--steps", type=int, default=10000)
    t.add_argument("--batch", type=int, default=1024)
    t.add_argument("--device", default="cpu")
    t.add_argument("--out", type=Path)
    t.add_argument("--width", type=int, default=256)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--minutes", type=float, default=60.0)
    t.add_argument("--mirror", action="store_true")
    t.add_argument("--save", type=Path, help="a folder to save each run's weights into")
    f = sub.add_parser("frontier", help="saved classifiers (--save) on the frontier's pushes, alone and averaged")
    f.add_argument("weights", nargs="+", type=Path)
    f.add_argument("--work", type=Path, default=Path("runs/frontier"))
    f.add_argument("--sets", nargs="+", default=["pybullet", "wheel"])
    m = sub.add_parser("embed", help="a model checkpoint with saved networks (--save) as its topple classifier")
    m.add_argument("--checkpoint", required=True)
    m.add_argument("--weights", nargs="+", type=Path, required=True)
    m.add_argument("--stores", nargs="+", required=True, help="the stores they were trained on (for F(t))")
    m.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    if args.cmd == "embed":
        embed(args.checkpoint, args.weights, args.stores, args.out)
    elif args.cmd == "frontier":
        torch.set_num_threads(1)
        frontier(args.weights, args.work, args.sets)
    elif args.cmd == "export":
        torch.set_num_threads(1)
        export(args.stores, args.external, args.out)
    else:
        train(args.data, args.runs, args.steps, args.device, args.batch, args.out, args.minutes, args.width, args.seed,
              args.mirror, args.save)


if __name__ == "__main__":
    main()
