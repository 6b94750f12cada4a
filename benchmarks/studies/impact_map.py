"""Can the impact phase be learned from step-0 features? The bundled model's accuracy on new meshes comes
from simulating the first 0.4 s (docs/research/simulated-start.md). Could a learned map from step 0 to the
state at 0.4 s replace that? This measures how much
of the contact prior's error at 0.4 s (K = 6 steps at 15 Hz) a small MLP on the step-0 features of the
topple classifier (physdyn/models/topple_classifier.py, 32 heading-free features) plus the step-0 spin in the
travel frame and the prior's own state at step K takes off, trained on one store's training split, scored on its validation and test
splits (shapes not trained on).

    python -m benchmarks.studies.impact_map data/quickstart_hull_large.zarr [--steps 6]

Targets: the truth's state at step K minus the prior's (rolled out from step 0, the body's inertia), in the
frame of the step-0 travel: velocity (along, across), spin w_z, displacement (along, across), turn about the
vertical. Non-toppling pushes only (the ones the rotation error is scored on).
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np
import torch

from benchmarks.studies.common import in_travel_frame, travel_frame, travel_state
from physdyn.data.store import load_store
from physdyn.data.windows import store_spin_inertia, world_oriented_points
from physdyn.eval.evaluate import select_sequences
from physdyn.eval.rollout import RolloutOptions, rollout
from physdyn.models.priors import contact_geometry
from physdyn.models.topple_classifier import topple_features
from physdyn.predict.predictor import contact_prior_predictor

FOOTPRINT = False
NAMES = ("v along", "v across", "w_z", "p along", "p across", "yaw")


def states(store, sims: np.ndarray, K: int, model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """-> features (B, F), truth - prior at step K (B, 6), the truth's own (B, 6) change over K steps."""
    first = store.start[sims]
    q0, p0 = store.orientation_xyzw[first], store.com_position[first]
    v0, w0 = store.linear_velocity[first], store.angular_velocity[first]
    qK, pK = store.orientation_xyzw[first + K], store.com_position[first + K]
    vK, wK = store.linear_velocity[first + K], store.angular_velocity[first + K]
    points = store.points[store.shape_id[sims]]
    out = rollout(model, points, q0, p0, v0, w0, K, RolloutOptions(spin_inertia=store_spin_inertia(store, sims, q0)))
    u = travel_frame(v0)
    across = np.stack([-u[:, 1], u[:, 0]], axis=1)
    true = travel_state(vK, wK, pK, qK, p0, q0, u)
    prior = travel_state(out.linear_velocity[:, K], out.angular_velocity[:, K], out.com_position[:, K],
                         out.orientation_xyzw[:, K], p0, q0, u)
    diff = true - prior
    diff[:, 5] = (diff[:, 5] + np.pi) % (2 * np.pi) - np.pi
    cloud = world_oriented_points(points, q0)
    w_travel = in_travel_frame(w0, u)
    features = [topple_features(cloud, v0, w0), w_travel, prior]
    if FOOTPRINT:  # the prior's own footprint (4 points, their weights) in the travel frame
        g = contact_geometry(torch.tensor(cloud, dtype=torch.float32)).numpy().astype(np.float64)
        pts = g[:, :12].reshape(-1, 4, 3)
        features.append(np.concatenate([(pts[..., :2] * u[:, None]).sum(-1), (pts[..., :2] * across[:, None]).sum(-1),
                                        pts[..., 2], g[:, 12:]], axis=1))
    return np.concatenate(features, axis=1), diff, true


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("store")
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--footprint", action="store_true", help="add the prior's footprint (travel frame) to the features")
    args = ap.parse_args()
    global FOOTPRINT
    FOOTPRINT = args.footprint
    torch.set_num_threads(1)
    torch.manual_seed(0)
    warnings.simplefilter("ignore")
    store = load_store(args.store)
    model = contact_prior_predictor(rate_hz=store.rate_hz).model
    keep = (store.topple_step < 0) & (store.lengths() > args.steps)
    data = {}
    for name in ("train", "val", "test"):
        sims = np.asarray(select_sequences(store, name))
        sims = sims[keep[sims]]
        data[name] = states(store, sims, args.steps, model)
        print(f"{name}: {len(sims)} non-toppling pushes", file=sys.stderr)
    x_tr, y_tr, _ = data["train"]
    mu, sd = x_tr.mean(0), x_tr.std(0) + 1e-9
    ym, ys = y_tr.mean(0), y_tr.std(0) + 1e-9
    net = torch.nn.Sequential(torch.nn.Linear(x_tr.shape[1], 128), torch.nn.ReLU(), torch.nn.Linear(128, 128),
                              torch.nn.ReLU(), torch.nn.Linear(128, 6))
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-5)
    X = torch.tensor((x_tr - mu) / sd, dtype=torch.float32)
    Y = torch.tensor((y_tr - ym) / ys, dtype=torch.float32)
    best, best_state = np.inf, None
    xv = torch.tensor((data["val"][0] - mu) / sd, dtype=torch.float32)
    yv = torch.tensor((data["val"][1] - ym) / ys, dtype=torch.float32)
    for epoch in range(args.epochs):
        for idx in torch.randperm(len(X)).split(256):
            opt.zero_grad()
            loss = torch.nn.functional.smooth_l1_loss(net(X[idx]), Y[idx])
            loss.backward()
            opt.step()
        with torch.no_grad():
            v = float(torch.nn.functional.smooth_l1_loss(net(xv), yv))
        if v < best:
            best, best_state = v, {k: t.clone() for k, t in net.state_dict().items()}
    net.load_state_dict(best_state)
    print(f"| split | quantity | truth at step {args.steps} (change for p, yaw), median | prior's error, median | prior + MLP, median | ratio |")
    print("|---|---|---|---|---|---|")
    for name in ("train", "val", "test"):
        x, y, true = data[name]
        with torch.no_grad():
            fix = net(torch.tensor((x - mu) / sd, dtype=torch.float32)).numpy() * ys + ym
        rest = y - fix
        rest[:, 5] = (rest[:, 5] + np.pi) % (2 * np.pi) - np.pi
        for j, q in enumerate(NAMES):
            a, b = np.median(np.abs(y[:, j])), np.median(np.abs(rest[:, j]))
            unit = " deg" if q == "yaw" else ""
            scale = 180 / np.pi if q == "yaw" else 1.0
            print(f"| {name} | {q} | {scale * np.median(np.abs(true[:, j])):.4g}{unit} | {scale * a:.4g}{unit} | {scale * b:.4g}{unit} | {b / a:.2f} |")


if __name__ == "__main__":
    main()
