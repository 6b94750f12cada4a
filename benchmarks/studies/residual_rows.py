"""The rows residual_learnability.py and residual_mlp.py fit: teacher-forced one-step residuals (truth - prior)
of a split's non-toppling pushes while sliding (> 0.1 m/s), first 20 steps.

X: v (3), w (3), rotation since step 0 (4), step index (1), fit-topple's 32 shape features; Y: the residuals
of [dv, dw]; M (with a model): the model's own changes minus the prior's, on the same rows."""
import numpy as np

from physdyn.data.windows import relative_rotation
from physdyn.eval.evaluate import gather_truth, predict_single_steps, select_sequences
from physdyn.models.topple_classifier import store_features


def residual_rows(store, prior, split, model=None):
    sims = select_sequences(store, split)
    sims = sims[~store.toppled[sims].astype(bool)]
    truth = gather_truth(store, sims)
    pr = predict_single_steps(prior, store, sims, truth)
    md = predict_single_steps(model, store, sims, truth) if model is not None else None
    shape = store_features(store, sims, 256, 0.25)
    B, S = truth["valid"].shape
    rel = relative_rotation(truth["orientation_xyzw"][:, 0], truth["orientation_xyzw"][:, :S])
    changes = lambda d, t: np.c_[d["delta_linear_velocity"][:, t], d["delta_angular_velocity"][:, t]]  # noqa: E731
    X, Y, M = [], [], []
    for t in range(min(S, 20)):
        ok = truth["valid"][:, t] & (np.linalg.norm(truth["linear_velocity"][:, t, :2], axis=1) > 0.1)
        X.append(np.c_[truth["linear_velocity"][:, t], truth["angular_velocity"][:, t], rel[:, t], np.full(B, t), shape][ok])
        Y.append((changes(truth, t) - changes(pr, t))[ok])
        if md is not None:
            M.append((changes(md, t) - changes(pr, t))[ok])
    return np.concatenate(X), np.concatenate(Y), (np.concatenate(M) if M else None)
