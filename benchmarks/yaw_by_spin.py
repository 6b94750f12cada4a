"""Where the rotation error comes from: the yaw error of non-toppling pushes by the push's initial spin.

    python benchmarks/yaw_by_spin.py                     # the bundled model, quickstart test split
    python benchmarks/yaw_by_spin.py --external runs/external/external_30x10.zarr   # also the external meshes

For each band of |omega_z| at step 0: how many pushes, the median error of the total yaw (the integral of
the predicted against the true omega_z over the trajectory) and the median ratio of predicted to true
yaw (1: unbiased; below 1: the prediction stops spinning too early). The external store is the one
``benchmarks/external_meshes.py`` writes; its pushes are predicted through ``Predictor.predict``.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from physdyn.data.store import load_store
from physdyn.errors import PredictionWarning
from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import evaluate
from physdyn.predict.body import prepare_body
from physdyn.predict.predictor import BUNDLED_CHECKPOINT, load_predictor

BANDS = ((0, 5), (5, 10), (10, 20), (20, np.inf))  # rad/s


def table(name: str, w0: np.ndarray, yaw_true: np.ndarray, yaw_pred: np.ndarray) -> None:
    err = np.degrees(np.abs(yaw_pred - yaw_true))
    turned = np.abs(yaw_true) > 0.3
    ratio = yaw_pred / np.where(turned, yaw_true, 1.0)
    print(f"\n{name}: {len(w0)} non-toppling pushes; predicted / true yaw, median {np.median(ratio[turned]):.2f}")
    print(f"{'|omega_z| at step 0':<22} {'pushes':>7} {'yaw error (deg)':>16} {'pred / true yaw':>16}")
    for lo, hi in BANDS:
        k = (np.abs(w0) >= lo) & (np.abs(w0) < hi)
        band = f"{lo:g}-{hi:g} rad/s" if np.isfinite(hi) else f"above {lo:g} rad/s"
        print(f"{band:<22} {int(k.sum()):7d} {np.median(err[k]):16.0f} {np.median(ratio[k & turned]):16.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default=str(BUNDLED_CHECKPOINT))
    parser.add_argument("--data", default="data/quickstart.zarr")
    parser.add_argument("--external", default=None, help="a store of benchmarks/external_meshes.py")
    args = parser.parse_args()
    store = load_store(args.data)
    kept = evaluate(load_checkpoint(args.checkpoint), store, "test", keep_trajectories=True)["trajectories"]
    valid = kept["truth"]["state_valid"]
    true_w, pred_w = kept["truth"]["angular_velocity"][..., 2], kept["predicted"].angular_velocity[..., 2]
    still = ~store.toppled[np.flatnonzero(store.split == 2)].astype(bool)
    yaw = lambda w: np.where(valid, w, 0.0)[:, :-1].sum(axis=1) / store.rate_hz  # noqa: E731
    table(f"{args.data} test split", true_w[still, 0], yaw(true_w)[still], yaw(pred_w)[still])
    if args.external:
        ext, predictor, bodies = load_store(args.external), load_predictor(args.checkpoint), {}
        rows = []
        for i in np.flatnonzero(~ext.toppled.astype(bool)):
            f = ext.frames(i)
            w, path = ext.angular_velocity[f], str(ext.source[ext.shape_id[i]])
            body = bodies.setdefault(path, prepare_body(path))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", PredictionWarning)
                p = predictor.predict(body, lin_vel=ext.linear_velocity[f.start], ang_vel=w[0],
                                      orientation_xyzw=ext.orientation_xyzw[f][0], seconds=(len(w) - 1) / ext.rate_hz)
            rows.append((w[0, 2], w[:-1, 2].sum() / ext.rate_hz, np.asarray(p["angular_velocity"])[:-1, 2].sum() / ext.rate_hz))
        a = np.array(rows)
        table(f"{args.external}", a[:, 0], a[:, 1], a[:, 2])


if __name__ == "__main__":
    main()
