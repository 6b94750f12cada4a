"""Is there signal in what the contact prior misses? Teacher-forced one-step residuals (truth - prior) of the
non-toppling pushes while sliding (> 0.1 m/s), first 20 steps: boosted trees on (velocities, rotation since
step 0, step index, fit-topple's 32 shape features), trained on the training split, against the network.
Also: the first three steps' vertical-velocity and tilt-spin changes predicted from the step-0 state alone.
Needs scikit-learn.

    python benchmarks/studies/residual_learnability.py runs/t1/speakers.zarr runs/t1/abs15/best.ckpt
"""
import sys
from pathlib import Path

import numpy as np
from sklearn.ensemble import HistGradientBoostingRegressor

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from priors import prior_only_model  # noqa: E402
from residual_rows import residual_rows  # noqa: E402

from physdyn.data.store import load_store  # noqa: E402
from physdyn.eval.baselines import load_checkpoint  # noqa: E402
from physdyn.models.topple_classifier import store_features  # noqa: E402

s = load_store(sys.argv[1])
prior = prior_only_model("contact", s)
trees = lambda: HistGradientBoostingRegressor(max_iter=300, learning_rate=0.05, loss="absolute_error", random_state=0)  # noqa: E731


def rows(split, model=None):
    return residual_rows(s, prior, split, model)


xtr, ytr, _ = rows("train")
xte, yte, mte = rows("test", load_checkpoint(sys.argv[2]))
print("sum of |one-step error| on the test split: the prior's, boosted trees' on top of it, the network's")
for j, n in enumerate(["dv_x", "dv_y", "dv_z", "dw_x", "dw_y", "dw_z"]):
    p = trees().fit(xtr, ytr[:, j]).predict(xte)
    print(f"  {n}: prior {np.abs(yte[:, j]).sum():8.1f}  trees {np.abs(yte[:, j] - p).sum():8.1f}  network {np.abs(yte[:, j] - mte[:, j]).sum():8.1f}")


def first_steps(split):
    sims = np.flatnonzero((s.split == {"train": 0, "test": 2}[split]) & ~s.toppled.astype(bool))
    f0 = s.start[sims]
    x = np.c_[store_features(s, sims, 256, 0.25), s.linear_velocity[f0], s.angular_velocity[f0]]
    return x, {f"{name} step {k}": arr[f0 + k + 1, c] - arr[f0 + k, c]
               for k in range(3) for name, arr, c in (("dv_z", s.linear_velocity, 2), ("dw_x", s.angular_velocity, 0))}


xtr, ytr = first_steps("train")
xte, yte = first_steps("test")
print("from the step-0 state alone (a roll-out's knowledge): sum |change| (the error of predicting none) and trees' error")
for k in ytr:
    p = trees().fit(xtr, ytr[k]).predict(xte)
    print(f"  {k}: {np.abs(yte[k]).sum():8.1f}  trees {np.abs(p - yte[k]).sum():8.1f}")
