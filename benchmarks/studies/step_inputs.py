"""Is the learned step's error floor its inputs? (docs/research/learned-step.md.)

spin_step.py's learned step fits the simulator's one-step change of spin to 0.19 of the truth's change on
random_urdfs, the same on shapes it trained on and on new ones, and neither width nor length moves it: a
floor that more of the same data or a bigger network does not lower. What the step never read:
- the ground: its cloud is centred on the centre of mass, so it cannot tell a body resting on its points
  from one a millimetre above the plane (``--inputs gap``);
- the contact geometry's detail: the cloud is thinned to 64 points, and contact depends on the hull's
  corners (``--points 256``, the model's `hull_surface` cloud);
- the past: PyBullet keeps a body's contact points from step to step, so its next step can depend on more
  than the current state (``--inputs prev1 prev2 time push``: the last one or two steps' changes, the time
  since the push, the push's velocities; ``--history-noise``: trained also on copies with that history
  blurred, as a roll-out's own would be).

It reads spin_step.py's samples (runs/turn/step.npz: the same pushes and steps) and adds those inputs, lined
up sample by sample; it trains the same PointNet with them; it rolls pushes out with it (several networks
averaged where several are given), from the push or from the truth's state some steps in.

    # here (alignment with step.npz checked: each sample's travel frame recomputed); then a copy small
    # enough to carry to a device machine beside step.npz (no 256-point clouds)
    python benchmarks/studies/step_inputs.py export --train data/clusters_hull.zarr \\
        runs/urdf_train/urdf_160_999_x40_hull256.zarr --external runs/external_val_100/urdf_100_159_hull256.zarr \\
        runs/frontier/pybullet/meshes_60_truth_x5.zarr runs/external/external_30x10.zarr
    python benchmarks/studies/step_inputs.py slim --out runs/turn/step_slim.npz
    # on a GPU machine, runs/turn/step.npz and runs/turn/step_slim.npz carried
    PYTHONPATH=. python3 benchmarks/studies/step_inputs.py train --extra runs/turn/step_slim.npz --device cuda \\
        --inputs prev1 prev2 [--history-noise 0.3] --seed 0 --save OUT.pt
    # here: closed loop, the prior alone against the learned step(s) in the same loop; --from-step K starts
    # from the truth's state K steps after the push (an oracle of the impact phase)
    python benchmarks/studies/step_inputs.py closed --save A.pt [B.pt ...] --external ... [--from-step K] [--perturb S]
    # the roll-outs' speed and spin K steps after the push, against the truth's
    python benchmarks/studies/step_inputs.py state-at --from-step K --save A.pt --external ...
    # teacher forced, by the time since the push
    python benchmarks/studies/step_inputs.py by-time --save A.pt [B.pt ...]
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from spin_step import MIRROR_INPUTS, MIRROR_TARGETS, chosen_steps, print_scores  # noqa: E402
from unwrapped_turn import load_parts  # noqa: E402

from physdyn.geometry.rotations import quat_to_matrix  # noqa: E402
from physdyn.models import outcome_correction as oc  # noqa: E402
from physdyn.models.topple_pointnet import ToppleNet, travel_turn  # noqa: E402

EXTRA = "runs/turn/step_extra.npz"


def ground_gap(clouds, q, p):
    """The height of the lowest of each body's points above the plane (m): negative where it presses in."""
    rz = quat_to_matrix(q)[:, 2, :]
    return p[:, 2] + np.einsum("bj,bnj->bn", rz, clouds).min(axis=1)


def extra(path, per_push):
    from physdyn.data.store import load_store

    store = load_store(path)
    sims, f = chosen_steps(store, per_push)
    q, p, v = store.orientation_xyzw[f], store.com_position[f], store.linear_velocity[f]
    points = np.asarray(store.points)
    gap = ground_gap(points[store.shape_id[sims]], q, p)
    turn = travel_turn(v)
    frame = turn @ quat_to_matrix(q)
    k = f - store.start[sims]
    hist = history(turn, store.linear_velocity, store.angular_velocity, f, k, store.start[sims])
    print(f"{path}: {len(sims)} samples, gap median {1000 * np.median(gap):.2f} mm, "
          f"quartiles {1000 * np.percentile(gap, 25):.2f} to {1000 * np.percentile(gap, 75):.2f}", flush=True)
    return {"gap": gap.astype(np.float32), "frame": frame.astype(np.float32), "clouds256": points.astype(np.float32),
            "hist": hist.astype(np.float32)}


def history(turn, lin, ang, f, k, first, stride=1):
    """What a roll-out knows of its past at step ``f`` (``k`` steps after the push at ``first``), in the travel
    frame ``turn``: the last two steps' changes of velocity and spin (zero, flagged, before the push), the time
    since the push (s) and the push's own velocities. ``lin``, ``ang``: rows of velocities, a step ``stride``
    rows after the one before. Columns as GROUPS."""
    rot = lambda x: np.einsum("bij,bj->bi", turn, x)  # noqa: E731
    cols = []
    for back in (1, 2):
        has = k >= back
        a, b = np.where(has, f - (back - 1) * stride, f), np.where(has, f - back * stride, f)
        cols += [rot(lin[a] - lin[b]), rot(ang[a] - ang[b]), has[:, None].astype(np.float64)]
    cols += [(k / 15.0)[:, None], rot(lin[first]), rot(ang[first])]
    return np.concatenate(cols, axis=1)


# column groups of ``history`` and of the ground gap, with their mirror signs (across the travel: y, and the
# spins about x and z, change sign)
DV_DW = [1, -1, 1, -1, 1, -1]
GROUPS = {"gap": (None, [1]), "prev1": (slice(0, 7), DV_DW + [1]), "prev2": (slice(7, 14), DV_DW + [1]),
          "time": (slice(14, 15), [1]), "push": (slice(15, 21), DV_DW)}


def inputs_of(d, groups):
    cols = [d["inputs"]]
    for g in groups:
        cols.append(d["gap"][:, None] if g == "gap" else d["hist"][:, GROUPS[g][0]])
    return np.concatenate(cols, axis=1)


def load(path, extra_path):
    tr, ex, names = load_parts(path)
    z = np.load(extra_path)
    for prefix, d in [("train_", tr)] + [(f"ext{i}_", e) for i, e in enumerate(ex)]:
        # a slim copy (``slim``: no 256-point clouds, no frames to check) fits a device machine's carry
        for k in ("gap", "clouds256", "hist"):
            if prefix + k in z.files:
                d[k] = z[prefix + k]
        err = np.abs(z[prefix + "frame"] - d["frame"]).max() if prefix + "frame" in z.files else 0.0
        if err > 1e-4:
            raise SystemExit(f"{prefix}: the extra samples do not line up with {path} (frames differ by {err})")
    return tr, ex, names


def configure(groups):
    oc.MIRROR_INPUTS = np.concatenate([MIRROR_INPUTS] + [np.array(GROUPS[g][1], dtype=np.float64) for g in groups])
    oc.INPUTS = len(oc.MIRROR_INPUTS)
    oc.TARGETS, oc.MIRROR_TARGETS = ("dv_x", "dv_y", "dv_z", "dw_x", "dw_y", "dw_z"), MIRROR_TARGETS


def train(a):
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
    tr, ex, names = load(a.out, a.extra)
    configure(a.inputs)
    cl = "clouds256" if a.points == 256 else "clouds"
    split = (np.flatnonzero(tr["split"] == s) for s in (0, 1, 2))
    tr_idx, val, test = split
    inputs, targets, shape, frame = inputs_of(tr, a.inputs).astype(np.float64), tr["targets"].astype(np.float64), tr["shape"], tr["frame"]
    if a.history_noise:
        # the training pushes again with their history columns blurred: in a roll-out the history is the roll-out's
        # own, wrong by about a fifth of each change, and a network that trusts it exactly compounds that
        rng = np.random.default_rng(a.seed)
        cols = np.flatnonzero(np.concatenate([np.full(13, False)] + [
            np.array([g in ("prev1", "prev2") and c < 6 for c in range(len(GROUPS[g][1]))]) for g in a.inputs]))
        noisy = inputs[tr_idx].copy()
        noisy[:, cols] += a.history_noise * inputs[tr_idx][:, cols].std(0) * rng.standard_normal((len(tr_idx), len(cols)))
        extra_rows = len(inputs) + np.arange(len(tr_idx))
        inputs, targets = np.concatenate([inputs, noisy]), np.concatenate([targets, targets[tr_idx]])
        shape, frame = np.concatenate([shape, shape[tr_idx]]), np.concatenate([frame, frame[tr_idx]])
        tr_idx = np.concatenate([tr_idx, extra_rows])
    t0 = time.time()
    run = oc.train_outcome_network(inputs, targets, tr_idx, val,
                                   a.steps, 1024, 256, a.seed, clouds=tr[cl], shape=shape, frame=frame,
                                   device=a.device, point_widths=tuple(a.widths), minutes=a.minutes)
    print(f"trained inputs={'+'.join(a.inputs) or 'base'} points={a.points} seed={a.seed} history_noise={a.history_noise}: validation {run['val_error']:.3f}, "
          f"{time.time() - t0:.0f} s, {run['steps']} steps", flush=True)
    run["state_dict"] = {k: v.cpu() for k, v in run["state_dict"].items()}
    if a.save:
        torch.save({"run": run, "widths": a.widths, "inputs": a.inputs, "points": a.points,
                    "history_noise": a.history_noise}, a.save)
    net = ToppleNet(256, oc.INPUTS, tuple(a.widths), outputs=6)
    net.load_state_dict(run["state_dict"])
    net.eval()
    print_scores(net, run, [("test split", tr, test)] + [(n, e, np.arange(len(e["split"]))) for n, e in zip(names, ex)],
                 lambda d: inputs_of(d, a.inputs), cl, chunk=4096)


def by_time(a):
    """Teacher forced, as ``train`` scores it, but by the time since the push: where is the step's error?"""
    tr, ex, names = load(a.out, a.extra)
    sets = [("test split", tr, np.flatnonzero(tr["split"] == 2))] + [(n, e, np.arange(len(e["split"]))) for n, e in zip(names, ex)]
    bins = ((0.0, 0.01), (0.05, 0.15), (0.15, 0.35), (0.35, 0.75), (0.75, np.inf))
    for path in a.save:
        (net, run, groups, n), = load_networks([path])
        print(f"{path} (inputs: {'+'.join(groups) or 'base'}); change of w_z, spinning steps: median |error| / median |truth's change|, "
              "prior -> network, by seconds since the push", flush=True)
        for name, d, idx in sets:
            x = torch.tensor((inputs_of(d, groups)[idx] - run["inputs_mean"]) / run["inputs_std"], dtype=torch.float32)
            cl = torch.tensor(np.einsum("bij,bnj->bni", d["frame"][idx], d["clouds" if n == 64 else "clouds256"][d["shape"][idx]]),
                              dtype=torch.float32)
            with torch.no_grad():
                h = torch.cat([net(cl[i:i + 4096], x[i:i + 4096]) for i in range(0, len(x), 4096)]).numpy()
            fix = h * run["targets_std"] + run["targets_mean"]
            t, spin = d["hist"][idx, 14], np.abs(d["inputs"][idx, 5]) > 2.0
            line = f"  {name[-40:]:40s}"
            for lo, hi in bins:
                sel = spin & (t >= lo) & (t < hi)
                truth = np.median(np.abs(d["truth"][idx][sel, 5]))
                line += (f" | {lo:g}-{hi:g} s ({sel.sum()}): {np.median(np.abs(d['targets'][idx][sel, 5])) / truth:.2f}"
                         f" -> {np.median(np.abs(d['targets'][idx][sel, 5] - fix[sel, 5])) / truth:.2f}")
            print(line, flush=True)


def load_networks(paths):
    nets = []
    for path in paths:
        saved = torch.load(path, weights_only=False)
        groups = list(saved.get("inputs", ["gap"] if saved.get("gap") else []))
        points = int(saved.get("points", 64))
        configure(groups)
        net = ToppleNet(256, oc.INPUTS, tuple(saved["widths"]), outputs=6)
        net.load_state_dict(saved["run"]["state_dict"])
        net.eval()
        nets.append((net, saved["run"], groups, points))
    return nets


def learned_rollout(model, store, sims, clouds, steps, nets=(), chunk=4096, start=0, perturb=0.0, state=None):
    """spin_step.learned_rollout with several networks (their changes averaged), each reading its own cloud
    size and extra inputs (the ground gap, the roll-out's own history) if it was trained so. ``clouds``:
    {points: (S, N, 3)}. ``start``: begin from the truth's state that many steps after the push (an oracle
    of the steps before), the history's changes too; ``perturb``: that state's speed and spin each scaled by
    1 + perturb x a standard normal draw per push (seeded): how well must a model know the state there?
    ``state``: (p, q, v, w) to start from instead of the truth's (networks reading the history cannot).
    The step is the model's (``model.prior_dt``)."""
    from physdyn.data.windows import store_spin_inertia, store_world_inertia
    from physdyn.eval.rollout import rollout
    from physdyn.geometry.rotations import quat_multiply, rotvec_to_quat

    first = store.start[sims] + start
    q, p = store.orientation_xyzw[first].copy(), store.com_position[first].copy()
    v, w = store.linear_velocity[first].copy(), store.angular_velocity[first].copy()
    if state is not None:
        p, q, v, w = (np.array(x, dtype=np.float64) for x in state)
    if perturb:
        rng = np.random.default_rng(0)
        v *= 1.0 + perturb * rng.standard_normal((len(sims), 1))
        w *= 1.0 + perturb * rng.standard_normal((len(sims), 1))
    points = store.points[store.shape_id[sims]]
    dt = float(model.prior_dt)
    path = [(p, q, v, w)]
    # the velocities so far (the truth's before ``start``), for the networks that read the history
    lin = [store.linear_velocity[first - start + j] for j in range(start)] + [v]
    ang = [store.angular_velocity[first - start + j] for j in range(start)] + [w]
    for k in range(start, start + steps):
        r = rollout(model, points, q, p, v, w, 1, spin_inertia=store_spin_inertia(store, sims, q),
                    body_inertia=store_world_inertia(store, sims, q))
        q1, p1 = r.orientation_xyzw[:, 1].copy(), r.com_position[:, 1].copy()
        v1, w1 = r.linear_velocity[:, 1].copy(), r.angular_velocity[:, 1].copy()
        moving = np.flatnonzero((np.linalg.norm(v, axis=1) > 0.02) | (np.linalg.norm(w, axis=1) > 0.2))
        if nets and len(moving):
            for part in np.array_split(moving, -(-len(moving) // chunk)):
                turn = travel_turn(v[part])
                rot = lambda x: np.einsum("bij,bj->bi", turn, x)  # noqa: E731
                spin = store_spin_inertia(store, sims[part], q[part])
                base = np.concatenate([rot(v[part]), rot(w[part]), spin[:, None], rot(v1[part] - v[part]), rot(w1[part] - w[part])], axis=1)
                d = {"inputs": base}
                if any("gap" in groups for _, _, groups, _ in nets):
                    d["gap"] = ground_gap(clouds[256][store.shape_id[sims[part]]], q[part], p[part])
                if any(g != "gap" for _, _, groups, _ in nets for g in groups):
                    # the history of these pushes: their velocities at steps 0..k as rows (k + 1) * B + push
                    hl, ha = np.concatenate([x[part] for x in lin]), np.concatenate([x[part] for x in ang])
                    rows = np.arange(len(part))
                    d["hist"] = history(turn, hl, ha, k * len(part) + rows, np.full(len(part), k), rows, len(part))
                frame = turn @ quat_to_matrix(q[part])
                fixes = []
                for net, run, groups, n in nets:
                    x = inputs_of(d, groups)
                    xs = torch.tensor((x - run["inputs_mean"]) / run["inputs_std"], dtype=torch.float32)
                    cl = torch.tensor(np.einsum("bij,bnj->bni", frame, clouds[n][store.shape_id[sims[part]]]), dtype=torch.float32)
                    with torch.no_grad():
                        fixes.append(net(cl, xs).numpy() * run["targets_std"] + run["targets_mean"])
                fix = np.mean(fixes, axis=0)
                back = lambda x: np.einsum("bji,bj->bi", turn, x)  # noqa: E731  travel -> world
                dv, dw = back(fix[:, :3]), back(fix[:, 3:])
                v1[part] += dv
                w1[part] += dw
                p1[part] += 0.5 * dt * dv
                q1[part] = quat_multiply(rotvec_to_quat(0.5 * dt * dw), q1[part])
                q1[part] /= np.linalg.norm(q1[part], axis=1, keepdims=True)
        p, q, v, w = p1, q1, v1, w1
        path.append((p, q, v, w))
        lin.append(v)
        ang.append(w)
    return tuple(np.stack([s[i] for s in path], axis=1) for i in range(4))


def state_errors(store, sims, k, v, w):
    """How far velocities ``v``, ``w`` (B, 3) are from the truth's ``k`` recorded steps after each push: the
    speed's relative error (%), and the spin's about the vertical (%, and rad/s) over the pushes spinning
    faster than 2 rad/s at the push; medians."""
    t = store.start[sims] + k
    speed, spin = np.linalg.norm(store.linear_velocity[t], axis=1), store.angular_velocity[t, 2]
    spinning = np.abs(store.angular_velocity[store.start[sims], 2]) > 2.0
    dv = np.abs(np.linalg.norm(v, axis=1) - speed) / np.maximum(speed, 1e-3)
    dw = np.abs(w[spinning, 2] - spin[spinning])
    return (100 * np.median(dv), 100 * np.median(dw / np.maximum(np.abs(spin[spinning]), 0.2)), np.median(dw))


def state_at(paths, nets, model, k):
    """How far the prior's and the learned step's roll-outs from the push are from the truth ``k`` steps in:
    the speed's relative error, and the spin's about the vertical (pushes spinning over 2 rad/s at the push)."""
    from physdyn.data.store import load_store
    from physdyn.geometry.sampling import thin_hull_surface

    for path in paths:
        store = load_store(path)
        sims = np.flatnonzero(store.topple_step < 0)
        sims = sims[store.lengths()[sims] > k + 1]
        full = np.asarray(store.points, dtype=np.float64)
        clouds = {256: full, 64: np.stack([thin_hull_surface(c, 64) for c in full])}
        line = f"{path[-40:]:40s} {len(sims)} pushes, at {k}/15 s:"
        for name, used in (("prior", ()), ("learned", nets)):
            _, _, V, W = learned_rollout(model, store, sims, clouds, k, used)
            speed, spin, spin_rad = state_errors(store, sims, k, V[:, k], W[:, k])
            line += f" {name}: speed {speed:.0f} % off, spin {spin_rad:.2f} rad/s off ({spin:.0f} % of the truth's);"
        print(line, flush=True)


def closed(paths, nets, model, with_prior, start=0, perturb=0.0):
    from physdyn.data.store import load_store
    from physdyn.geometry.rotations import quat_conjugate, quat_multiply, wrap_angle
    from physdyn.geometry.sampling import thin_hull_surface

    for path in paths:
        store = load_store(path)
        sims = np.flatnonzero(store.topple_step < 0)
        sims = sims[store.lengths()[sims] > start + 1]
        n = store.lengths()[sims] - start
        last = store.start[sims] + start + n - 1
        full = np.asarray(store.points, dtype=np.float64)
        clouds = {256: full, 64: np.stack([thin_hull_surface(c, 64) for c in full])}
        line = f"{path[-40:]:40s} {len(sims)} pushes, final position / yaw error:"
        for learned in ((False, True) if with_prior else (True,)):
            t0 = time.time()
            P, Q, _, _ = learned_rollout(model, store, sims, clouds, int(n.max()) - 1, nets if learned else (), start=start,
                                         perturb=perturb)
            rows = np.arange(len(sims))
            dp = np.linalg.norm(P[rows, n - 1, :2] - store.com_position[last, :2], axis=1)
            yaw = np.abs(wrap_angle(oc.yaw_of(quat_multiply(Q[rows, n - 1], quat_conjugate(store.orientation_xyzw[last])))))
            line += (f" {'learned' if learned else 'prior'} {100 * np.median(dp):.2f} cm, {np.degrees(np.median(yaw)):.1f} deg"
                     f" ({time.time() - t0:.0f} s);")
        print(line, flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cmd", choices=["export", "slim", "train", "closed", "by-time", "state-at"])
    ap.add_argument("--train", nargs="*", default=[])
    ap.add_argument("--external", nargs="*", default=[])
    ap.add_argument("--out", default="runs/turn/step.npz")
    ap.add_argument("--extra", default=EXTRA)
    ap.add_argument("--per-push", type=int, default=8)
    ap.add_argument("--inputs", nargs="*", default=[], choices=sorted(GROUPS),
                    help="extra inputs: the ground gap, the last one or two steps' changes, the time since the push, the push")
    ap.add_argument("--history-noise", type=float, default=0.0,
                    help="also train on the training pushes with the history's changes blurred by this many of their std")
    ap.add_argument("--points", type=int, choices=[64, 256], default=64)
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--widths", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--save", nargs="*", default=[])
    ap.add_argument("--from-step", type=int, default=0,
                    help="closed: start from the truth's state this many steps in; state-at: compare there")
    ap.add_argument("--perturb", type=float, default=0.0,
                    help="closed: scale the starting speed and spin by 1 + this x N(0, 1), per push")
    ap.add_argument("--no-prior", action="store_true", help="closed: skip the prior-alone roll-out")
    a = ap.parse_args()
    if a.cmd == "export":
        parts = [extra(p, a.per_push) for p in a.train]
        train_d = {k: np.concatenate([d[k] for d in parts]) for k in parts[0]}
        flat = {f"train_{k}": v for k, v in train_d.items()}
        for i, p in enumerate(a.external):
            flat.update({f"ext{i}_{k}": v for k, v in extra(p, a.per_push).items()})
        np.savez(a.extra, **flat)
        load(a.out, a.extra)  # the alignment check
        print(f"wrote {a.extra}; lines up with {a.out}")
    elif a.cmd == "slim":  # --extra's gap and history alone, to --out
        z = np.load(a.extra)
        np.savez_compressed(a.out, **{k: z[k] for k in z.files if k.endswith(("_gap", "_hist"))})
    elif a.cmd == "train":
        a.save = a.save[0] if a.save else None
        train(a)
    elif a.cmd == "by-time":
        by_time(a)
    else:
        from physdyn.predict.predictor import load_predictor

        model = load_predictor("fast").model
        model.outcome_correction = model.topple_classifier = None
        if a.cmd == "state-at":
            state_at(a.external, load_networks(a.save), model, a.from_step)
        else:
            closed(a.external, load_networks(a.save), model, not a.no_prior, a.from_step, a.perturb)


if __name__ == "__main__":
    main()
