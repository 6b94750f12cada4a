"""Can a plain MLP learn what the contact prior misses, from the state alone? The rows of
residual_learnability.py (teacher-forced one-step residuals truth - prior of the non-toppling pushes while
sliding, first 20 steps), fitted by an MLP (3 x 256, L1 loss, standardised inputs and targets, best of 6,000
steps on the validation split) with and without fit-topple's 32 shape features, against boosted trees.
Needs scikit-learn.

    python benchmarks/studies/residual_mlp.py runs/t1/speakers.zarr
"""
import sys
from pathlib import Path

import numpy as np
import torch
from sklearn.ensemble import HistGradientBoostingRegressor

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from priors import prior_only_model  # noqa: E402
from residual_rows import residual_rows  # noqa: E402

from physdyn.data.store import load_store  # noqa: E402

s = load_store(sys.argv[1])
prior = prior_only_model("contact", s)
NAMES = ["dv_x", "dv_y", "dv_z", "dw_x", "dw_y", "dw_z"]


def rows(split):
    return residual_rows(s, prior, split)[:2]


def mlp(xtr, ytr, xva, yva, xte, hidden=256, steps=6000):
    torch.manual_seed(0)
    mu, sd, ys = xtr.mean(0), xtr.std(0) + 1e-8, ytr.std(0) + 1e-8
    f = lambda a: torch.tensor((a - mu) / sd, dtype=torch.float32)  # noqa: E731
    xt, yt, xv, yv = f(xtr), torch.tensor(ytr / ys, dtype=torch.float32), f(xva), torch.tensor(yva / ys, dtype=torch.float32)
    layers = [torch.nn.Linear(xt.shape[1], hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, hidden), torch.nn.ReLU(),
              torch.nn.Linear(hidden, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, yt.shape[1])]
    net = torch.nn.Sequential(*layers)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=0.0)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    best, kept = np.inf, None
    for i in range(steps):
        idx = torch.randint(0, len(xt), (256,))
        loss = (net(xt[idx]) - yt[idx]).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        schedule.step()
        if i % 250 == 0:
            with torch.no_grad():
                v = float((net(xv) - yv).abs().mean())
            if v < best:
                best, kept = v, {k: t.clone() for k, t in net.state_dict().items()}
    net.load_state_dict(kept)
    with torch.no_grad():
        return net(f(xte)).numpy() * ys


xtr, ytr = rows("train")
xva, yva = rows("val")
xte, yte = rows("test")
print("sum of |one-step error| on the test split: the prior's, then with boosted trees / an MLP on top of it")
for label, cols in (("state and shape features", slice(None)), ("state only (v, w, rotation since step 0, step)", slice(0, 11))):
    net = mlp(xtr[:, cols], ytr, xva[:, cols], yva, xte[:, cols])
    print(f"[{label}]")
    for j, n in enumerate(NAMES):
        trees = HistGradientBoostingRegressor(max_iter=300, learning_rate=0.05, loss="absolute_error", random_state=0)
        tr = trees.fit(xtr[:, cols], ytr[:, j]).predict(xte[:, cols])
        print(f"  {n}: prior {np.abs(yte[:, j]).sum():8.1f}  trees {np.abs(yte[:, j] - tr).sum():8.1f}  mlp {np.abs(yte[:, j] - net[:, j]).sum():8.1f}")
