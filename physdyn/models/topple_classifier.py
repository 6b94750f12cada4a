"""Will it topple? A classifier of the whole sequence from what the model sees at step 0.

Measured (docs/research/topple-from-cloud.md): the per-step topple head over a roll-out misses most topples,
because roll-outs corrected from the contact prior hardly tilt and the head learns from the label of the
next step; yet whether a push topples the object is nearly decided at step 0 (re-simulating perturbed
pushes flips about 1 % of outcomes). So the sequence is classified from physics-shaped features of the
point cloud in its step-0 orientation and the step-0 velocities:

- the footprint (cloud points within 5 mm of the lowest one): its convex hull's area, the distance from the
  centre of mass's ground projection to its edge along the travel, against it, along the direction the
  top tips (horizontal spin), and to the nearest edge;
- the centre-of-mass height h, the energy to tip over each of those edges g(sqrt(h^2 + e^2) - h), and
  the kinetic energies (linear, rotational, and of the tilt about the tipping edge) against them;
- extents, radius of gyration and inertia per unit mass estimated from the cloud (0.8 x its second
  moments, as the contact prior does: the model never sees the mass properties).

A logistic regression on the standardised features (fitted by Newton's method with a small ridge), its
threshold chosen on the validation split and folded into the bias, so a probability >= 0.5 means
"topples". Per step, the probability of having toppled by step t is P(topples) x F(t), F the share of
the training split's toppling sequences that have toppled by step t.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from physdyn.errors import PhysdynError

FOOTPRINT_DEPTH = 0.005  # m: cloud points this close to the lowest one form the footprint
GRAVITY = 9.81
INERTIA_SHAPE_FACTOR = 0.8  # a solid's second moments are ~0.8 of its surface points' (the contact prior's value)
FEATURE_NAMES = (
    "speed_xy", "v_z", "w_xy", "w_z", "w_tip_along_travel", "h_com", "foot_area", "foot_radius",
    "edge_min", "edge_travel", "edge_back", "edge_tip", "extent_x", "extent_y", "extent_z", "gyration",
    "inertia_xx", "inertia_yy", "inertia_zz", "h_over_edge_min", "h_over_edge_travel", "h_over_edge_tip",
    "tip_energy_travel", "tip_energy_tip", "tip_energy_min", "kinetic_linear", "kinetic_rotation",
    "kinetic_tilt", "tilt_ratio", "log_tilt_ratio", "travel_ratio", "friction_lever",
)
# With ``physics``: a 1 s PyBullet roll-out of the cloud's own hull (physdyn/sim/cloud_body.py), its largest
# tilt (deg) within 0.25, 0.5 and 1 s, and whether that passed the 45 degree rule.
PHYSICS_FEATURE_NAMES = ("sim_tilt_0.25s", "sim_tilt_0.5s", "sim_tilt_1s", "sim_toppled_1s")


def _rays_to_hull(equations: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance from the origin to each row's hull boundary along its unit direction (2D): equations
    (n, E, 3) (rows padded with zeros, which face nowhere), directions (n, 2) -> (n,); 0 where no edge
    faces the direction (no hull: a line or point contact)."""
    along = np.einsum("nk,nek->ne", directions, equations[..., :2])
    ok = along > 1e-12
    distance = np.where(ok, -equations[..., 2] / np.where(ok, along, 1.0), np.inf).min(axis=1)
    return np.where(ok.any(axis=1), distance, 0.0)


def _units(x: np.ndarray) -> np.ndarray:
    """Rows of x (n, 2) scaled to unit length; (1, 0) for a row of (near) zero length."""
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return np.where(n > 1e-9, x / np.where(n > 1e-9, n, 1.0), np.array([1.0, 0.0]))


def _cloud_features(P: np.ndarray) -> dict[str, Any]:
    """What the features need of one cloud alone, whatever the push: height, footprint hull, moments."""

    z = P[:, 2]
    foot = P[z <= z.min() + FOOTPRINT_DEPTH, :2]
    hull = None
    if len(foot) >= 3:
        try:
            hull = ConvexHull(foot, qhull_options="QJ")
        except QhullError:  # collinear points: a line contact, no area
            hull = None
    if hull is not None:
        eq, area, edge_min, corners = hull.equations, float(hull.volume), float((-hull.equations[:, 2]).min()), foot[hull.vertices]
    else:
        eq, area, edge_min, corners = None, 0.0, 0.0, foot
    second = P.T @ P / len(P)
    return {"h": -float(z.min()), "eq": eq, "area": area, "edge_min": edge_min,
            "radius": float(np.linalg.norm(corners, axis=1).max()) if len(corners) else 0.0,
            "extent": P.max(axis=0) - P.min(axis=0), "second": second,
            "inertia": INERTIA_SHAPE_FACTOR * (np.trace(second) * np.eye(3) - second)}  # per unit mass


def topple_features(points: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray,
                    friction: float = 0.25) -> np.ndarray:
    """points (B, N, 3): the body's cloud in its step-0 world orientation, centre of mass at the origin;
    velocities (B, 3) at step 0, world frame -> (B, len(FEATURE_NAMES)) float64. A cloud repeated in the
    batch (one mesh pushed many times) is measured once, and its pushes are taken together."""
    points = np.asarray(points, np.float64)
    v0 = np.asarray(linear_velocity, np.float64).reshape(-1, 3)
    w0 = np.asarray(angular_velocity, np.float64).reshape(-1, 3)
    if not len(points):
        return np.empty((0, len(FEATURE_NAMES)))
    groups: dict[bytes, int] = {}
    which = np.array([groups.setdefault(P.tobytes(), len(groups)) for P in points], dtype=np.int64)
    firsts = np.unique(which, return_index=True)[1]
    clouds = [_cloud_features(points[i]) for i in firsts]
    widest = max([0 if c["eq"] is None else len(c["eq"]) for c in clouds] + [1])
    hulls = np.zeros((len(clouds), widest, 3))
    for g, c in enumerate(clouds):
        if c["eq"] is not None:
            hulls[g, : len(c["eq"])] = c["eq"]
    per_cloud = lambda key: np.array([c[key] for c in clouds], np.float64)[which]  # noqa: E731
    h, edge_min, area, radius = per_cloud("h"), per_cloud("edge_min"), per_cloud("area"), per_cloud("radius")
    extent, second, inertia = per_cloud("extent"), per_cloud("second"), per_cloud("inertia")
    eq = hulls[which]
    vxy, wxy = v0[:, :2], w0[:, :2]
    travel = _units(vxy)
    tipping = np.stack([wxy[:, 1], -wxy[:, 0]], axis=1)
    tip = _units(tipping)  # where the top goes under the horizontal spin
    e_travel, e_back, e_tip = _rays_to_hull(eq, travel), _rays_to_hull(eq, -travel), _rays_to_hull(eq, tip)
    tip_energy = lambda e: GRAVITY * (np.sqrt(h * h + e * e) - h)  # noqa: E731
    w_xy = np.linalg.norm(wxy, axis=1)
    spinning = w_xy > 1e-9
    axis = np.where(spinning[:, None], np.concatenate([wxy, np.zeros((len(w0), 1))], axis=1)
                    / np.where(spinning, w_xy, 1.0)[:, None], np.array([1.0, 0.0, 0.0]))
    tilt_inertia = np.einsum("ni,nij,nj->n", axis, inertia, axis) + h * h + e_tip * e_tip  # about the tipping edge
    kinetic_tilt = 0.5 * tilt_inertia * w_xy ** 2
    kinetic_linear = 0.5 * (v0 * v0).sum(axis=1)
    kinetic_rotation = 0.5 * np.einsum("ni,nij,nj->n", w0, inertia, w0)
    e_tip_energy, e_travel_energy = tip_energy(e_tip), tip_energy(e_travel)
    return np.stack([
        np.linalg.norm(vxy, axis=1), v0[:, 2], w_xy, w0[:, 2], (tipping * travel).sum(axis=1), h, area, radius,
        edge_min, e_travel, e_back, e_tip, extent[:, 0], extent[:, 1], extent[:, 2],
        np.sqrt(np.trace(second, axis1=1, axis2=2)), inertia[:, 0, 0], inertia[:, 1, 1], inertia[:, 2, 2],
        h / np.maximum(edge_min, 1e-4), h / np.maximum(e_travel, 1e-4), h / np.maximum(e_tip, 1e-4),
        e_travel_energy, e_tip_energy, tip_energy(edge_min), kinetic_linear, kinetic_rotation, kinetic_tilt,
        kinetic_tilt / np.maximum(e_tip_energy, 1e-6), np.log(kinetic_tilt + 1e-6) - np.log(e_tip_energy + 1e-6),
        (kinetic_linear + kinetic_rotation) / np.maximum(e_travel_energy, 1e-6), friction * h - e_travel,
    ], axis=1)




def physics_features(points: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray,
                     friction: float = 0.25, inertia: np.ndarray | None = None) -> np.ndarray:
    """points (B, N, 3) in the step-0 world orientation, velocities (B, 3) -> (B, len(PHYSICS_FEATURE_NAMES)):
    the largest tilts of a short PyBullet roll-out of each cloud's hull (``CloudSimulator.max_tilt``).
    inertia: (B, 3, 3) each body's own I / m in world axes where known (a store's shapes, a mesh), else
    the hull's: with it, 0.958 against 0.928 on the external validation set from the roll-out alone."""
    from physdyn.sim.cloud_body import shared_simulator  # PyBullet: only for classifiers fitted with it

    with shared_simulator() as simulator:
        tilt = simulator.max_tilt(points, linear_velocity, angular_velocity, friction, inertia)
    return np.concatenate([tilt, (tilt[:, -1:] >= 45.0).astype(np.float64)], axis=1)


def all_features(points: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray, friction: float,
                 physics: bool, inertia: np.ndarray | None = None) -> np.ndarray:
    """``topple_features``, followed by ``physics_features`` when ``physics``."""
    x = topple_features(points, linear_velocity, angular_velocity, friction)
    if physics and len(x):
        x = np.concatenate([x, physics_features(points, linear_velocity, angular_velocity, friction, inertia)], axis=1)
    return x


@dataclass
class ToppleClassifier:
    """Logistic regression over ``topple_features``; ``timing`` (S,) is F(t) for t = 0..S-1 steps."""

    mean: np.ndarray
    std: np.ndarray
    weights: np.ndarray
    bias: float
    timing: np.ndarray
    friction: float
    rate_hz: float
    num_points: int | None = None  # the cloud it was fitted on (None: all the store's points)
    # Each feature is clipped to [low, high] (the training split's 1st and 99th percentiles) before it is
    # standardised: the ratio features have tails of 1e6 that otherwise dominate mean, std and the fit.
    # None: no clipping (a classifier's file without the bounds).
    low: np.ndarray | None = None
    high: np.ndarray | None = None
    # Whether it also reads a short simulation of the cloud's hull (PHYSICS_FEATURE_NAMES; `fit-topple
    # --physics`): more accurate, and a few milliseconds of PyBullet per push (docs/model-card.md, Toppling).
    physics: bool = False

    @property
    def feature_names(self) -> tuple[str, ...]:
        return FEATURE_NAMES + (PHYSICS_FEATURE_NAMES if self.physics else ())

    def standardised(self, features: np.ndarray) -> np.ndarray:
        """(B, F) features -> clipped to [low, high] where fitted so, centred and scaled."""
        return standardise(features, self.low, self.high, self.mean, self.std)

    def probability(self, features: np.ndarray) -> np.ndarray:
        """(B, F) -> (B,) probability that the sequence topples (0.5 is the chosen threshold)."""
        z = (self.standardised(features)) @ self.weights + self.bias
        return 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))

    def per_step(self, probability: np.ndarray, steps: int) -> np.ndarray:
        """(B,) -> (B, steps + 1): the probability of having toppled by step t (0 at step 0)."""
        return per_step_probability(self.timing, probability, steps)

    def predict(self, points_world: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray,
                steps: int, inertia: np.ndarray | None = None) -> np.ndarray:
        """(B, steps + 1) per-step probabilities; ``inertia`` (B, 3, 3): the bodies' own I / m in world axes
        for the physics features (fitted with the store's; without it, the hull's)."""
        features = all_features(points_world, linear_velocity, angular_velocity, self.friction, self.physics, inertia)
        return self.per_step(self.probability(features), steps)

    def to_dict(self) -> dict[str, Any]:
        return {"mean": self.mean.tolist(), "std": self.std.tolist(), "weights": self.weights.tolist(),
                "bias": float(self.bias), "timing": self.timing.tolist(), "friction": float(self.friction),
                "rate_hz": float(self.rate_hz), "num_points": self.num_points, "features": list(self.feature_names),
                "low": None if self.low is None else self.low.tolist(),
                "high": None if self.high is None else self.high.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ToppleClassifier":
        features = list(d.get("features", []))
        physics = features == list(FEATURE_NAMES + PHYSICS_FEATURE_NAMES)
        if features != list(FEATURE_NAMES) and not physics:
            raise ValueError("the checkpoint's topple classifier was fitted on other features; refit it with "
                             "`physdyn fit-topple`")
        return cls(np.asarray(d["mean"]), np.asarray(d["std"]), np.asarray(d["weights"]), float(d["bias"]),
                   np.asarray(d["timing"]), float(d["friction"]), float(d["rate_hz"]), d.get("num_points"),
                   None if d.get("low") is None else np.asarray(d["low"]),
                   None if d.get("high") is None else np.asarray(d["high"]), physics)


def per_step_probability(timing: np.ndarray, probability: np.ndarray, steps: int) -> np.ndarray:
    """(B,) P(topples) -> (B, steps + 1): P(topples) x F(t), F = ``timing`` held at its last value."""
    share = timing[np.minimum(np.arange(steps + 1), len(timing) - 1)]
    return np.asarray(probability)[:, None] * share[None, :]


def topple_timing(stores: list[Any]) -> np.ndarray:
    """F(t), t = 0, 1, ...: the share of the stores' toppling training pushes that have toppled by step t."""
    toppled = np.concatenate([s.topple_step[(s.topple_step >= 0) & (s.split == 0)] for s in stores])
    if not len(toppled):
        return np.array([0.0, 1.0])
    timing = np.array([np.mean(toppled <= t) for t in range(int(toppled.max()) + 2)])
    timing[0] = 0.0  # nothing has toppled at the push
    return timing


def logistic_regression(x: np.ndarray, y: np.ndarray, ridge: float = 1e-3, iterations: int = 50) -> tuple[np.ndarray, float]:
    """Newton's method on the mean log-loss + ridge/2 |w|^2 (bias not penalised); x standardised."""
    n, f = x.shape
    a = np.concatenate([x, np.ones((n, 1))], axis=1)
    theta = np.zeros(f + 1)
    penalty = np.full(f + 1, ridge)
    penalty[-1] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(a @ theta, -50, 50)))
        grad = a.T @ (p - y) / n + penalty * theta
        hess = (a * (p * (1 - p))[:, None]).T @ a / n + np.diag(penalty + 1e-9)
        step = np.linalg.solve(hess, grad)
        theta -= step
        if np.abs(step).max() < 1e-8:
            break
    return theta[:-1], float(theta[-1])


def fit_clipped_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1e-4) -> dict[str, Any]:
    """A logistic regression on features clipped to their 1st-99th percentiles and standardised -> the
    ``ToppleClassifier`` fields low, high, mean, std, weights, bias. Without the clipping a few ratios of
    1e6 (a push that barely tilts a shape that barely tips) set the scale of their feature, and on the
    quickstart_shapes store the fit fell to always answering "no" (0.714 on training, 0.885 clipped)."""
    scaling = clipped_scaling(x)
    weights, bias = logistic_regression(standardise(x, **scaling), y, ridge)
    return {**scaling, "weights": weights, "bias": bias}


def clipped_scaling(x: np.ndarray) -> dict[str, np.ndarray]:
    """The clipping range (1st-99th percentiles) and the mean and std of the clipped features (n, F)."""
    low, high = np.percentile(x, 1, axis=0), np.percentile(x, 99, axis=0)
    clipped = np.clip(x, low, high)
    return {"low": low, "high": high, "mean": clipped.mean(axis=0), "std": clipped.std(axis=0) + 1e-9}


def standardise(x: np.ndarray, low: np.ndarray | None, high: np.ndarray | None, mean: np.ndarray,
                std: np.ndarray) -> np.ndarray:
    """Features (n, F) clipped to [low, high] (where given), centred and scaled."""
    x = np.asarray(x, np.float64)
    if low is not None and high is not None:
        x = np.clip(x, low, high)
    return (x - mean) / std


def best_threshold(probability: np.ndarray, label: np.ndarray) -> float:
    """The threshold with the highest accuracy (the middle of the best run of candidates)."""
    candidates = np.unique(np.concatenate([probability, [0.5]]))
    accuracy = np.array([np.mean((probability >= c) == label) for c in candidates])
    best = np.flatnonzero(accuracy == accuracy.max())
    return float(candidates[best[len(best) // 2]])


def store_features(store: Any, sims: np.ndarray, num_points: int | None, friction: float, seed: int = 0,
                   physics: bool = False) -> np.ndarray:
    """``all_features`` of a store's simulations at step 0, from the cloud the model would see."""
    # zarr and trimesh behind it: only fitting reads a store, and a prediction (or a study training a
    # correction on a machine without them) imports this module without it
    from physdyn.data.windows import store_world_inertia, subsample_indices, world_oriented_points

    sims = np.asarray(sims, dtype=np.int64)
    first = store.start[sims]
    points = store.points[store.shape_id[sims]]
    index = subsample_indices(points.shape[1], num_points, np.random.default_rng(seed), len(sims))
    if index is not None:
        points = np.take_along_axis(points, index[..., None], axis=1)
    world = world_oriented_points(points, store.orientation_xyzw[first])
    inertia = store_world_inertia(store, sims, store.orientation_xyzw[first]) if physics else None
    return all_features(world, store.linear_velocity[first], store.angular_velocity[first], friction, physics, inertia)


def fit_topple_classifier(store: Any, num_points: int | None = None, friction: float = 0.25, ridge: float = 1e-4,
                          seed: int = 0, physics: bool = False) -> tuple[ToppleClassifier, dict[str, Any]]:
    """Fit on the store's training split, choose the threshold on its validation split. Returns the
    classifier and a report (accuracies on train and validation, counts). ``num_points``: the cloud size
    (default: all the store's points; 1,024 points classify better than the 256 a CPU model sees)."""

    train, val = np.flatnonzero(store.split == 0), np.flatnonzero(store.split == 1)
    y_train, y_val = store.toppled[train].astype(float), store.toppled[val].astype(bool)
    if y_train.min() == y_train.max() or not len(val):
        raise PhysdynError(f"{store.url}: the topple classifier needs toppling and non-toppling training "
                           "sequences and a validation split")
    x_train = store_features(store, train, num_points, friction, seed, physics)
    clf = ToppleClassifier(**fit_clipped_logistic(x_train, y_train, ridge), timing=np.array([0.0, 1.0]),
                           friction=friction, rate_hz=float(store.rate_hz), num_points=num_points, physics=physics)
    x_val = store_features(store, val, num_points, friction, seed + 1, physics)
    p_val = clf.probability(x_val)
    threshold = best_threshold(p_val, y_val)
    clf.bias -= float(np.log(threshold / (1 - threshold)))  # now 0.5 is the chosen threshold
    clf.timing = topple_timing([store])
    report = {"train_accuracy": float(np.mean((clf.probability(x_train) >= 0.5) == y_train.astype(bool))),
              "val_accuracy": float(np.mean((clf.probability(x_val) >= 0.5) == y_val)),
              "val_majority": float(max(y_val.mean(), 1 - y_val.mean())), "threshold": threshold,
              "train_sequences": int(len(train)), "val_sequences": int(len(val))}
    return clf, report
