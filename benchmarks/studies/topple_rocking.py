"""Does a rocking integration tell toppling better? The rocking block of rocking_block.py (vectorised, the
cloud's inertia estimate, no rebound) run on every push: its own call (peak tilt past the tipping angle),
and its features added to fit-topple's 32 for a logistic regression and boosted trees, fitted on the large
store's training split, thresholds chosen on the quickstart validation split, scored on its test split.
Needs scikit-learn and data/quickstart.zarr, data/quickstart_large.zarr.

    python benchmarks/studies/topple_rocking.py
"""
import numpy as np
from physdyn.data.store import load_store
from physdyn.data.windows import world_oriented_points
from physdyn.geometry.rotations import quat_to_matrix
from physdyn.models.topple_classifier import INERTIA_SHAPE_FACTOR, best_threshold, clipped_scaling, standardise, store_features
g = 9.81; H = 1 / 960
def rock_features(s, sims, mu=0.25, seconds=1.0, true_inertia=True):
    n = len(sims); b = np.zeros(n); h = np.zeros(n); Ip = np.zeros(n); ud = np.zeros(n); om = np.zeros(n); ts = np.zeros(n); Ia = np.zeros(n)
    for j, i in enumerate(sims):
        f = s.frames(i); sh = s.shape_id[i]; q0 = s.orientation_xyzw[f.start]
        P = world_oriented_points(s.points[sh], q0); v0 = s.linear_velocity[f.start]; w0 = s.angular_velocity[f.start]
        wt = np.array([w0[0], w0[1], 0.0]); om[j] = np.linalg.norm(wt)
        a = wt / max(om[j], 1e-9) if om[j] > 1e-9 else np.r_[1.0, 0, 0]
        d = np.array([-a[1], a[0], 0.0]); z = P[:, 2]; foot = P[z < z.min() + 0.005]
        b[j] = max(-np.min(foot @ d), 1e-3); h[j] = -z.min()
        if true_inertia:
            R0 = quat_to_matrix(q0); A = quat_to_matrix(s.inertia_orientation_xyzw[sh])
            Iw = R0 @ A @ np.diag(s.inertia_diag[sh]) @ A.T @ R0.T / float(s.mass[sh])
        else:
            Iw = INERTIA_SHAPE_FACTOR * (np.eye(3) * (P ** 2).sum(1).mean() - P.T @ P / len(P))
        Ia[j] = a @ Iw @ a; Ip[j] = Ia[j] + b[j] ** 2 + h[j] ** 2
        u = v0[:2]; sp = np.linalg.norm(u); ud[j] = (np.r_[u / max(sp, 1e-9), 0] @ d); ts[j] = sp / (mu * g)
    alpha = np.arctan2(b, h); th = np.zeros(n); Om = om.copy(); peak = np.zeros(n); alive = om > 1e-6; top = np.zeros(n, bool); t = 0.0
    for _ in range(int(seconds / H)):
        Hc = b * np.sin(th) + h * np.cos(th)
        acc = -(g / Ip) * (b * np.cos(th) - h * np.sin(th)) - np.where(t < ts, mu * g * ud * Hc / Ip, 0.0)
        Om = np.where(alive, Om + acc * H, 0.0); th = np.where(alive, th + Om * H, th); t += H
        peak = np.maximum(peak, th); top |= alive & (th > alpha); alive &= (th >= 0) & ~top
    nofric = om ** 2 * Ip / (2 * g) / (np.sqrt(b ** 2 + h ** 2) - h)  # energy ratio without friction
    return np.stack([np.minimum(peak / alpha, 1.5), top.astype(float), np.log(np.maximum(nofric, 1e-6)), -ud * ts * h / Ip, alpha], 1)


if __name__ == "__main__":
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression

    large, qs = load_store("data/quickstart_large.zarr"), load_store("data/quickstart.zarr")
    x, r, y = {}, {}, {}
    for tag, st, sp in [("tr", large, 0), ("va", qs, 1), ("te", qs, 2)]:
        sims = np.flatnonzero(st.split == sp)
        x[tag], r[tag], y[tag] = store_features(st, sims, 256, 0.25), rock_features(st, sims, true_inertia=False), st.toppled[sims].astype(bool)
    print(f"the rocking block's own call: test accuracy {np.mean((r['te'][:, 1] > 0.5) == y['te']):.3f} (always no: {1 - y['te'].mean():.3f})")
    for name, f in [("32 features", lambda k: x[k]), ("32 + rocking", lambda k: np.c_[x[k], r[k]])]:
        scaling = clipped_scaling(f("tr"))  # as fit-topple clips and scales its features
        prep = lambda k: standardise(f(k), **scaling)  # noqa: E731
        for fam, m in [("logistic", LogisticRegression(C=100, max_iter=3000)),
                       ("boosted trees", HistGradientBoostingClassifier(max_iter=500, learning_rate=0.05, random_state=0))]:
            m.fit(prep("tr"), y["tr"])
            threshold = best_threshold(m.predict_proba(prep("va"))[:, 1], y["va"])
            acc = np.mean((m.predict_proba(prep("te"))[:, 1] >= threshold) == y["te"])
            print(f"{name:14s} {fam:14s} test accuracy {acc:.3f}")
