"""The outcome correction's turn, unwrapped: does it gain from the roll-out's whole turn (an input) and a turn
target relative to it? (docs/research/outcome-correction.md.)

A push turns a median 206 degrees on the frontier's pybullet set, and the contact prior's whole turn is off by
a factor (truth / prior: quartiles 1.04-1.62), yet the shipped correction reads and corrects the resting yaw
wrapped to [-pi, pi]: it cannot say "a fifth more turn". Kinds:
  A  the shipped formulation: 13 inputs, target wrap(truth yaw - roll-out yaw);
  B  14 inputs, the roll-out's unwrapped turn added; target (turn_truth - turn_rollout) / (|turn_rollout| + C);
  C  14 inputs as B, the target as A (wrapped).

    # here: the stores as impact_pointnet.py's docstring makes them, the x40 one with 40 pushes a mesh in
    # mesh_folder_store; the roll-outs are `fast`'s prior (8 sub-steps)
    python benchmarks/studies/unwrapped_turn.py export --train data/clusters_hull.zarr \
        runs/urdf_train/urdf_160_999_x40_hull256.zarr --external runs/external_val_100/urdf_100_159_hull256.zarr \
        runs/frontier/pybullet/meshes_60_truth_x5.zarr runs/external/external_30x10.zarr --out runs/turn/uc.npz
    python benchmarks/studies/unwrapped_turn.py turns --out runs/turn/uc.npz      # what the yaw needs
    python benchmarks/studies/unwrapped_turn.py train --out runs/turn/urdf.npz --steps 4000 --seeds 0 1   # MLPs, CPU
    # on a GPU machine (runs/turn/uc.npz carried), one run a kind and seed, several at once:
    python3 benchmarks/studies/unwrapped_turn.py train --out runs/turn/uc.npz --pointnet --device cuda --kinds C \
        --seeds 0 --steps 10000 --minutes 4.5 --save $OUT/C_s0
    python benchmarks/studies/unwrapped_turn.py evaluate --out runs/turn/uc.npz --runs C_s0_C.pt C_s1_C.pt C_s2_C.pt

(runs/turn/urdf.npz: the same export with runs/urdf_train/urdf_160_999_x40_hull256.zarr alone as --train.)
Training needs torch and numpy only (a GPU machine has no zarr or trimesh): the package modules it imports
at the top import neither.
"""
import argparse
import sys
import time

import numpy as np
import torch

from physdyn.geometry.rotations import quat_conjugate, quat_multiply, wrap_angle
from physdyn.models import outcome_correction as oc

C = 0.5  # rad: B's target is the turn's miss over |the roll-out's turn| + C, so small turns keep a scale


def unwrapped(q, w, dt):
    """(B, T) turn about the vertical since step 0, unwrapped: each step's yaw change taken nearest to what
    the mean spin over the step turns (a body may turn more than half a turn between 15 Hz frames)."""
    yaw = oc.yaw_of(quat_multiply(q, quat_conjugate(q[:, :1])))
    wbar = 0.5 * (w[:, 1:, 2] + w[:, :-1, 2]) * dt
    d = wrap_angle(np.diff(yaw, axis=1) - wbar) + wbar
    return np.concatenate([np.zeros((len(q), 1)), np.cumsum(d, axis=1)], axis=1)



def outcomes(model, paths):
    """physdyn.eval.outcome_fit.store_outcomes plus the roll-out's and the truth's unwrapped turns (tp, tt) and
    the truth's displacement (disp): the roll-outs are store_outcomes' own, read as it makes them."""
    from physdyn.data.store import load_store
    from physdyn.eval import outcome_fit

    stores = [load_store(p) for p in paths]
    rolled = []

    def keeping(*args, **kwargs):
        out = real(*args, **kwargs)
        rolled.append(unwrapped(out.orientation_xyzw, out.angular_velocity, model.prior_dt)[:, -1])
        return out

    real, outcome_fit.rollout = outcome_fit.rollout, keeping
    try:
        out = outcome_fit.store_outcomes(model, stores)
    finally:
        outcome_fit.rollout = real
    out["tp"] = np.concatenate(rolled)
    tt = []
    for store in stores:  # store_outcomes' order: each store's non-toppling pushes
        lengths = store.lengths()
        for s in np.flatnonzero(store.topple_step < 0):
            a, n = store.start[s], lengths[s]
            tt.append(unwrapped(store.orientation_xyzw[None, a:a + n], store.angular_velocity[None, a:a + n], 1 / 15)[0, -1])
    out["tt"] = np.array(tt)
    out["disp"] = np.linalg.norm(out["targets"][:, :2] + out["inputs"][:, 9:11], axis=1)  # truth = roll-out + target
    return out


def variant(d, kind):
    """The inputs and targets of kind A, B or C (the module's docstring)."""
    if kind == "A":
        return d["inputs"], d["targets"]
    x = np.concatenate([d["inputs"], d["tp"][:, None]], axis=1)
    y = d["targets"].copy()
    if kind == "B":
        y[:, 2] = (d["tt"] - d["tp"]) / (np.abs(d["tp"]) + C)
    return x, y



def set_mode(kind):
    """What train_outcome_network reads from the module: the number of inputs and how they mirror (the whole
    turn changes sign, as the resting yaw does)."""
    n = 13 if kind == "A" else 14
    oc.INPUTS = n
    oc.MIRROR_INPUTS = np.concatenate([np.array([1, -1, 1, -1, 1, -1, 1, -1, -1, 1, -1, -1, 1.0]), [-1.0]])[:n]



def predict(run, x, clouds=None, shape=None, frame=None, width=256, pointnet=False, widths=(64, 128, 256)):
    xs = torch.tensor((x - run["inputs_mean"]) / run["inputs_std"], dtype=torch.float32)
    xs[:, torch.tensor(run["inputs_std"] < oc.CONSTANT_INPUT)] = 0
    with torch.no_grad():
        if not pointnet:
            net = oc.OutcomeNet(width, x.shape[1])
            net.load_state_dict(run["state_dict"])
            h = net(xs)
        else:
            net = oc.ToppleNet(width, x.shape[1], tuple(widths), outputs=3)
            net.load_state_dict(run["state_dict"])
            cl = torch.tensor(np.einsum("bij,bnj->bni", frame, clouds[shape]), dtype=torch.float32)
            h = torch.cat([net(cl[i:i + 4096], xs[i:i + 4096]) for i in range(0, len(xs), 4096)])
    return h.numpy() * run["targets_std"] + run["targets_mean"]



def score(d, kind, fix, idx):
    """Median position error (cm), yaw error (deg) and position error over the truth's displacement."""
    along = d["targets"][idx, 0] - (fix[:, 0] if fix is not None else 0)
    across = d["targets"][idx, 1] - (fix[:, 1] if fix is not None else 0)
    pos = np.hypot(along, across)
    if fix is None:
        yaw = d["targets"][idx, 2]
    elif kind in ("A", "C"):
        yaw = wrap_angle(d["targets"][idx, 2] - fix[:, 2])
    else:
        tp = d["tp"][idx]
        yaw = wrap_angle(d["tt"][idx] - (tp + fix[:, 2] * (np.abs(tp) + C)))
    return np.median(pos) * 100, np.degrees(np.median(np.abs(yaw))), np.median(pos / np.maximum(d["disp"][idx], 1e-6))



def load_parts(path):
    z = np.load(path)

    def part(prefix):
        return {k[len(prefix):]: z[k] for k in z.files if k.startswith(prefix)}

    return part("train_"), [part(f"ext{i}_") for i in range(len(z["names"]))], [str(n) for n in z["names"]]


def evaluate(path, kind, runs, seeds, pointnet, widths):
    """Median resting position error (cm), yaw error (deg) and position error / displacement, per seed and
    for the seeds' mean, on the training stores' test split and each external store."""
    tr, ex, names = load_parts(path)
    set_mode(kind)
    test = np.flatnonzero(tr["rests"] & (tr["split"] == 2))
    for name, d, idx in [("test split", tr, test)] + [(n, e, np.flatnonzero(e["rests"])) for n, e in zip(names, ex)]:
        xe, _ = variant(d, kind)
        kw = dict(clouds=d["clouds"], shape=d["shape"][idx], frame=d["frame"][idx], pointnet=True, widths=tuple(widths)) if pointnet else {}
        fixes = [predict(r, xe[idx], **kw) for r in runs]
        line = [f"{name[-40:]:40s} prior " + "%.2f cm %.1f deg %.3f" % score(d, kind, None, idx)]
        for s, f in zip(seeds, fixes):
            line.append(f"{kind}s{s} " + "%.2f cm %.1f deg %.3f" % score(d, kind, f, idx))
        if len(fixes) > 1:
            line.append(f"{kind} mean " + "%.2f cm %.1f deg %.3f" % score(d, kind, np.mean(fixes, 0), idx))
        print(" | ".join(line), flush=True)


def turns(path):
    """How the roll-out's whole turn compares with the truth's, per set; what knowing the truth's turn to a
    few per cent would give; and what a per-shape or global factor on the roll-out's turn gives."""
    tr, ex, names = load_parts(path)
    rng = np.random.default_rng(0)
    for name, d in [("training stores, every split", tr)] + list(zip(names, ex)):
        m = d["rests"]
        tp, tt = d["tp"][m], d["tt"][m]
        print(f"== {name}: {m.sum()} pushes at rest; the roll-out's yaw error {np.degrees(np.median(np.abs(wrap_angle(tt - tp)))):.1f} deg")
        print("   the truth's |turn|, quartiles and 90th percentile (deg):", np.percentile(np.degrees(np.abs(tt)), [25, 50, 75, 90]).round(0))
        big = np.abs(tp) > 0.3
        print("   truth / roll-out turn (|roll-out turn| > 0.3 rad), percentiles 10 25 50 75 90:", np.percentile(tt[big] / tp[big], [10, 25, 50, 75, 90]).round(2))
        known = [np.degrees(np.median(np.abs(wrap_angle(tt * s * rng.standard_normal(len(tt)))))) for s in (0.02, 0.05, 0.1, 0.2)]
        print("   the truth's turn known to 2 / 5 / 10 / 20 %% (gaussian): yaw error %.1f / %.1f / %.1f / %.1f deg" % tuple(known))
    m = tr["rests"] & (np.abs(tr["tp"]) > 1.0) & (np.sign(tr["tp"]) == np.sign(tr["tt"]))
    lr_all = np.log(tr["tt"][m] / tr["tp"][m])
    shape = tr["shape"][m]
    # the pushes of shapes with at least five such pushes: every figure below is over these
    keep = np.isin(shape, [u for u in np.unique(shape) if (shape == u).sum() >= 5])
    tp, tt, shape, lr = tr["tp"][m][keep], tr["tt"][m][keep], shape[keep], lr_all[keep]
    within, loo = [], np.empty(len(tp))
    for u in np.unique(shape):
        j = np.flatnonzero(shape == u)
        within.append(lr[j] - np.median(lr[j]))
        for k in j:
            loo[k] = abs(wrap_angle(tt[k] - np.exp(np.median(lr[j[j != k]])) * tp[k]))  # its shape's other pushes
    g = np.exp(np.median(lr))
    print(f"== training stores, pushes turning over 1 rad the same way in both, of shapes with at least five such "
          f"({len(tp)} of {m.sum()}): log(truth / roll-out turn) median {np.median(lr):.3f}, spread (median |deviation|) "
          f"{np.median(np.abs(lr - np.median(lr))):.3f} over all, {np.median(np.abs(np.concatenate(within))):.3f} within a shape")
    print(f"   yaw error: the roll-out {np.degrees(np.median(np.abs(wrap_angle(tt - tp)))):.1f} deg; each push's turn times "
          f"its shape's other pushes' median factor {np.degrees(np.median(loo)):.1f} deg; times one factor for all "
          f"({g:.3f}) {np.degrees(np.median(np.abs(wrap_angle(tt - g * tp)))):.1f} deg")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cmd", choices=["export", "turns", "train", "evaluate"])
    ap.add_argument("--train", nargs="*", default=[])
    ap.add_argument("--external", nargs="*", default=[])
    ap.add_argument("--out", default="runs/turn/turn.npz", help="the exported roll-outs")
    ap.add_argument("--checkpoint", default="fast", help="export: whose prior rolls out (its correction and classifier dropped)")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--kinds", nargs="+", default=["A", "B"])
    ap.add_argument("--pointnet", action="store_true")
    ap.add_argument("--num-points", type=int, default=64, help="export: clouds thinned to this many points")
    ap.add_argument("--widths", type=int, nargs="+", default=[32, 64, 128])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--save", default=None, help="train: write PREFIX_KIND.pt; evaluate: the .pt files to read")
    ap.add_argument("--runs", nargs="*", default=[], help="evaluate: .pt files of one kind, averaged")
    a = ap.parse_args()
    if a.cmd == "export":
        from physdyn.geometry.sampling import thin_hull_surface
        from physdyn.predict.predictor import load_predictor

        model = load_predictor(a.checkpoint).model
        model.outcome_correction = model.topple_classifier = None
        tr = outcomes(model, a.train)
        ex = [outcomes(model, [p]) for p in a.external]
        for d in [tr] + ex:
            d["clouds"] = np.stack([thin_hull_surface(c, a.num_points) for c in d["clouds"]]).astype(np.float32)
        flat = {f"train_{k}": v for k, v in tr.items()}
        for i, d in enumerate(ex):
            flat.update({f"ext{i}_{k}": v for k, v in d.items()})
        flat["names"] = np.array(a.external)
        np.savez(a.out, **flat)
        return
    if a.cmd == "turns":
        turns(a.out)
        return
    if a.cmd == "evaluate":
        saved = [torch.load(f, weights_only=False) for f in a.runs]
        kind = saved[0]["kind"]
        evaluate(a.out, kind, [r for s in saved for r in s["runs"]], [s for f in saved for s in f["seeds"]],
                 saved[0]["pointnet"], saved[0]["widths"])
        return
    tr, _, _ = load_parts(a.out)
    use = tr["rests"]
    train, val, test = (np.flatnonzero(use & (tr["split"] == s)) for s in (0, 1, 2))
    print(f"train {len(train)} val {len(val)} test {len(test)}", flush=True)
    for kind in a.kinds:
        set_mode(kind)
        x, y = variant(tr, kind)
        runs = []
        for s in a.seeds:
            t0 = time.time()
            kw = dict(clouds=tr["clouds"], shape=tr["shape"], frame=tr["frame"], point_widths=tuple(a.widths)) if a.pointnet else {}
            r = oc.train_outcome_network(x, y, train, val, a.steps, 1024, 256, s, device=a.device, minutes=a.minutes, **kw)
            r["state_dict"] = {k: v.cpu() for k, v in r["state_dict"].items()}
            runs.append(r)
            print(f"{kind} seed {s}: validation {r['val_error']:.3f}, {time.time() - t0:.0f} s, {r['steps']} steps", flush=True)
        if a.save:
            torch.save({"kind": kind, "runs": runs, "seeds": a.seeds, "pointnet": a.pointnet, "widths": a.widths},
                       f"{a.save}_{kind}.pt")
        evaluate(a.out, kind, runs, a.seeds, a.pointnet, a.widths)


if __name__ == "__main__":
    main()
