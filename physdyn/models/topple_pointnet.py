"""Will it topple? Small PointNets over the step-0 cloud, no simulator (``physdyn fit-topple --pointnet``).

Toppling is nearly decided at step 0, and it needs no precision in the physics: PyBullet with its friction or
its push 10 % off still classifies 0.97-1.00 of the frontier's pushes (docs/research/friction-and-sensitivity.md).
The logistic regression of ``topple_classifier.py`` reads hand-made features and stops near 0.90 on meshes it
never saw; a network that reads the cloud itself reaches 0.95-0.96 once it is trained on thousands of shapes
(docs/research/topple-from-cloud.md).

Each network sees the cloud (``hull_surface`` points, body frame turned to its step-0 orientation) in the
frame of the push's travel (x along the step-0 horizontal velocity, z up), each point's height above the
lowest one, and seven scalars: the step-0 velocity and spin in that frame and I_zz / m about the vertical.
A PointNet (4 -> 64 -> 128 -> width per point by default, max-pooled) and a head of two hidden layers give the logit;
the probability is the mean of the networks' (an ensemble of seeds). Per step, the probability of having
toppled by step t is P(topples) x F(t), as ``ToppleClassifier``'s. Fitted with ``--num-points``, it reads
each cloud thinned to that size, its hull vertices first (``thinned_to``), wherever it runs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch
from scipy.special import expit

from physdyn.geometry.rotations import quat_to_matrix
from physdyn.models.topple_classifier import per_step_probability, topple_timing

KIND = "pointnet"
POINTS_METHOD = "hull_surface"  # the cloud it reads: the hull's vertices keep the edges a body tips over
SCALARS = 7  # step-0 velocity (3) and spin (3) in the travel frame, I_zz / m
# Mirrored across its travel (y -> -y), a push is a push of the mirrored shape with the same outcome: the
# velocity (along, across, up) changes sign as (+, -, +), the spin, an axial vector, as (-, +, -).
MIRROR_SCALARS = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0], dtype=np.float32)
MIN_STEPS = 20  # training steps: the best of 20 validation checks is kept
PUSHES_PER_PASS = 32  # pushes per forward pass at prediction (``_in_passes``; ``OutcomeCorrection.correction``)
# Up to this many pushes the topple PointNet runs on numpy (``numpy_forward``), above it on torch: for one push
# torch's per-layer dispatch is most of the cost (0.30 against 0.14 ms a push), for hundreds its products are
# the cheaper (0.09 against 0.10-0.23 ms; `python benchmarks/frontier.py`, docs/performance.md)
NUMPY_PUSHES = 8
POINT_WIDTHS = (64, 128)  # the per-point layers' widths before the last (of ``width``): the per-push cost
THINNED_KEPT = 256  # thinned clouds a cache keeps, the latest (``thinned_clouds``)
INERTIA_SHAPE_FACTOR = 0.8  # I_zz / m from a bare cloud: 0.8 x its mean squared horizontal radius (the contact prior's)


class ToppleNet(torch.nn.Module):
    """One network: PointNet over (x, y, z, height above the lowest point) in decimetres, joined with the
    standardised scalars; one logit (or ``outputs`` numbers: the outcome correction's PointNet)."""

    def __init__(self, width: int = 256, scalars: int = SCALARS, point_widths: tuple[int, ...] = POINT_WIDTHS,
                 outputs: int = 1):
        super().__init__()
        self.outputs = outputs
        if not point_widths or min(point_widths) < 1:
            raise ValueError(f"point_widths: one or more layer widths of at least 1, got {point_widths}")
        layers: list[torch.nn.Module] = []
        for a, b in zip((4, *point_widths), point_widths):
            layers += [torch.nn.Linear(a, b), torch.nn.ReLU()]
        self.points = torch.nn.Sequential(*layers, torch.nn.Linear(point_widths[-1], width))
        self.head = torch.nn.Sequential(torch.nn.Linear(width + scalars, width), torch.nn.ReLU(),
                                        torch.nn.Linear(width, width), torch.nn.ReLU(), torch.nn.Linear(width, outputs))

    def forward(self, cloud: torch.Tensor, scalars: torch.Tensor) -> torch.Tensor:
        """cloud (B, N, 3) in the travel frame (m), scalars (B, 7) standardised -> (B,) logits, or (B,
        outputs) where it has more than one (the outcome correction's, ``physdyn fit-outcome --pointnet``)."""
        height = cloud[..., 2:3] - cloud[..., 2:3].amin(dim=1, keepdim=True)
        feature = self.points(torch.cat([cloud * 10.0, height * 10.0], dim=-1)).amax(dim=1)
        out = self.head(torch.cat([feature, scalars], dim=-1))
        return out[:, 0] if self.outputs == 1 else out


def _in_passes(net: ToppleNet, cloud: torch.Tensor, scalars: torch.Tensor) -> torch.Tensor:
    """``net``'s outputs ((B,) logits, or (B, outputs)) a few pushes at a time: the per-point layers' activations of PUSHES_PER_PASS
    pushes stay in the CPU's cache, where those of 512 pushes (130 MB) do not: about 0.6x the cost a push
    for 512, the same numbers to float32 rounding (docs/research/fast-cost.md)."""
    if len(cloud) <= PUSHES_PER_PASS:
        return net(cloud, scalars)
    return torch.cat([net(cloud[i : i + PUSHES_PER_PASS], scalars[i : i + PUSHES_PER_PASS])
                      for i in range(0, len(cloud), PUSHES_PER_PASS)])


def numpy_layers(net: ToppleNet) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[tuple[np.ndarray, np.ndarray]]]:
    """``net``'s per-point and head layers as float32 (weight transposed, bias) pairs, for ``numpy_forward``."""
    def pairs(seq: torch.nn.Sequential) -> list[tuple[np.ndarray, np.ndarray]]:
        return [(np.ascontiguousarray(m.weight.detach().numpy().T, dtype=np.float32),
                 np.asarray(m.bias.detach().numpy(), dtype=np.float32)) for m in seq if isinstance(m, torch.nn.Linear)]
    return pairs(net.points), pairs(net.head)


def numpy_forward(layers: tuple[list, list], cloud: np.ndarray, scalars: np.ndarray) -> np.ndarray:
    """``ToppleNet.forward`` on numpy, float32, ``layers`` from ``numpy_layers``: (B, N, 3), (B, S) -> (B,
    outputs), (B, 1) for one output (``ToppleNet`` gives (B,)). The same numbers to float32 rounding (a few 1e-7 of the outputs); for a small network torch's
    per-call overhead is most of one push's cost (0.46 against 0.07 ms for ``fast``'s outcome correction)."""
    points, head = layers
    cloud = np.asarray(cloud, dtype=np.float32)
    height = cloud[..., 2:3] - cloud[..., 2:3].min(axis=1, keepdims=True)
    h = np.concatenate([cloud * np.float32(10.0), height * np.float32(10.0)], axis=-1)
    for i, (weight, bias) in enumerate(points):
        h = h @ weight + bias
        if i + 1 < len(points):
            np.maximum(h, 0.0, out=h)
    h = np.concatenate([h.max(axis=1), np.asarray(scalars, dtype=np.float32)], axis=-1)
    for i, (weight, bias) in enumerate(head):
        h = h @ weight + bias
        if i + 1 < len(head):
            np.maximum(h, 0.0, out=h)
    return h


def thinned_clouds(points_body: np.ndarray, count: int, hull_counts: Any = None,
                   kept: dict[tuple, np.ndarray] | None = None) -> np.ndarray:
    """(B, count, 3) float32: each body-frame cloud of (B, N, 3) thinned by ``thin_hull_surface``, each distinct
    cloud once: a batch of one object's pushes repeats one cloud hundreds of times. ``kept``: thinned clouds by
    (count, cloud, hull count), read and filled (the latest THINNED_KEPT; a predictor's
    ``physdyn.pipeline.stages.BodyCache``). As given where ``count`` is 0 or not below N. ``hull_counts`` (B,):
    how many of each cloud's first points are its mesh's hull vertices, where the caller knows (a prediction:
    ``PreparedBody.hull_count``); then no qhull runs for it (``thin_hull_surface``)."""
    points_body = np.asarray(points_body, dtype=np.float32)
    if not count or points_body.shape[1] <= count:
        return points_body
    from physdyn.geometry.sampling import thin_hull_surface

    kept = {} if kept is None else kept
    out = np.empty((len(points_body), count, 3), dtype=np.float32)
    for b, cloud in enumerate(points_body):
        hull_count = None if hull_counts is None else int(hull_counts[b])
        key = (count, cloud.tobytes(), hull_count)
        if key not in kept:
            if len(kept) >= THINNED_KEPT:
                kept.pop(next(iter(kept)))  # the oldest
            kept[key] = thin_hull_surface(cloud, count, hull_count)
        out[b] = kept[key]
    return out


def travel_turn(linear_velocity: np.ndarray) -> np.ndarray:
    """(B, 3, 3) world -> travel frame: x along the step-0 horizontal velocity (world x where there is
    none), y across it, z up."""
    d = np.asarray(linear_velocity, dtype=np.float64)[:, :2]
    n = np.linalg.norm(d, axis=1, keepdims=True)
    u = np.where(n > 1e-9, d / np.maximum(n, 1e-12), np.array([1.0, 0.0]))
    turn = np.zeros((len(d), 3, 3))
    turn[:, 0, :2], turn[:, 1, 0], turn[:, 1, 1], turn[:, 2, 2] = u, -u[:, 1], u[:, 0], 1.0
    return turn


def travel_scalars(linear_velocity: np.ndarray, angular_velocity: np.ndarray, spin_inertia: np.ndarray,
                   turn: np.ndarray) -> np.ndarray:
    """(B, 7) raw scalars: velocity and spin in the travel frame ``turn`` (B, 3, 3), I_zz / m."""
    v = np.einsum("bij,bj->bi", turn, np.asarray(linear_velocity, dtype=np.float64))
    w = np.einsum("bij,bj->bi", turn, np.asarray(angular_velocity, dtype=np.float64))
    return np.concatenate([v, w, np.asarray(spin_inertia, dtype=np.float64).reshape(-1, 1)], axis=1)


def cloud_spin_inertia(points_world: np.ndarray) -> np.ndarray:
    """(B,) I_zz / m estimated from a bare cloud (B, N, 3) centred at the centre of mass."""
    return INERTIA_SHAPE_FACTOR * (np.asarray(points_world)[..., :2] ** 2).sum(-1).mean(-1)


@dataclass
class PointNetToppleClassifier:
    """An ensemble of ``ToppleNet`` state dicts with the scalars' standardisation; ``timing`` (S,) is F(t)."""

    networks: list[dict[str, torch.Tensor]]
    scalars_mean: np.ndarray
    scalars_std: np.ndarray
    timing: np.ndarray
    rate_hz: float
    width: int = 256
    num_points: int = 256
    points_method: str = POINTS_METHOD
    point_widths: tuple[int, ...] = POINT_WIDTHS
    thinned_from: int = 0  # > 0: it reads hull_surface clouds of this size thinned to num_points (``thinned_to``)
    physics: bool = False  # it simulates nothing (Pipeline.without_simulator keeps it)
    _modules: list[ToppleNet] = field(default_factory=list, repr=False, compare=False)
    _layers: list[tuple[list, list]] = field(default_factory=list, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._modules = []
        for state in self.networks:
            net = ToppleNet(self.width, point_widths=tuple(self.point_widths))
            net.load_state_dict(state)
            self._modules.append(net.eval())
        self._layers = [numpy_layers(net) for net in self._modules]  # the networks are fixed once built

    def probability(self, points_world: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray,
                    spin_inertia: np.ndarray) -> np.ndarray:
        """(B,) probability that each push topples: clouds (B, N, 3) turned to step 0, centred at the centre
        of mass; step-0 velocities (B, 3); I_zz / m (B,)."""
        turn = travel_turn(linear_velocity)
        travelled = np.einsum("bij,bnj->bni", turn, np.asarray(points_world, dtype=np.float64))
        standard = (travel_scalars(linear_velocity, angular_velocity, spin_inertia, turn) - self.scalars_mean) / self.scalars_std
        if len(travelled) <= NUMPY_PUSHES:  # the same network on numpy (float32 rounding apart)
            return np.mean([expit(numpy_forward(layers, travelled, standard)[:, 0]) for layers in self._layers],
                           axis=0).astype(np.float64)
        cloud = torch.tensor(travelled, dtype=torch.float32)
        scalars = torch.tensor(standard, dtype=torch.float32)
        with torch.no_grad():
            return np.mean([torch.sigmoid(_in_passes(net, cloud, scalars)).numpy() for net in self._modules],
                           axis=0).astype(np.float64)

    @property
    def thinned_to(self) -> int:
        """The size it thins the clouds it is given to (0: it reads them as they are). Fitted on thinned
        clouds (``fit-topple --pointnet --num-points``), it is given ``thinned_from``-point ones and thins them
        by ``thin_hull_surface`` before a push turns them (from the body frame's lowest hull vertex, as its
        training clouds were): ``thinned_clouds``."""
        return self.num_points if self.thinned_from else 0

    def per_step(self, probability: np.ndarray, steps: int) -> np.ndarray:
        """(B,) -> (B, steps + 1): the probability of having toppled by step t (0 at step 0)."""
        return per_step_probability(self.timing, probability, steps)

    def predict(self, points_world: np.ndarray, linear_velocity: np.ndarray, angular_velocity: np.ndarray,
                steps: int, inertia: np.ndarray | None = None) -> np.ndarray:
        """(B, steps + 1) per-step probabilities; ``inertia`` (B, 3, 3): the bodies' I / m in world axes
        (without it, I_zz / m is estimated from the cloud)."""
        spin = cloud_spin_inertia(points_world) if inertia is None else np.asarray(inertia)[:, 2, 2]
        return self.per_step(self.probability(points_world, linear_velocity, angular_velocity, spin), steps)

    def to_dict(self) -> dict[str, Any]:
        # tensors, lists and numbers only: checkpoints are read without running code (docs/security.md)
        return {"kind": KIND, "networks": [{k: t.detach().cpu().clone() for k, t in s.items()} for s in self.networks],
                "scalars_mean": self.scalars_mean.tolist(), "scalars_std": self.scalars_std.tolist(),
                "timing": self.timing.tolist(), "rate_hz": float(self.rate_hz), "width": int(self.width),
                "num_points": int(self.num_points), "points_method": self.points_method,
                "point_widths": [int(w) for w in self.point_widths], "thinned_from": int(self.thinned_from)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "PointNetToppleClassifier":
        return cls([dict(s) for s in d["networks"]], np.asarray(d["scalars_mean"]), np.asarray(d["scalars_std"]),
                   np.asarray(d["timing"]), float(d["rate_hz"]), int(d["width"]), int(d["num_points"]),
                   str(d.get("points_method", POINTS_METHOD)), tuple(int(w) for w in d.get("point_widths", POINT_WIDTHS)),
                   int(d.get("thinned_from", 0)))


@dataclass
class TrainingSet:
    """Every push of some stores as the networks read it: clouds (S, N, 3) body frame; per push its shape
    (P,) into clouds, step-0 rotation into the travel frame (P, 3, 3), raw scalars (P, 7), label (P,) 1 if
    it topples, split (P,) 0 train, 1 validation, 2 test."""

    clouds: np.ndarray
    shape: np.ndarray
    turn: np.ndarray
    scalars: np.ndarray
    label: np.ndarray
    split: np.ndarray


def train_network(data: TrainingSet, train: np.ndarray, val: np.ndarray, steps: int = 10000, batch: int = 1024,
                  width: int = 256, seed: int = 0, mirror: bool = True, device: str = "cpu",
                  minutes: float | None = None, progress: Callable[[int, float], None] | None = None,
                  point_widths: tuple[int, ...] = POINT_WIDTHS) -> dict[str, Any]:
    """One network on the pushes ``train`` (indices into ``data``), its checkpoint the best of 20 checks of
    accuracy on ``val``: AdamW (lr 1e-3, weight decay 1e-4) on a one-cycle schedule, binary cross-entropy,
    half of each batch mirrored across its travel (``mirror``). ``minutes``: stop then, keeping the best so
    far. Returns {"state_dict", "scalars_mean", "scalars_std", "val_accuracy", "steps"}."""
    if steps < MIN_STEPS:
        raise ValueError(f"steps must be at least {MIN_STEPS} (the network is checked 20 times), got {steps}")
    dev = torch.device(device)
    torch.manual_seed(seed)
    mu, sd = data.scalars[train].mean(0), data.scalars[train].std(0) + 1e-9
    clouds = torch.tensor(data.clouds, dtype=torch.float32, device=dev)
    turn = torch.tensor(data.turn, dtype=torch.float32, device=dev)
    shape = torch.tensor(data.shape, device=dev)
    label = torch.tensor(data.label, dtype=torch.float32, device=dev)
    scalars = torch.tensor((data.scalars - mu) / sd, dtype=torch.float32, device=dev)
    scalars_m = torch.tensor((data.scalars * MIRROR_SCALARS - mu) / sd, dtype=torch.float32, device=dev)
    flip_y = torch.tensor([1.0, -1.0, 1.0], device=dev)

    def cloud_of(idx: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bij,bnj->bni", turn[idx], clouds[shape[idx]])

    def accuracy(net: ToppleNet, idx: np.ndarray) -> float:
        net.eval()
        with torch.no_grad():
            logits = torch.cat([net(cloud_of(part), scalars[part]) for part in torch.tensor(idx, device=dev).split(8192)])
        net.train()
        return float(((logits > 0).float() == label[torch.tensor(idx, device=dev)]).float().mean())

    net = ToppleNet(width, point_widths=tuple(point_widths)).to(dev)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=1e-3, total_steps=steps, pct_start=max(0.05, 2.0 / steps))
    train_t = torch.tensor(train, device=dev)
    best, best_state, started, done = -1.0, None, time.time(), steps
    for step in range(steps):
        idx = train_t[torch.randint(len(train_t), (batch,), device=dev)]
        x, cloud = scalars[idx], cloud_of(idx)
        if mirror:
            m = torch.rand(batch, device=dev) < 0.5
            x = torch.where(m[:, None], scalars_m[idx], x)
            cloud = torch.where(m[:, None, None], cloud * flip_y, cloud)
        loss = torch.nn.functional.binary_cross_entropy_with_logits(net(cloud, x), label[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % max(1, steps // 20) == 0 or step + 1 == steps:
            acc = accuracy(net, val)
            if acc > best:
                best, best_state = acc, {k: t.detach().cpu().clone() for k, t in net.state_dict().items()}
            if progress is not None:
                progress(step + 1, acc)
            if minutes is not None and time.time() - started > 60 * minutes:
                done = step + 1
                break
    return {"state_dict": best_state, "scalars_mean": mu, "scalars_std": sd, "val_accuracy": best, "steps": done}


def store_training_set(stores: list[Any]) -> TrainingSet:
    """``TrainingSet`` of every push of ``stores`` (each store's own split; their clouds must be of one size)."""
    from physdyn.data.windows import store_spin_inertia

    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("clouds", "shape", "turn", "scalars", "label", "split")}
    offset = 0
    for store in stores:
        sims = np.arange(store.num_sims)
        first = store.start[sims]
        q0, v0, w0 = store.orientation_xyzw[first], store.linear_velocity[first], store.angular_velocity[first]
        turn = travel_turn(v0)
        parts["clouds"].append(np.asarray(store.points, dtype=np.float32))
        parts["shape"].append(store.shape_id[sims].astype(np.int64) + offset)
        parts["turn"].append(turn @ quat_to_matrix(q0))
        parts["scalars"].append(travel_scalars(v0, w0, store_spin_inertia(store, sims, q0), turn))
        parts["label"].append((store.topple_step[sims] >= 0).astype(np.float32))
        parts["split"].append(np.asarray(store.split[sims], dtype=np.int64))
        offset += store.num_shapes
    return TrainingSet(**{k: np.concatenate(v) for k, v in parts.items()})


def fit_pointnet_topple(stores: list[Any], seeds: tuple[int, ...] = (0,), steps: int = 3000, batch: int = 256,
                        width: int = 256, device: str = "cpu", minutes: float | None = None,
                        point_widths: tuple[int, ...] = POINT_WIDTHS, num_points: int | None = None,
                        progress: Callable[[int, int, float], None] | None = None) -> tuple[PointNetToppleClassifier, dict[str, Any]]:
    """One network per seed on the stores' training splits, each chosen on their validation splits, as one
    classifier. ``num_points`` below the stores' cloud size: the networks read each cloud thinned to it
    (``thin_hull_surface``), and so does the classifier at prediction (``thinned_to``): the per-point
    layers' cost a push is proportional to it. Returns the classifier and a report (validation accuracy of
    each network and of the ensemble, counts)."""
    data = store_training_set(stores)
    stored = int(data.clouds.shape[1])
    thinned_from = stored if num_points is not None and num_points < stored else 0
    if thinned_from:
        from physdyn.geometry.sampling import thin_hull_surface

        data.clouds = np.stack([thin_hull_surface(cloud, num_points) for cloud in data.clouds])
    train, val = np.flatnonzero(data.split == 0), np.flatnonzero(data.split == 1)
    runs = [train_network(data, train, val, steps, batch, width, seed, True, device, minutes,
                          None if progress is None else (lambda step, acc, s=seed: progress(s, step, acc)), point_widths)
            for seed in seeds]
    # one standardisation for the ensemble: every run's is the training split's, the same numbers
    classifier = PointNetToppleClassifier([r["state_dict"] for r in runs], runs[0]["scalars_mean"],
                                          runs[0]["scalars_std"], topple_timing(stores), float(stores[0].rate_hz), width,
                                          int(data.clouds.shape[1]), point_widths=tuple(point_widths),
                                          thinned_from=thinned_from)
    # the validation pushes, in ``val``'s order, with the clouds thinned above (each store's part of them)
    first = stores_first_frames(stores, split=1, clouds=np.split(data.clouds, np.cumsum([s.num_shapes for s in stores])[:-1]))
    p = classifier.probability(first["points"], first["v0"], first["w0"], first["spin"])
    report = {"val_accuracy": float(np.mean((p > 0.5) == (data.label[val] > 0.5))),
              "network_val_accuracy": [r["val_accuracy"] for r in runs], "steps": [r["steps"] for r in runs],
              "val_majority": float(max(data.label[val].mean(), 1 - data.label[val].mean())),
              "train_sequences": int(len(train)), "val_sequences": int(len(val))}
    return classifier, report


def stores_first_frames(stores: list[Any], split: int | None = None,
                        clouds: list[np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """The pushes' clouds turned to their step-0 orientation (P, N, 3), step-0 velocities, I_zz / m: every
    push of the stores in order, or those of one ``split``. ``clouds``: per store, the body-frame clouds
    (S, N', 3) a classifier reads in place of its own (thinned ones: ``thinned_to``)."""
    from physdyn.data.windows import store_spin_inertia, world_oriented_points

    out: dict[str, list[np.ndarray]] = {"points": [], "v0": [], "w0": [], "spin": []}
    for i, store in enumerate(stores):
        sims = np.arange(store.num_sims) if split is None else np.flatnonzero(store.split == split)
        first = store.start[sims]
        q0 = store.orientation_xyzw[first]
        body = store.points if clouds is None else clouds[i]
        out["points"].append(world_oriented_points(body[store.shape_id[sims]], q0))
        out["v0"].append(store.linear_velocity[first])
        out["w0"].append(store.angular_velocity[first])
        out["spin"].append(store_spin_inertia(store, sims, q0))
    return {k: np.concatenate(v) for k, v in out.items()}
