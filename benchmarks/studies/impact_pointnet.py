"""Does a network that reads the whole cloud learn the impact phase, given far more shapes? The map from
step-0 summaries (impact_map.py) did not fit the spin left after the impact even on its training split. This
asks the same of a PointNet that sees the cloud itself (oriented as at step 0, in the frame of the travel),
the step-0 velocities and the contact prior's own state at step K, trained on growing numbers of shapes,
and scored on shapes it never saw: the store's validation and test splits and an external set of meshes.

    # on this machine: the external set (random_urdfs 100-159), then the inputs (the prior's roll-out, CPU)
    python -c "from pathlib import Path; \
        from benchmarks.external_meshes import collect_meshes, mesh_folder_store; w = Path('runs/external_val_100'); \
        collect_meshes(w / 'meshes', 60, 100, False); mesh_folder_store(w / 'meshes', w / 'urdf_100_159_hull256.zarr', \
        10, overrides=('points_method=hull_surface', 'num_points=256'))"
    python -m benchmarks.studies.impact_pointnet export data/quickstart_hull_many.zarr data/clusters_hull.zarr \
        --external runs/external_val_100/urdf_100_159_hull256.zarr --out runs/impact/many.npz
    # anywhere (a GPU where there is one): 300, 1,000 and all training shapes of the first store, both stores,
    # and the control without the cloud; --k 0 for the state at rest
    python -m benchmarks.studies.impact_pointnet train runs/impact/many.npz --k 6 \
        --runs 0:300 0:1000 0:all 1:all 0,1:all 0,1:all:scalars --device cuda --steps 10000 --batch 1024

Real irregular meshes (random_urdfs 160-999) in training, the frontier's wheel meshes scored apart
(measured only), and half of each batch mirrored across its travel (docs/research/learned-impact.md):

    python -c "from pathlib import Path; \
        from benchmarks.external_meshes import collect_meshes, mesh_folder_store; o = ('points_method=hull_surface', 'num_points=256'); \
        collect_meshes(Path('runs/urdf_train/meshes'), 840, 160, False); \
        mesh_folder_store(Path('runs/urdf_train/meshes'), Path('runs/urdf_train/urdf_160_999_hull256.zarr'), 10, overrides=o); \
        mesh_folder_store(Path('runs/frontier/wheel/meshes_60'), Path('runs/external_wheel/wheel_60_hull256.zarr'), 10, overrides=o)"
    python -m benchmarks.studies.impact_pointnet export data/quickstart_hull_many.zarr data/clusters_hull.zarr \
        runs/urdf_train/urdf_160_999_hull256.zarr --external runs/external_val_100/urdf_100_159_hull256.zarr \
        runs/external_wheel/wheel_60_hull256.zarr --steps 0 --out runs/impact/urdf.npz
    python -m benchmarks.studies.impact_pointnet train runs/impact/urdf.npz --k 0 --runs 0,1,2:all --mirror \
        --device cuda --steps 10000 --batch 1024
    python -m benchmarks.studies.impact_pointnet mirror-check data/clusters_hull.zarr   # the prior is equivariant

Targets as impact_map's: the truth's state at step K minus the prior's, in the frame of the step-0 travel
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

from benchmarks.studies.common import parse_run

NAMES = ("v along", "v across", "w_z", "p along", "p across", "yaw")
# A push mirrored across its travel (y -> -y in the travel frame) is a push of the mirrored shape: the
# velocities (along, across, up) change sign as (+, -, +), the spins, an axial vector, as (-, +, -), the
# state (v along, v across, w_z, p along, p across, yaw) as below; the scalars are v0, w0, the prior's state
# and I_zz / m.
MIRROR_STATE = np.array([1.0, -1.0, -1.0, 1.0, -1.0, -1.0], dtype=np.float32)
MIRROR_SCALARS = np.concatenate([[1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], MIRROR_STATE, [1.0]]).astype(np.float32)


def export(stores: list[str], externals: list[str], steps: list[int], out: Path) -> None:
    from benchmarks.studies.common import in_travel_frame, travel_frame, travel_state

    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia
    from physdyn.eval.rollout import RolloutOptions, rollout
    from physdyn.geometry.rotations import quat_to_matrix
    from physdyn.predict.predictor import contact_prior_predictor

    per_k = [f"{k}_{K}" for K in steps for k in ("scalars", "diff", "true")]
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("frame", "group", "shape", "source", *per_k)}
    clouds, offset = [], 0
    for source, (path, is_external) in enumerate([(s, False) for s in stores] + [(s, True) for s in externals]):
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
                        RolloutOptions(spin_inertia=inertia))
            u = travel_frame(v0)
            across = np.stack([-u[:, 1], u[:, 0]], axis=1)

            for K in steps:  # K = 0: each push's last frame (at rest), the state the frontier scores
                k = lengths[chunk] - 1 if K == 0 else np.full(len(chunk), K)
                true = travel_state(store.linear_velocity[first + k], store.angular_velocity[first + k],
                                    store.com_position[first + k], store.orientation_xyzw[first + k], p0, q0, u)
                prior = travel_state(o.linear_velocity[rows, k], o.angular_velocity[rows, k], o.com_position[rows, k],
                                     o.orientation_xyzw[rows, k], p0, q0, u)
                diff = wrap_yaw(true - prior)
                # At K = 0 the prior's state is read at the truth's last frame, a length a deployed correction
                # would not know; the prior is at rest there in 99.9 % of pushes, so it tells nothing.
                parts[f"scalars_{K}"].append(np.concatenate([in_travel_frame(v0, u), in_travel_frame(w0, u), prior,
                                                             inertia[:, None]], axis=1))
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
                        external_names=np.array([Path(p).stem for p in externals]),
                        **{k: np.concatenate(v).astype(np.float32 if k not in ("group", "shape", "source") else np.int64)
                           for k, v in parts.items()})
    print(f"wrote {out}", file=sys.stderr)


def mirror_check(store_path: str, count: int = 200) -> None:
    """The contact prior's roll-out of mirrored pushes (shape, pose and velocities mirrored in the world,
    y -> -y) against the mirrored roll-out, in the travel frame, at step 6 and at rest: what --mirror assumes."""
    from benchmarks.studies.common import in_travel_frame, travel_frame, travel_state

    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia
    from physdyn.eval.rollout import RolloutOptions, rollout
    from physdyn.predict.predictor import contact_prior_predictor

    store = load_store(store_path)
    model = contact_prior_predictor(rate_hz=store.rate_hz).model
    sims = np.flatnonzero(store.topple_step < 0)[:count]
    first, lengths, rows = store.start[sims], store.lengths()[sims], np.arange(len(sims))
    q0, p0 = store.orientation_xyzw[first], store.com_position[first]
    v0, w0 = store.linear_velocity[first], store.angular_velocity[first]
    inertia = store_spin_inertia(store, sims, q0)
    flip = np.diag([1.0, -1.0, 1.0])
    # the mirrored body: points y -> -y, orientation flip R flip (the quaternion's x and z change sign),
    # the spin an axial vector (-flip w)
    pushes = [(store.points[store.shape_id[sims]], q0, p0, v0, w0),
              (store.points[store.shape_id[sims]] @ flip, q0 * np.array([-1.0, 1.0, -1.0, 1.0]), p0 @ flip,
               v0 @ flip, -(w0 @ flip))]
    states = []
    for points, q, p, v, w in pushes:
        o = rollout(model, points, q, p, v, w, int(lengths.max()) - 1, RolloutOptions(spin_inertia=inertia))
        u = travel_frame(v)
        states.append([travel_state(o.linear_velocity[rows, k], o.angular_velocity[rows, k], o.com_position[rows, k],
                                    o.orientation_xyzw[rows, k], p, q, u)
                       for k in (np.full(len(sims), 6), lengths - 1)]
                      + [np.concatenate([in_travel_frame(v, u), in_travel_frame(w, u)], axis=1)])
    for name, a, b, sign in zip(("state at step 6", "state at rest", "step-0 velocities and spins"), *states,
                                (MIRROR_STATE, MIRROR_STATE, MIRROR_SCALARS[:6])):
        print(f"{name}: largest |mirrored - mirror of the original| per column {np.abs(a * sign - b).max(0)}, "
              f"largest |value| {np.abs(a).max(0).round(3)} ({len(sims)} pushes)")


class ImpactNet(torch.nn.Module):
    """PointNet over the step-0 cloud in the travel frame (xyz and the height above the lowest point),
    max-pooled, joined with the push's scalars."""

    def __init__(self, n_scalars: int, width: int = 256, use_cloud: bool = True, outputs: int = 6):
        super().__init__()
        self.use_cloud = use_cloud
        self.points = torch.nn.Sequential(torch.nn.Linear(4, 64), torch.nn.ReLU(), torch.nn.Linear(64, 128),
                                          torch.nn.ReLU(), torch.nn.Linear(128, width)) if use_cloud else None
        inner = (width if use_cloud else 0) + n_scalars
        self.head = torch.nn.Sequential(torch.nn.Linear(inner, width), torch.nn.ReLU(), torch.nn.Linear(width, width),
                                        torch.nn.ReLU(), torch.nn.Linear(width, outputs))

    def forward(self, cloud: torch.Tensor | None, scalars: torch.Tensor) -> torch.Tensor:
        if not self.use_cloud:
            return self.head(scalars)
        z = cloud[..., 2:3] - cloud[..., 2:3].amin(dim=1, keepdim=True)
        # decimetres: inputs of order one for the first layer
        f = self.points(torch.cat([cloud * 10.0, z * 10.0], dim=-1)).amax(dim=1)
        return self.head(torch.cat([f, scalars], dim=-1))


def wrap_yaw(residual: np.ndarray) -> np.ndarray:
    """The yaw column (5) of (B, 6) residuals wrapped into [-pi, pi), in place; returns it."""
    residual[:, 5] = (residual[:, 5] + np.pi) % (2 * np.pi) - np.pi
    return residual


def train(data_path: Path, K: int, specs: list[str], steps: int, device: str, batch: int, out: Path | None,
          minutes: float, width: int = 256, seed: int = 0, mirror: bool = False) -> None:
    torch.set_float32_matmul_precision("high")  # TF32 on a GPU: the study's figures need no more
    d = dict(np.load(data_path))
    raw_scalars, diff = d[f"scalars_{K}"], d[f"diff_{K}"]
    # At rest (K = 0) the velocities are zero up to the stopping threshold: only position and yaw are
    # learned, chosen on and scored.
    cols = [3, 4, 5] if K == 0 else list(range(6))
    dev = torch.device(device)
    group, shape, source, names = d["group"], d["shape"], d["source"], [str(n) for n in d["names"]]
    clouds = torch.tensor(d["clouds"], device=dev)
    frame = torch.tensor(d["frame"], device=dev).view(-1, 3, 3)
    shape_t = torch.tensor(shape, device=dev)
    tr_all = group == 0

    def cloud_of(idx: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bij,bnj->bni", frame[idx], clouds[shape_t[idx]])

    # the scored groups: each store's validation and test splits (shapes never trained on), the external set
    groups = {f"{g} {names[k]}": np.flatnonzero((group == gi) & (source == k))
              for k in range(len(names)) for gi, g in ((1, "val"), (2, "test"))}
    # every store after the training stores is an external set (older exports held one, unnamed)
    external_names = [str(n) for n in d.get("external_names", ["external"])]
    for k, name in enumerate(external_names):
        label = "external" if len(external_names) == 1 and name == "external" else f"external {name}"
        groups[label] = np.flatnonzero((group == 3) & (source == len(names) + k))
    # the prior's own errors, the scale every ratio below is of
    print(f"the contact prior's own error at K = {K or 'the last frame'} (medians):")
    for name, idx in groups.items():
        if len(idx):
            y = diff[idx]
            print(f"  {name} ({len(idx)}): yaw {np.degrees(np.median(np.abs(y[:, 5]))):.1f} deg, "
                  f"position {100 * np.median(np.hypot(y[:, 3], y[:, 4])):.2f} cm"
                  + (f", spin w_z {np.median(np.abs(y[:, 2])):.3f} rad/s" if K else ""))
    results = []
    for spec in specs:
        stores, n, use_cloud = parse_run(spec)
        torch.manual_seed(seed)
        in_stores = np.isin(source, stores)
        # the first n training shapes of the first store in one fixed random order (so that the 300 of one
        # run are among the 1,000 of the next), all of the others'
        first = np.random.default_rng(0).permutation(np.unique(shape[tr_all & (source == stores[0])]))
        keep = np.concatenate([first[:n] if n else first, np.unique(shape[tr_all & in_stores & (source != stores[0])])])
        tr = np.flatnonzero(tr_all & np.isin(shape, keep))
        va = np.flatnonzero((group == 1) & in_stores)
        if not len(tr) or not len(va):
            sys.exit(f"run {spec}: {len(tr)} training and {len(va)} validation pushes; name stores that have both")
        # standardised with the run's own training pushes: nothing scored as held out shapes the inputs
        sc_mu, sc_sd = raw_scalars[tr].mean(0), raw_scalars[tr].std(0) + 1e-9
        y_mu, y_sd = diff[tr].mean(0), diff[tr].std(0) + 1e-9
        scalars = torch.tensor((raw_scalars - sc_mu) / sc_sd, device=dev)
        target = torch.tensor(((diff - y_mu) / y_sd)[:, cols], device=dev)
        # the mirrored pushes' inputs and targets, standardised as the others (training only)
        scalars_m = torch.tensor((raw_scalars * MIRROR_SCALARS - sc_mu) / sc_sd, device=dev)
        target_m = torch.tensor(((diff * MIRROR_STATE - y_mu) / y_sd)[:, cols], device=dev)
        flip_y = torch.tensor([1.0, -1.0, 1.0], device=dev)

        def predict(net, idx: np.ndarray) -> np.ndarray:
            """(len(idx), 6) corrections (zero in the columns not learned)."""
            net.eval()
            fix = np.zeros((len(idx), 6))
            with torch.no_grad():
                for start in range(0, len(idx), 8192):
                    part = torch.tensor(idx[start:start + 8192], device=dev)
                    y = net(cloud_of(part) if use_cloud else None, scalars[part]).cpu().numpy()
                    fix[start:start + len(part), cols] = y * y_sd[cols] + y_mu[cols]
            net.train()
            return fix

        net = ImpactNet(scalars.shape[1], width=width, use_cloud=use_cloud, outputs=len(cols)).to(dev)
        opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=1e-3, total_steps=steps, pct_start=max(0.05, 2.0 / steps))
        tr_t = torch.tensor(tr, device=dev)
        best, best_state, t0, done = np.inf, None, time.time(), steps
        for step in range(steps):
            idx = tr_t[torch.randint(len(tr_t), (batch,), device=dev)]
            x, y = scalars[idx], target[idx]
            cloud = cloud_of(idx) if use_cloud else None
            if mirror:  # half the batch mirrored across its travel
                m = torch.rand(batch, device=dev) < 0.5
                x, y = torch.where(m[:, None], scalars_m[idx], x), torch.where(m[:, None], target_m[idx], y)
                if cloud is not None:
                    cloud = torch.where(m[:, None, None], cloud * flip_y, cloud)
            pred = net(cloud, x)
            loss = torch.nn.functional.smooth_l1_loss(pred, y)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            if (step + 1) % max(1, steps // 20) == 0 or step + 1 == steps:
                rest = wrap_yaw(diff[va] - predict(net, va))
                v = float(np.mean(np.abs(rest[:, cols] / y_sd[cols])))
                if v < best:
                    best, best_state = v, {k: t.detach().clone() for k, t in net.state_dict().items()}
                # the time guard: the best so far is scored, and the row says the schedule was cut
                if time.time() - t0 > 60 * minutes:
                    done = step + 1
                    break
        net.load_state_dict(best_state)
        row = {"run": spec, "k": K, "seed": seed, "mirror": mirror, "train_stores": [names[k] for k in stores], "train_shapes": int(len(keep)),
               "train_pushes": int(len(tr)), "cloud": use_cloud, "width": width, "batch": batch,
               "requested_steps": steps, "steps": done, "capped": done < steps,
               "seconds": round(time.time() - t0, 1), "ratios": {}}
        for name, idx in {"train": tr, **groups}.items():
            if not len(idx):
                continue
            y = diff[idx]
            rest = wrap_yaw(y - predict(net, idx))
            row["ratios"][name] = {NAMES[j]: float(np.median(np.abs(rest[:, j])) / np.median(np.abs(y[:, j])))
                                   for j in cols}
            row["ratios"][name]["n"] = int(len(idx))
        results.append(row)
        print(json.dumps(row), flush=True)
        if out:  # after every run, so that a run cut short loses only itself
            out.write_text(json.dumps(results, indent=1))
    shown = [NAMES[j] for j in cols]
    print(f"\nK = {K or 'the last frame'}; {len(group)} pushes; the network's error as a fraction of "
          "the prior's (median |error|)")
    print("| run (stores:shapes) | training shapes (pushes) | input | steps | scored on | " + " | ".join(shown) + " |")
    print("|---|---|---|---|---|" + "---|" * len(shown))
    for row in results:
        for name, r in row["ratios"].items():
            print(f"| {row['run']} | {row['train_shapes']} ({row['train_pushes']}) | "
                  f"{'cloud + scalars' if row['cloud'] else 'scalars'} | {row['steps']}{' (capped)' if row['capped'] else ''} | "
                  f"{name} ({r['n']}) | " + " | ".join(f"{r[q]:.2f}" for q in shown) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export", help="the inputs and targets of every non-toppling push, as one .npz")
    e.add_argument("stores", nargs="+")
    e.add_argument("--external", nargs="+", default=[], help="stores of meshes new to every model, each scored apart")
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
    t.add_argument("--seed", type=int, default=0, help="the network's initialisation and batches (not the shape subsets)")
    t.add_argument("--minutes", type=float, default=60.0, help="stop a run after this long (its best so far is scored)")
    t.add_argument("--mirror", action="store_true", help="mirror half of each batch across its travel (shape and push)")
    m = sub.add_parser("mirror-check", help="the contact prior mirrored as --mirror assumes (largest differences)")
    m.add_argument("store")
    args = ap.parse_args()
    if args.cmd == "mirror-check":
        torch.set_num_threads(1)
        mirror_check(args.store)
    elif args.cmd == "export":
        torch.set_num_threads(1)
        export(args.stores, args.external, args.steps, args.out)
    else:
        train(args.data, args.k, args.runs, args.steps, args.device, args.batch, args.out, args.minutes, args.width, args.seed,
              args.mirror)


if __name__ == "__main__":
    main()
