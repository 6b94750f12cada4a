"""Can a network that reads the cloud in its current pose learn the simulator's one-step change of spin?
(docs/research/learned-step.md.)

A rotation error of 10 degrees needs a push's spin deceleration right to about 7-8 %
(docs/research/friction-and-sensitivity.md), and
that a correction of where the contact prior stops cannot get there. The alternative is a learned step: a
network that, fed the true state at a 15 Hz step (the cloud turned to its current orientation, in the frame
of its current horizontal travel, with the velocities, I_zz / m and the contact prior's own one-step change
from that state), gives the truth's change over the step. This measures how well such a network fits that
change, teacher forced (every input from the truth), and how it rolls out.

    python benchmarks/studies/spin_step.py export --train data/clusters_hull.zarr \\
        runs/urdf_train/urdf_160_999_x40_hull256.zarr --external runs/external_val_100/urdf_100_159_hull256.zarr \\
        runs/frontier/pybullet/meshes_60_truth_x5.zarr runs/external/external_30x10.zarr --out runs/turn/step.npz
    # on a GPU machine (runs/turn/step.npz carried):
    python3 benchmarks/studies/spin_step.py train --out runs/turn/step.npz --device cuda --seed 0 --save $OUT/step_s0.pt
    # here: the learned step in the loop, against the prior alone in the same loop
    python benchmarks/studies/spin_step.py closed --save step_s0.pt --external runs/external_val_100/urdf_100_159_hull256.zarr \
        runs/frontier/pybullet/meshes_60_truth_x5.zarr runs/external/external_30x10.zarr
    # and with fit-outcome's 13-input correction fitted on the learned step's roll-outs
    python benchmarks/studies/spin_step.py stack --steps 4000 --save step_s0.pt --train data/clusters_hull.zarr \
        runs/urdf_train/urdf_160_999_x40_hull256.zarr --external ...

Samples: every step of every non-toppling push while the body moves (speed over 0.02 m/s or spin over 0.2
rad/s), at most ``--per-push`` a push (evenly spread). Targets: the truth's change of velocity and spin over
the step minus the prior's, in the travel frame. Scored on the spinning samples (|w_z| > 2 rad/s): median
|error of the change of w_z| over the median |truth's change|, the prior's and the network's.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from unwrapped_turn import load_parts, predict  # noqa: E402

from physdyn.geometry.rotations import quat_to_matrix  # noqa: E402
from physdyn.models import outcome_correction as oc  # noqa: E402
from physdyn.models.topple_pointnet import travel_turn  # noqa: E402

MIRROR_INPUTS = np.array([1, -1, 1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1], dtype=np.float64)  # v, w, I, dv, dw prior
MIRROR_TARGETS = np.array([1, -1, 1, -1, 1, -1], dtype=np.float64)


def chosen_steps(store, per_push):
    """The samples' pushes and steps: every non-toppling push's moving steps (speed over 0.02 m/s or spin
    over 0.2 rad/s), at most ``per_push`` of them, evenly spread."""
    lengths = store.lengths()
    sims, frames = [], []
    for s in np.flatnonzero(store.topple_step < 0):
        f = store.start[s] + np.arange(lengths[s] - 1)
        moving = (np.linalg.norm(store.linear_velocity[f], axis=1) > 0.02) | (np.linalg.norm(store.angular_velocity[f], axis=1) > 0.2)
        f = f[moving]
        if len(f) > per_push:
            f = f[np.linspace(0, len(f) - 1, per_push).round().astype(int)]
        sims += [s] * len(f)
        frames += list(f)
    return np.array(sims, dtype=np.int64), np.array(frames, dtype=np.int64)


def samples(model, path, per_push, chunk=4096, choose=chosen_steps):
    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia, store_world_inertia
    from physdyn.eval.rollout import rollout

    store = load_store(path)
    sims, frames = choose(store, per_push)
    out = {k: [] for k in ("inputs", "targets", "truth", "frame", "shape", "split", "push")}
    for i in range(0, len(sims), chunk):
        s, f = sims[i:i + chunk], frames[i:i + chunk]
        q, p = store.orientation_xyzw[f], store.com_position[f]
        v, w = store.linear_velocity[f], store.angular_velocity[f]
        spin = store_spin_inertia(store, s, q)
        r = rollout(model, store.points[store.shape_id[s]], q, p, v, w, 1, spin_inertia=spin,
                    body_inertia=store_world_inertia(store, s, q))
        turn = travel_turn(v)
        rot = lambda x: np.einsum("bij,bj->bi", turn, x)  # noqa: E731
        dv_p, dw_p = rot(r.linear_velocity[:, 1] - v), rot(r.angular_velocity[:, 1] - w)
        dv_t, dw_t = rot(store.linear_velocity[f + 1] - v), rot(store.angular_velocity[f + 1] - w)
        out["inputs"].append(np.concatenate([rot(v), rot(w), spin[:, None], dv_p, dw_p], axis=1))
        out["targets"].append(np.concatenate([dv_t - dv_p, dw_t - dw_p], axis=1))
        out["truth"].append(np.concatenate([dv_t, dw_t], axis=1))
        out["frame"].append(turn @ quat_to_matrix(q))
        out["shape"].append(store.shape_id[s].astype(np.int64))
        out["split"].append(np.asarray(store.split[s], dtype=np.int64))
        out["push"].append(s.astype(np.int64))
    d = {k: np.concatenate(v).astype(np.float32 if k in ("inputs", "targets", "truth", "frame") else np.int32) for k, v in out.items()}
    d["clouds"] = np.asarray(store.points, dtype=np.float32)
    print(f"{path}: {len(sims)} samples", flush=True)
    return d


def print_scores(net, run, sets, inputs_of=lambda d: d["inputs"], clouds="clouds", chunk=8192):
    """The network's one-step fit against the prior's (``score``) on each (name, samples, index) of ``sets``."""
    for name, d, idx in sets:
        x = torch.tensor((inputs_of(d)[idx] - run["inputs_mean"]) / run["inputs_std"], dtype=torch.float32)
        cl = torch.tensor(np.einsum("bij,bnj->bni", d["frame"][idx], d[clouds][d["shape"][idx]]), dtype=torch.float32)
        with torch.no_grad():
            h = torch.cat([net(cl[i:i + chunk], x[i:i + chunk]) for i in range(0, len(x), chunk)]).numpy()
        fix = h * run["targets_std"] + run["targets_mean"]
        prior, learned = score(d, idx, None), score(d, idx, fix)
        print(f"{name[-40:]:40s} change of w_z (spinning): prior {prior['w_z']:.3f}, network {learned['w_z']:.3f} | "
              f"of the speed along: prior {prior['v_along']:.3f}, network {learned['v_along']:.3f}", flush=True)


def merged(parts):
    out, offset = {}, 0
    for d in parts:
        d = dict(d)
        d["shape"] = d["shape"] + offset
        offset += len(d["clouds"])
        for k, v in d.items():
            out.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in out.items()}


def score(d, idx, fix):
    """Median |error of the change of w_z| / median |truth's change|, and the same for the speed along the travel."""
    spin = idx[np.abs(d["inputs"][idx, 5]) > 2.0]
    res = {}
    for name, col in (("w_z", 5), ("v_along", 0)):
        sel = spin if name == "w_z" else idx
        truth = np.abs(d["truth"][sel, col])
        err = d["targets"][sel, col] - (0 if fix is None else fix[np.searchsorted(idx, sel), col])
        res[name] = np.median(np.abs(err)) / np.median(truth)
    return res


def stack(train_paths, ext_paths, saved, model, steps, seeds):
    """A correction of the end (fit-outcome's 13-input networks) fitted on the learned step's roll-outs to
    rest, and scored on them: does it add to the learned step? (The roll-out is step_inputs.py's.)"""
    from step_inputs import learned_rollout, load_networks

    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia
    from physdyn.geometry.rotations import wrap_angle
    from physdyn.geometry.sampling import thin_hull_surface

    nets = load_networks([saved])

    def outcomes(path):
        store = load_store(path)
        sims = np.flatnonzero(store.topple_step < 0)
        n = store.lengths()[sims]
        first, last = store.start[sims], store.start[sims] + n - 1
        thin = np.stack([thin_hull_surface(c, 64) for c in np.asarray(store.points)])
        P, Q, V, W = learned_rollout(model, store, sims, {64: thin}, int(n.max()) - 1 + oc.EXTRA_STEPS, nets)
        rows, end = np.arange(len(sims)), n - 1 + oc.EXTRA_STEPS
        q0, v0, w0 = store.orientation_xyzw[first], store.linear_velocity[first], store.angular_velocity[first]
        inputs, turn = oc.outcome_inputs(v0, w0, store_spin_inertia(store, sims, q0), store.com_position[first], q0,
                                         P[rows, end], Q[rows, end], V[rows, end], W[rows, end])
        truth = oc.resting_state(turn, store.com_position[first], q0, store.com_position[last], store.orientation_xyzw[last],
                                 store.linear_velocity[last], store.angular_velocity[last])
        target = truth[:, 3:] - inputs[:, 9:12]
        target[:, 2] = wrap_angle(target[:, 2])
        rests = (np.linalg.norm(V[rows, end], axis=1) < oc.REST_SPEED) & (np.linalg.norm(W[rows, end], axis=1) < oc.REST_SPIN)
        print(f"rolled {path}: {len(sims)} pushes, {rests.sum()} at rest", flush=True)
        return {"inputs": inputs, "targets": target, "rests": rests, "split": np.asarray(store.split[sims])}

    parts = [outcomes(p) for p in train_paths]
    tr = {k: np.concatenate([d[k] for d in parts]) for k in parts[0]}
    train, val = (np.flatnonzero(tr["rests"] & (tr["split"] == s)) for s in (0, 1))
    runs = [oc.train_outcome_network(tr["inputs"], tr["targets"], train, val, steps, 1024, 256, s) for s in seeds]
    for path in ext_paths:
        d = outcomes(path)
        idx = np.flatnonzero(d["rests"])
        line = [f"{path[-40:]:40s} {len(idx)} at rest: the learned step %.2f cm, %.1f deg" % (
            100 * np.median(np.hypot(*d["targets"][idx, :2].T)), np.degrees(np.median(np.abs(d["targets"][idx, 2]))))]
        for s, r in zip(seeds, runs):
            err = d["targets"][idx] - predict(r, d["inputs"][idx])
            line.append(f"+ correction s{s} %.2f cm, %.1f deg" % (100 * np.median(np.hypot(*err[:, :2].T)),
                                                               np.degrees(np.median(np.abs(wrap_angle(err[:, 2]))))))
        print(" | ".join(line), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cmd", choices=["export", "train", "closed", "stack"])
    ap.add_argument("--train", nargs="*", default=[])
    ap.add_argument("--external", nargs="*", default=[])
    ap.add_argument("--out", default="runs/turn/step.npz")
    ap.add_argument("--per-push", type=int, default=8)
    ap.add_argument("--num-points", type=int, default=64)
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--widths", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--save", default=None)
    a = ap.parse_args()
    if a.cmd == "export":
        from physdyn.geometry.sampling import thin_hull_surface
        from physdyn.predict.predictor import load_predictor

        model = load_predictor("fast").model
        model.outcome_correction = model.topple_classifier = None
        sets = [merged([samples(model, p, a.per_push) for p in a.train])] + [samples(model, p, a.per_push) for p in a.external]
        for d in sets:
            d["clouds"] = np.stack([thin_hull_surface(c, a.num_points) for c in d["clouds"]]).astype(np.float32)
        flat = {f"train_{k}": v for k, v in sets[0].items()}
        for i, d in enumerate(sets[1:]):
            flat.update({f"ext{i}_{k}": v for k, v in d.items()})
        flat["names"] = np.array(a.external)
        np.savez(a.out, **flat)
        return
    if a.cmd in ("closed", "stack"):
        from physdyn.predict.predictor import load_predictor

        model = load_predictor("fast").model
        model.outcome_correction = model.topple_classifier = None
        if a.cmd == "closed":  # the prior alone and with the learned step, in step_inputs.py's loop
            from step_inputs import closed, load_networks

            closed(a.external, load_networks([a.save]), model, True)
        else:
            stack(a.train, a.external, a.save, model, a.steps, (0, 1))
        return
    tr, ex, names = load_parts(a.out)
    train, val, test = (np.flatnonzero(tr["split"] == s) for s in (0, 1, 2))
    oc.INPUTS, oc.MIRROR_INPUTS = len(MIRROR_INPUTS), MIRROR_INPUTS
    oc.TARGETS, oc.MIRROR_TARGETS = ("dv_x", "dv_y", "dv_z", "dw_x", "dw_y", "dw_z"), MIRROR_TARGETS
    t0 = time.time()
    run = oc.train_outcome_network(tr["inputs"].astype(np.float64), tr["targets"].astype(np.float64), train, val,
                                   a.steps, 1024, 256, a.seed, clouds=tr["clouds"], shape=tr["shape"], frame=tr["frame"],
                                   device=a.device, point_widths=tuple(a.widths), minutes=a.minutes)
    print(f"trained: validation {run['val_error']:.3f}, {time.time() - t0:.0f} s, {run['steps']} steps", flush=True)
    run["state_dict"] = {k: v.cpu() for k, v in run["state_dict"].items()}
    if a.save:
        torch.save({"run": run, "widths": a.widths}, a.save)
    net = oc.ToppleNet(256, len(MIRROR_INPUTS), tuple(a.widths), outputs=6)
    net.load_state_dict(run["state_dict"])
    net.eval()
    print_scores(net, run, [("test split", tr, test)] + [(n, e, np.arange(len(e["split"]))) for n, e in zip(names, ex)])


if __name__ == "__main__":
    main()
