"""Will a push topple the object, from step-0 features of a `hull_surface` cloud: fit-topple's features
(physdyn/models/topple_classifier.py, no simulation) into a small MLP instead of the logistic regression.
docs/ablations.md, "The prior is the model on new meshes" (eleventh session).

    python benchmarks/studies/topple_mlp_hull.py data/quickstart_hull_large.zarr

Prints validation accuracy every 10 epochs for two widths (training split to fit, validation to report; the
majority answer and `physdyn fit-topple`'s logistic regression for comparison come from
`physdyn fit-topple --checkpoint CKPT --data STORE --out OUT`).
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from physdyn.data.store import load_store
from physdyn.models.topple_classifier import store_features


def main(path: str) -> None:
    torch.set_num_threads(1)
    store = load_store(path)
    train, val = np.flatnonzero(store.split == 0), np.flatnonzero(store.split == 1)
    xt, xv = store_features(store, train, None, 0.25), store_features(store, val, None, 0.25)
    yt, yv = store.toppled[train].astype(np.float32), store.toppled[val].astype(bool)
    lo, hi = np.percentile(xt, 1, axis=0), np.percentile(xt, 99, axis=0)
    clip = lambda x: np.clip(x, lo, hi)  # noqa: E731
    mu, sd = clip(xt).mean(0), clip(xt).std(0) + 1e-9
    Xt = torch.tensor((clip(xt) - mu) / sd, dtype=torch.float32)
    Xv = torch.tensor((clip(xv) - mu) / sd, dtype=torch.float32)
    Yt = torch.tensor(yt)
    print(f"{len(train)} training, {len(val)} validation sequences; majority on validation {max(yv.mean(), 1 - yv.mean()):.3f}")
    for hidden in (64, 128):
        torch.manual_seed(0)
        net = torch.nn.Sequential(torch.nn.Linear(Xt.shape[1], hidden), torch.nn.SiLU(), torch.nn.Linear(hidden, hidden),
                                  torch.nn.SiLU(), torch.nn.Linear(hidden, 1))
        opt = torch.optim.AdamW(net.parameters(), 3e-3, weight_decay=1e-4)
        for epoch in range(60):
            for b in torch.randperm(len(Xt)).split(256):
                loss = torch.nn.functional.binary_cross_entropy_with_logits(net(Xt[b]).squeeze(-1), Yt[b])
                opt.zero_grad()
                loss.backward()
                opt.step()
            if epoch % 10 == 9:
                with torch.no_grad():
                    val_acc = float(((net(Xv).squeeze(-1) > 0).numpy() == yv).mean())
                    train_acc = float(((net(Xt).squeeze(-1) > 0).numpy() == yt.astype(bool)).mean())
                print(f"width {hidden}, epoch {epoch + 1}: training {train_acc:.3f}, validation {val_acc:.3f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
