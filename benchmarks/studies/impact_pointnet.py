"""Does a network that reads the whole cloud learn the impact phase, given far more shapes? The map from
step-0 summaries (impact_map.py) did not fit the spin left after the impact even on its training split. This
asks the same of a PointNet that sees the cloud itself (oriented as at step 0, in the frame of the travel),
the step-0 velocities and the contact prior's own state at step K, trained on growing numbers of shapes,
and scored on shapes it never saw: the store's validation and test splits and an external set of meshes.

    # on this machine: the inputs (the prior's roll-out is numpy/torch on the CPU)
    python benchmarks/studies/impact_pointnet.py export data/quickstart_hull_many.zarr \\
        --external runs/external_val/external_60x10_hull256.zarr --out runs/impact/many.npz
    # anywhere (a GPU where there is one): train on 300, 1,000 and all training shapes of the first store
    python benchmarks/studies/impact_pointnet.py train runs/impact/many.npz --runs 0:300 0:1000 0:all --device cuda

Targets as impact_map.py: the truth's state at step K minus the prior's, in the frame of the step-0 travel
(velocity along and across, spin w_z, displacement along and across, turn about the vertical); medians of
|error| after the network's correction as a fraction of the prior's. Non-toppling pushes only.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

NAMES = ("v along", "v across", "w_z", "p along", "p across", "yaw")
GROUPS = ("train", "val", "test", "external")


def export(stores: list[str], external: str | None, steps: list[int], out: Path) -> None:
    from impact_map import travel_frame, yaw_of

    from physdyn.data.store import load_store
    from physdyn.data.windows import relative_rotation, store_spin_inertia
    from physdyn.eval.rollout import rollout
    from physdyn.geometry.rotations import quat_to_matrix
    from physdyn.predict.predictor import contact_prior_predictor

    per_k = [f"{k}_{K}" for K in steps for k in ("scalars", "diff", "true")]
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("frame", "group", "shape", "source", *per_k)}
    clouds, offset = [], 0
    for source, (path, is_external) in enumerate([(s, False) for s in stores] + ([(external, True)] if external else [])):
        store = load_store(path)
        model = contact_prior_predictor(rate_hz=store.rate_hz).model
        lengths = store.lengths()
        sims = np.flatnonzero((store.topple_step < 0) & (lengths > max(*steps, 1)))
        for chunk in np.array_split(sims, max(1, len(sims) // 4096)):
            first, rows = store.start[chunk], np.arange(len(chunk))
            q0, p0 = store.orientation_xyzw[first], store.com_position[first]
            v0, w0 = store.linear_velocity[first], store.angular_velocity[first]
            inertia = store_spin_inertia(store, chunk, q0)
            o = rollout(model, store.points[store.shape_id[chunk]], q0, p0, v0, w0, int(lengths[chunk].max()) - 1,
                        spin_inertia=inertia)
            u = travel_frame(v0)
            across = np.stack([-u[:, 1], u[:, 0]], axis=1)
            tv = lambda a: np.stack([(a[:, :2] * u).sum(1), (a[:, :2] * across).sum(1), a[:, 2]], axis=1)  # noqa: E731

            def frame(v, w, p, q):
                dp = p[:, :2] - p0[:, :2]
                turn = yaw_of(relative_rotation(q0, q[:, None])[:, 0])
                return np.stack([(v[:, :2] * u).sum(1), (v[:, :2] * across).sum(1), w[:, 2],
                                 (dp * u).sum(1), (dp * across).sum(1), turn], axis=1)

            for K in steps:  # K = 0: each push's last frame (at rest), the state the frontier scores
                k = lengths[chunk] - 1 if K == 0 else np.full(len(chunk), K)
                true = frame(store.linear_velocity[first + k], store.angular_velocity[first + k],
                             store.com_position[first + k], store.orientation_xyzw[first + k])
                prior = frame(o.linear_velocity[rows, k], o.angular_velocity[rows, k], o.com_position[rows, k],
                              o.orientation_xyzw[rows, k])
                diff = true - prior
                diff[:, 5] = (diff[:, 5] + np.pi) % (2 * np.pi) - np.pi
                parts[f"scalars_{K}"].append(np.concatenate([tv(v0), tv(w0), prior, inertia[:, None]], axis=1))
                parts[f"diff_{K}"].append(diff)
                parts[f"true_{K}"].append(true)
            # body frame -> world at step 0 -> the travel frame (x along the travel): the network sees the
            # cloud as the ground does, with no heading to learn
            turn = np.zeros((len(chunk), 3, 3))
            turn[:, 0, :2], turn[:, 1, :2], turn[:, 2, 2] = u, across, 1.0
            parts["frame"].append((turn @ quat_to_matrix(q0)).reshape(-1, 9))
            parts["group"].append(np.full(len(chunk), 3) if is_external else store.split[chunk].astype(np.int64))
            parts["shape"].append(store.shape_id[chunk] + offset)
            parts["source"].append(np.full(len(chunk), source))
        clouds.append(np.asarray(store.points, dtype=np.float32))
        offset += store.num_shapes
        print(f"{path}: {len(sims)} non-toppling pushes", file=sys.stderr)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, clouds=np.concatenate(clouds), names=np.array([Path(p).stem for p in stores]),
                        **{k: np.concatenate(v).astype(np.float32 if k not in ("group", "shape", "source") else np.int64)
                           for k, v in parts.items()})
    print(f"wrote {out}", file=sys.stderr)


class ImpactNet(torch.nn.Module):
    """PointNet over the step-0 cloud in the travel frame (xyz and the height above the lowest point),
    max-pooled, joined with the push's scalars."""

    def __init__(self, n_scalars: int, width: int = 256, use_cloud: bool = True):
        super().__init__()
        self.use_cloud = use_cloud
        self.points = torch.nn.Sequential(torch.nn.Linear(4, 64), torch.nn.ReLU(), torch.nn.Linear(64, 128),
                                          torch.nn.ReLU(), torch.nn.Linear(128, width)) if use_cloud else None
        inner = (width if use_cloud else 0) + n_scalars
        self.head = torch.nn.Sequential(torch.nn.Linear(inner, width), torch.nn.ReLU(), torch.nn.Linear(width, width),
                                        torch.nn.ReLU(), torch.nn.Linear(width, 6))

    def forward(self, cloud: torch.Tensor, scalars: torch.Tensor) -> torch.Tensor:
        if not self.use_cloud:
            return self.head(scalars)
        z = cloud[..., 2:3] - cloud[..., 2:3].amin(dim=1, keepdim=True)
        f = self.points(torch.cat([cloud * 10.0, z * 10.0], dim=-1)).amax(dim=1)  # metres -> decimetres
        return self.head(torch.cat([f, scalars], dim=-1))


def parse_run(spec: str) -> tuple[list[int], int, bool]:
    """"STORES:SHAPES[:scalars]", e.g. "0:300" (300 training shapes of the first store), "0,1:all",
    "0,1:all:scalars" (no cloud: the control) -> (stores, shapes (0: all), use_cloud)."""
    parts = spec.split(":")
    stores = [int(x) for x in parts[0].split(",")]
    n = 0 if parts[1] == "all" else int(parts[1])
    return stores, n, not (len(parts) > 2 and parts[2] == "scalars")


def train(data_path: Path, K: int, specs: list[str], steps: int, device: str, batch: int, out: Path | None,
          minutes: float, width: int = 256) -> None:
    torch.set_float32_matmul_precision("high")  # TF32 on a GPU: the study's figures need no more
    d = dict(np.load(data_path))
    d.update(scalars=d[f"scalars_{K}"], diff=d[f"diff_{K}"])
    dev = torch.device(device)
    rng = np.random.default_rng(0)
    group, shape, source, names = d["group"], d["shape"], d["source"], [str(n) for n in d["names"]]
    clouds = torch.tensor(d["clouds"], device=dev)
    frame = torch.tensor(d["frame"], device=dev).view(-1, 3, 3)
    tr_all = group == 0
    sc_mu, sc_sd = d["scalars"][tr_all].mean(0), d["scalars"][tr_all].std(0) + 1e-9
    y_mu, y_sd = d["diff"][tr_all].mean(0), d["diff"][tr_all].std(0) + 1e-9
    scalars = torch.tensor((d["scalars"] - sc_mu) / sc_sd, device=dev)
    target = torch.tensor((d["diff"] - y_mu) / y_sd, device=dev)
    shape_t = torch.tensor(shape, device=dev)

    def cloud_of(idx: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bij,bnj->bni", frame[idx], clouds[shape_t[idx]])

    def predict(net, idx: np.ndarray) -> np.ndarray:
        net.eval()
        outs = []
        with torch.no_grad():
            for part in torch.tensor(idx, device=dev).split(8192):
                outs.append(net(cloud_of(part), scalars[part]).cpu().numpy())
        net.train()
        return np.concatenate(outs) * y_sd + y_mu if outs else np.zeros((0, 6))

    # the scored groups: each store's validation and test splits (shapes never trained on), the external set
    groups = {f"{g} {names[k]}": np.flatnonzero((group == gi) & (source == k))
              for k in range(len(names)) for gi, g in ((1, "val"), (2, "test"))}
    groups["external"] = np.flatnonzero(group == 3)
    results = []
    for spec in specs:
        stores, n, use_cloud = parse_run(spec)
        torch.manual_seed(0)
        in_stores = np.isin(source, stores)
        # the first n training shapes of the first store (a fixed random order), all of the others'
        first = rng.permutation(np.unique(shape[tr_all & (source == stores[0])]))
        keep = np.concatenate([first[:n] if n else first, np.unique(shape[tr_all & in_stores & (source != stores[0])])])
        tr = np.flatnonzero(tr_all & np.isin(shape, keep))
        va = np.flatnonzero((group == 1) & in_stores)
        net = ImpactNet(scalars.shape[1], width=width, use_cloud=use_cloud).to(dev)
        opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=1e-3, total_steps=steps, pct_start=0.05)
        tr_t = torch.tensor(tr, device=dev)
        best, best_state, t0, done = np.inf, None, time.time(), steps
        for step in range(steps):
            idx = tr_t[torch.randint(len(tr_t), (batch,), device=dev)]
            loss = torch.nn.functional.smooth_l1_loss(net(cloud_of(idx), scalars[idx]), target[idx])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            if (step + 1) % max(1, steps // 20) == 0 or step + 1 == steps:
                v = float(np.mean(np.abs((d["diff"][va] - predict(net, va)) / y_sd)))
                if v < best:
                    best, best_state = v, {k: t.detach().clone() for k, t in net.state_dict().items()}
                if time.time() - t0 > 60 * minutes:  # the time guard: score the best so far, say where it stopped
                    done = step + 1
                    break
        net.load_state_dict(best_state)
        row = {"run": spec, "train_stores": [names[k] for k in stores], "train_shapes": int(len(keep)),
               "train_pushes": int(len(tr)), "cloud": use_cloud, "seconds": round(time.time() - t0, 1),
               "steps": done, "width": width, "ratios": {}}
        for name, idx in {"train": tr, **groups}.items():
            if not len(idx):
                continue
            y = d["diff"][idx]
            rest = y - predict(net, idx)
            rest[:, 5] = (rest[:, 5] + np.pi) % (2 * np.pi) - np.pi
            row["ratios"][name] = {q: float(np.median(np.abs(rest[:, j])) / np.median(np.abs(y[:, j])))
                                   for j, q in enumerate(NAMES)}
            row["ratios"][name]["n"] = int(len(idx))
        results.append(row)
        print(json.dumps(row), flush=True)
        if out:  # after every run, so that a run cut short loses only itself
            out.write_text(json.dumps(results, indent=1))
    print(f"\nK = {K or 'the last frame'}; {len(group)} pushes; the network's error as a fraction of "
          "the prior's (median |error|)")
    print("| run (stores:shapes) | training shapes (pushes) | input | scored on | " + " | ".join(NAMES) + " |")
    print("|---|---|---|---|" + "---|" * len(NAMES))
    for row in results:
        for name, r in row["ratios"].items():
            print(f"| {row['run']} | {row['train_shapes']} ({row['train_pushes']}) | "
                  f"{'cloud + scalars' if row['cloud'] else 'scalars'} | {name} ({r['n']}) | "
                  + " | ".join(f"{r[q]:.2f}" for q in NAMES) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export", help="the inputs and targets of every non-toppling push, as one .npz")
    e.add_argument("stores", nargs="+")
    e.add_argument("--external", help="a store of meshes new to every model, scored apart")
    e.add_argument("--steps", type=int, nargs="+", default=[6, 0], help="K (0: each push's last frame, at rest)")
    e.add_argument("--out", type=Path, required=True)
    t = sub.add_parser("train", help="train on growing numbers of training shapes; print the ratios")
    t.add_argument("data", type=Path)
    t.add_argument("--k", type=int, default=6, help="which of the exported K to train on (0: the last frame)")
    t.add_argument("--runs", nargs="+", default=["0:300", "0:all"],
                   help="STORES:SHAPES[:scalars] per run: the stores trained on (their training splits; the first "
                        "cut to SHAPES shapes, 'all' for all), ':scalars' for the control without the cloud")
    t.add_argument("--steps", type=int, default=20000)
    t.add_argument("--batch", type=int, default=512)
    t.add_argument("--device", default="cpu")
    t.add_argument("--out", type=Path, help="the results as JSON")
    t.add_argument("--width", type=int, default=256, help="the PointNet's feature size and the head's width")
    t.add_argument("--minutes", type=float, default=60.0, help="stop a run after this long (its best so far is scored)")
    args = ap.parse_args()
    if args.cmd == "export":
        torch.set_num_threads(1)
        export(args.stores, args.external, args.steps, args.out)
    else:
        train(args.data, args.k, args.runs, args.steps, args.device, args.batch, args.out, args.minutes, args.width)


if __name__ == "__main__":
    main()
