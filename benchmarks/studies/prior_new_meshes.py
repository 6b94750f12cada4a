"""Why the networks add nothing on meshes new to them: the contact prior alone against the truth on the
frontier's pybullet set (benchmarks/frontier.py's store), where its rotation error comes from, and how its
spin deceleration compares with PyBullet's. docs/research/contact-prior.md.

    python -m benchmarks.studies.prior_new_meshes bins       # final errors by the push's spin and speed
    python -m benchmarks.studies.prior_new_meshes onestep    # fed the true state: spin change over one step, prior / truth

The predictor is `contact_prior_predictor()` (the prior alone, no network). Needs the frontier's truth store
(runs/frontier/pybullet/meshes_60_truth_x5.zarr, made by benchmarks/frontier.py on first use).
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
import torch

from benchmarks import frontier as fr  # noqa: E402

from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.predict.predictor import contact_prior_predictor  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402


def setup(work: Path):
    meshes = fr.collect_set("pybullet", work, 60)
    store = fr.truth_store(meshes, 5)
    parsed = {key: load_mesh(key) for key in dict.fromkeys(map(str, store.source))}
    return store, parsed


def bins(store, parsed, predictor) -> None:
    req = fr.requests_from_store(store)
    out = fr.physdyn_batched({"p": predictor}, parsed, req, req.rounds(), False)["p"]
    still = ~req.toppled
    pred, true, q0 = Rotation.from_quat(out.q), Rotation.from_quat(req.true_q), Rotation.from_quat(req.q0)
    error = np.degrees((pred * true.inv()).magnitude())
    yaw = lambda r: np.arctan2(r.as_matrix()[:, 1, 0], r.as_matrix()[:, 0, 0])  # noqa: E731
    true_yaw, pred_yaw = yaw(true * q0.inv()), yaw(pred * q0.inv())
    yaw_error = np.degrees(np.abs((pred_yaw - true_yaw + np.pi) % (2 * np.pi) - np.pi))
    print(f"non-toppling pushes {still.sum()}: rotation error median {np.median(error[still]):.1f} deg, of it yaw "
          f"{np.median(yaw_error[still]):.1f} deg; true turn median {np.degrees(np.median(np.abs(true_yaw[still]))):.1f} deg")
    print("| push's | third | pushes | rotation error (deg) | yaw error (deg) |\n|---|---|---|---|---|")
    for name, x in (("|w_xy| at step 0 (rad/s)", np.linalg.norm(req.w0[:, :2], axis=1)), ("|w_z| at step 0 (rad/s)", np.abs(req.w0[:, 2])),
                    ("speed at step 0 (m/s)", np.linalg.norm(req.v0[:, :2], axis=1))):
        edges = np.quantile(x[still], [0, 1 / 3, 2 / 3, 1])
        for lo, hi in zip(edges[:-1], edges[1:]):
            m = still & (x >= lo) & (x <= hi)
            print(f"| {name} | {lo:.2f}-{hi:.2f} | {m.sum()} | {np.median(error[m]):.1f} | {np.median(yaw_error[m]):.1f} |")


def onestep(store, parsed, predictor) -> None:
    rows = []
    for i in range(store.num_sims):
        if store.topple_step[i] >= 0:
            continue
        f = store.frames(i)
        q, v, w = store.orientation_xyzw[f], store.linear_velocity[f], store.angular_velocity[f]
        mesh = parsed[str(store.source[store.shape_id[i]])]
        for k in range(min(8, len(v) - 1)):
            if abs(w[k, 2]) < 0.5:
                continue
            r = predictor.predict(mesh, v[k], w[k], seconds=1 / predictor.rate_hz, orientation_xyzw=q[k])
            rows.append((k, r["angular_velocity"][-1][2] - w[k, 2], w[k + 1, 2] - w[k, 2],
                         np.linalg.norm(r["linear_velocity"][-1][:2]) - np.linalg.norm(v[k, :2]),
                         np.linalg.norm(v[k + 1, :2]) - np.linalg.norm(v[k, :2]), np.linalg.norm(w[k, :2])))
    a = np.array(rows)
    print("| step | pushes | spin change, prior / truth: median (IQR) | speed change, prior / truth | true tilt spin (rad/s) |\n|---|---|---|---|---|")
    for k in range(8):
        m = (a[:, 0] == k) & (np.abs(a[:, 2]) > 0.05)
        if m.sum() < 5:
            continue
        ratio = a[m, 1] / a[m, 2]
        speed = a[m, 3] / np.where(np.abs(a[m, 4]) > 1e-3, a[m, 4], np.nan)
        print(f"| {k} | {m.sum()} | {np.median(ratio):.2f} ({np.quantile(ratio, .25):.2f}-{np.quantile(ratio, .75):.2f}) | "
              f"{np.nanmedian(speed):.2f} | {np.median(a[m, 5]):.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("bins", "onestep"))
    ap.add_argument("--work", default="runs/frontier")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    store, parsed = setup(Path(args.work))
    {"bins": bins, "onestep": onestep}[args.what](store, parsed, contact_prior_predictor())


if __name__ == "__main__":
    main()
