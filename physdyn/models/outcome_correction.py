"""Where does the push end? A learned correction of a roll-out's resting pose (``physdyn fit-outcome``).

A position 1/120 s PyBullet gets right asks for the friction's work right to about 2 % on every new mesh
(docs/research/friction-and-sensitivity.md); the contact prior's slide is right to about
2.5 % and its path bends wrongly, and neither its per-step residual networks nor a map of the impact phase
carried a gain to meshes they never saw. This corrects the end instead: a small network reads the push (the
step-0 velocity and spin in the frame of its travel, I_zz / m) and where the roll-out came to rest (its
displacement along and across the travel, its turn about the vertical, and its last velocities), and gives
the truth minus that resting pose, trained on thousands of shapes' pushes, half of each batch mirrored
across its travel. One network per seed, averaged. With ``fit-outcome --pointnet`` each network is a small
PointNet that also reads the push's step-0 cloud in the frame of its travel (``ToppleNet`` with three
outputs). Measured in docs/research/outcome-correction.md, where richer inputs (the roll-out's state early in
the impact, how long and how far it moved, the centre of mass's height) were tried and not kept.

The correction is spread over the trajectory in proportion to the roll-out's own progress (the fraction of
its horizontal path, and of its turning, covered by each step), so the path stays smooth, starts where it
started and ends at the corrected pose; the velocities take the matching change. It applies only where the
roll-out has come to rest by its last step and has not toppled: what it was trained on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch

from physdyn.geometry.rotations import quat_conjugate, quat_multiply, turn_about_vertical, world_delta_rotvec, wrap_angle
from physdyn.models.topple_pointnet import (MIN_STEPS, PUSHES_PER_PASS, POINT_WIDTHS, ToppleNet, cloud_spin_inertia,
                                           numpy_forward, numpy_layers, travel_scalars, travel_turn)

KIND = "outcome_mlp"
POINTNET_KIND = "outcome_pointnet"  # fit-outcome --pointnet: an older physdyn says it does not know it
INPUTS = 13  # step-0 velocity (3) and spin (3) in the travel frame, the resting state (6), I_zz / m
TARGETS = ("along", "across", "yaw")  # truth minus roll-out at rest: displacement in the travel frame, turn
# Mirrored across its travel (y -> -y), a push is a push of the mirrored shape: velocities (along, across, up)
# change sign as (+, -, +), spins as (-, +, -); the resting state (v along, v across, w_z, p along, p across,
# yaw) as (+, -, -, +, -, -); the targets (along, across, yaw) as (+, -, -).
MIRROR_INPUTS = np.array([1, -1, 1, -1, 1, -1, 1, -1, -1, 1, -1, -1, 1], dtype=np.float64)
MIRROR_TARGETS = np.array([1.0, -1.0, -1.0])
# At rest: a roll-out slower than this at its last step has stopped (the contact prior stops at 1e-8; the
# networks' own velocities settle near, not at, zero).
REST_SPEED = 0.02   # m/s
REST_SPIN = 0.2     # rad/s
CONSTANT_INPUT = 1e-6  # an input whose spread over the training pushes is below this was the same for all
EXTRA_STEPS = 15    # fitting rolls each push out this far past its truth's end, as a long request would


class OutcomeNet(torch.nn.Module):
    """Standardised inputs (B, 13) -> standardised corrections (B, 3): two hidden layers."""

    def __init__(self, width: int = 256, inputs: int = INPUTS):
        super().__init__()
        self.layers = torch.nn.Sequential(torch.nn.Linear(inputs, width), torch.nn.ReLU(), torch.nn.Linear(width, width),
                                          torch.nn.ReLU(), torch.nn.Linear(width, len(TARGETS)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)


def yaw_of(q_xyzw: np.ndarray) -> np.ndarray:
    """The turn about the world vertical of (..., 4) rotations, radians."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]  # (np.moveaxis cost a quarter of a call)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def resting_state(turn: np.ndarray, p0: np.ndarray, q0: np.ndarray, p: np.ndarray, q: np.ndarray, v: np.ndarray,
                  w: np.ndarray) -> np.ndarray:
    """(B, 6) the state at the last step in the travel frame ``turn`` (B, 3, 3): velocity along and across,
    spin about the vertical, displacement from ``p0`` along and across, turn about the vertical since ``q0``."""
    vt = np.einsum("bij,bj->bi", turn, v)
    dp = np.einsum("bij,bj->bi", turn, p - p0)
    yaw = yaw_of(quat_multiply(q, quat_conjugate(q0)))
    return np.stack([vt[:, 0], vt[:, 1], w[:, 2], dp[:, 0], dp[:, 1], yaw], axis=1)


def outcome_inputs(v0: np.ndarray, w0: np.ndarray, spin_inertia: np.ndarray, p0: np.ndarray, q0: np.ndarray,
                   p: np.ndarray, q: np.ndarray, v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(raw inputs (B, 13), the travel frames (B, 3, 3)) from the step-0 state and the last step's."""
    turn = travel_turn(v0)
    push = travel_scalars(v0, w0, spin_inertia, turn)  # the topple PointNets' scalars: v0, w0, I_zz / m
    return np.concatenate([push[:, :6], resting_state(turn, p0, q0, p, q, v, w), push[:, 6:]], axis=1), turn


@dataclass
class OutcomeCorrection:
    """An ensemble of ``OutcomeNet`` state dicts with the inputs' and targets' standardisation; with
    ``num_points`` > 0, of PointNets (``ToppleNet`` with three outputs) that also read each push's step-0
    cloud of that many points in the frame of its travel (``fit-outcome --pointnet``), thinned from
    ``thinned_from``-point ``hull_surface`` clouds where that is set (``thinned_to``)."""

    networks: list[dict[str, torch.Tensor]]
    inputs_mean: np.ndarray
    inputs_std: np.ndarray
    targets_mean: np.ndarray
    targets_std: np.ndarray
    width: int = 256
    num_points: int = 0
    thinned_from: int = 0
    point_widths: tuple[int, ...] = POINT_WIDTHS
    _layers: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list, repr=False, compare=False)
    _pointnets: list[tuple[list, list]] = field(default_factory=list, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.num_points:
            # on numpy (``numpy_forward``), as the MLPs below: torch's per-call overhead would be most of a push's cost
            self._pointnets = []
            for state in self.networks:
                net = ToppleNet(self.width, INPUTS, tuple(self.point_widths), outputs=len(TARGETS))
                net.load_state_dict(state)
                self._pointnets.append(numpy_layers(net))
            return
        # The networks' layers stacked, on numpy: one prediction is a few small products, where torch's
        # per-call overhead would cost a millisecond, and a new mesh's prediction pays it for every call
        for state in self.networks:
            OutcomeNet(self.width).load_state_dict(state)  # the state is a whole network of this width
        names = sorted({k.rsplit(".", 1)[0] for k in self.networks[0]}, key=lambda k: int(k.split(".")[1]))
        self._layers = [(np.stack([s[f"{n}.weight"].double().numpy().T for s in self.networks]),
                         np.stack([s[f"{n}.bias"].double().numpy() for s in self.networks])[:, None, :]) for n in names]

    @property
    def given_points(self) -> int:
        """The size of the body-frame clouds a PointNet correction is given: the size it was fitted on, or the one
        it thins from (``thinned_to``); 0 for MLPs, which read no cloud."""
        return self.thinned_from or self.num_points

    @property
    def thinned_to(self) -> int:
        """The size it thins the clouds it is given to (``thinned_clouds``; 0: it reads them as they are)."""
        return self.num_points if self.thinned_from else 0

    def check_given(self, points_body: np.ndarray) -> None:
        """A one-line error where the clouds (B, N, 3) are not of the size it was fitted on."""
        given = np.shape(points_body)[1]
        if given != self.given_points:
            raise ValueError(f"this outcome correction was fitted on hull_surface clouds of {self.given_points} "
                             f"points and is given {given}: give it clouds of the size its model reads")

    def correction(self, inputs: np.ndarray, clouds: np.ndarray | None = None) -> np.ndarray:
        """Raw inputs (B, 13) -> (B, 3): the displacement along and across the travel (m) and the turn
        about the vertical (rad) to add to the resting pose (the mean of the networks'). ``clouds`` (B,
        num_points, 3): each push's step-0 cloud in its travel frame, for PointNets (``num_points`` > 0)."""
        x = (np.asarray(inputs, dtype=np.float64) - self.inputs_mean) / self.inputs_std
        # An input every training push had the same value of (the resting velocities: roll-outs ran past rest;
        # the velocity across the travel: zero by its frame) reads as training saw it: a request cut off while
        # still slowing has 0.01 m/s there, which over the 1e-9 of its spread made kilometres
        x[:, self.inputs_std < CONSTANT_INPUT] = 0.0
        if self.num_points:
            if clouds is None:
                raise ValueError("this outcome correction reads each push's cloud: pass clouds")
            if not len(x):
                return np.zeros((0, len(TARGETS)))
            # a few pushes a pass: their per-point activations stay in the cache (as the topple PointNet's)
            h = np.mean([np.concatenate([numpy_forward(layers, clouds[i : i + PUSHES_PER_PASS], x[i : i + PUSHES_PER_PASS])
                                         for i in range(0, len(x), PUSHES_PER_PASS)]) for layers in self._pointnets],
                        axis=0).astype(np.float64)
            return h * self.targets_std + self.targets_mean
        h = x[None]
        for i, (weight, bias) in enumerate(self._layers):
            h = h @ weight + bias
            if i + 1 < len(self._layers):
                h = np.maximum(h, 0.0)
        return h.mean(axis=0) * self.targets_std + self.targets_mean

    def apply(self, states: dict[str, np.ndarray], v0: np.ndarray, w0: np.ndarray, spin_inertia: np.ndarray,
              dt: float, toppled: np.ndarray | None = None, lengths: np.ndarray | None = None,
              clouds_world: np.ndarray | None = None) -> np.ndarray:
        """Correct ``states`` (``com_position`` (B, T, 3), ``orientation_xyzw`` (B, T, 4), ``linear_velocity``,
        ``angular_velocity``, one step every ``dt`` s) in place where a push rests at its own last step and has
        not ``toppled`` (B,). ``lengths`` (B,): each push's own number of steps (default T), for roll-outs
        padded to the longest of a batch: a push is judged at its own end, as it would be alone, and past it
        takes the whole correction. The step-0 velocities stay as given. ``clouds_world`` (B, num_points, 3):
        the clouds it reads (``thinned_to``) turned to step 0, for PointNets. Returns which rows it corrected (B,)."""
        if self.num_points and clouds_world is None:
            raise ValueError("this outcome correction reads each push's cloud: pass clouds_world")
        p, q = states["com_position"], states["orientation_xyzw"]
        v, w = states["linear_velocity"], states["angular_velocity"]
        B, T = p.shape[:2]
        lengths = np.full(B, T) if lengths is None else np.minimum(np.asarray(lengths, dtype=np.int64), T)
        corrected = np.zeros(B, dtype=bool)
        for L in np.unique(lengths):
            rows = np.flatnonzero(lengths == L)
            if L < 2:
                continue
            rests = (np.linalg.norm(v[rows, L - 1], axis=1) < REST_SPEED) & (np.linalg.norm(w[rows, L - 1], axis=1) < REST_SPIN)
            if toppled is not None:
                rests &= ~np.asarray(toppled, dtype=bool)[rows]
            idx = rows[rests]
            if not len(idx):
                continue
            corrected[idx] = True
            inputs, turn = outcome_inputs(v0[idx], w0[idx], spin_inertia[idx], p[idx, 0], q[idx, 0], p[idx, L - 1],
                                          q[idx, L - 1], v[idx, L - 1], w[idx, L - 1])
            clouds = None if not self.num_points else np.einsum("bij,bnj->bni", turn, np.asarray(clouds_world)[idx])
            fix = self.correction(inputs, clouds)
            shift = fix[:, 0:1] * turn[:, 0, :2] + fix[:, 1:2] * turn[:, 1, :2]  # (b, 2) world, horizontal
            b = len(idx)
            moved = np.linalg.norm(np.diff(p[idx, :L, :2], axis=1), axis=-1)
            turns = np.abs(wrap_angle(np.diff(yaw_of(quat_multiply(q[idx, :L], quat_conjugate(q[idx, :1]))), axis=1)))
            # the path's progress (rows :b) and the turn's (rows b:), each falling back on the other, in one pass:
            # its own L steps as alone; past its own end, the whole correction and no change of velocity
            own = _progress(np.concatenate([moved, turns]), np.concatenate([turns, moved]))
            fraction = np.concatenate([own, np.ones((2 * b, T - L))], axis=1)
            rate = np.concatenate([_rate(own, dt), np.zeros((2 * b, T - L))], axis=1)
            p[idx, :, :2] += fraction[:b, :, None] * shift[:, None, :]
            v[idx, :, :2] += rate[:b, :, None] * shift[:, None, :]
            spin = fraction[b:] * fix[:, 2:3]  # (b, T) radians about the world vertical through the centre of mass
            q[idx] = turn_about_vertical(spin, q[idx])
            w[idx, :, 2] += rate[b:] * fix[:, 2:3]
        return corrected

    def to_dict(self) -> dict[str, Any]:
        # tensors, lists and numbers only: checkpoints are read without running code (docs/security.md)
        return {"kind": POINTNET_KIND if self.num_points else KIND, "networks": [{k: t.detach().cpu().clone() for k, t in s.items()} for s in self.networks],
                "inputs_mean": self.inputs_mean.tolist(), "inputs_std": self.inputs_std.tolist(),
                "targets_mean": self.targets_mean.tolist(), "targets_std": self.targets_std.tolist(),
                "width": int(self.width), "num_points": int(self.num_points), "thinned_from": int(self.thinned_from),
                "point_widths": [int(w) for w in self.point_widths]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "OutcomeCorrection":
        if d.get("kind") not in (KIND, POINTNET_KIND):
            raise ValueError(f"unknown outcome correction kind {d.get('kind')!r}")
        return cls([dict(s) for s in d["networks"]], np.asarray(d["inputs_mean"]), np.asarray(d["inputs_std"]),
                   np.asarray(d["targets_mean"]), np.asarray(d["targets_std"]), int(d["width"]),
                   int(d.get("num_points", 0)), int(d.get("thinned_from", 0)),
                   tuple(int(w) for w in d.get("point_widths", POINT_WIDTHS)))


def _progress(step_sizes: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """(b, L-1) non-negative step sizes -> (b, L) the fraction covered by each step, 0 at the first and 1 at
    the last; where nothing moved, that of ``fallback`` (the path for a turn, the turn for a path), and where
    neither did, all of it at step 1."""
    def covered(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = np.concatenate([np.zeros((len(x), 1)), np.cumsum(x, axis=1)], axis=1)
        return c, c[:, -1:]

    own, own_total = covered(step_sizes)
    other, other_total = covered(fallback)
    at_once = np.ones_like(own)
    at_once[:, 0] = 0.0
    return np.where(own_total > 1e-12, own / np.maximum(own_total, 1e-12),
                    np.where(other_total > 1e-12, other / np.maximum(other_total, 1e-12), at_once))


def _rate(fraction: np.ndarray, dt: float) -> np.ndarray:
    """d fraction / dt (b, T): central differences, backward at the last step, and 0 at step 0, whose velocity
    is the one the caller gave."""
    rate = np.zeros_like(fraction)
    if fraction.shape[1] > 2:
        rate[:, 1:-1] = (fraction[:, 2:] - fraction[:, :-2]) / (2.0 * dt)
    if fraction.shape[1] > 1:
        rate[:, -1] = (fraction[:, -1] - fraction[:, -2]) / dt
    return rate


def correct_rollout(correction: OutcomeCorrection, dt: float, states: dict[str, np.ndarray], v0: np.ndarray,
                    w0: np.ndarray, spin_inertia: np.ndarray | None, points_world: np.ndarray, toppled: np.ndarray,
                    extra: tuple[np.ndarray | None, np.ndarray | None] = (None, None)) -> None:
    """Apply ``correction`` to a roll-out's ``states`` (one step every ``dt`` s) in place
    (``OutcomeCorrection.apply``; ``toppled`` (B,): the roll-out's own verdict; ``extra``: (lengths (B,) or None,
    clouds_world or None: what a PointNet correction reads, its ``thinned_to`` clouds turned to step 0)), and make
    its ``delta_*`` (if present) the corrected states' steps. spin_inertia (B,) or None: estimated from
    ``points_world`` (B, N, 3), the clouds in the step-0 frame."""
    lengths, clouds_world = extra
    spin = cloud_spin_inertia(points_world) if spin_inertia is None else np.asarray(spin_inertia, dtype=np.float64)
    rows = correction.apply(states, np.asarray(v0, dtype=np.float64).reshape(-1, 3),
                            np.asarray(w0, dtype=np.float64).reshape(-1, 3), spin, float(dt), toppled, lengths,
                            clouds_world)
    if rows.any() and "delta_position" in states:
        states["delta_position"][rows] = np.diff(states["com_position"][rows], axis=1)
        states["delta_linear_velocity"][rows] = np.diff(states["linear_velocity"][rows], axis=1)
        states["delta_angular_velocity"][rows] = np.diff(states["angular_velocity"][rows], axis=1)
        q = states["orientation_xyzw"][rows]
        states["delta_rotation"][rows] = world_delta_rotvec(q[:, :-1], q[:, 1:])


# --------------------------------------------------------------------------------------------------
# Training (the roll-outs it learns from: physdyn/eval/outcome_fit.py)
# --------------------------------------------------------------------------------------------------
def train_outcome_network(inputs: np.ndarray, targets: np.ndarray, train: np.ndarray, val: np.ndarray,
                          steps: int = 6000, batch: int = 1024, width: int = 256, seed: int = 0,
                          progress: Callable[[int, float], None] | None = None, clouds: np.ndarray | None = None,
                          shape: np.ndarray | None = None, frame: np.ndarray | None = None, device: str = "cpu",
                          point_widths: tuple[int, ...] = POINT_WIDTHS, minutes: float | None = None) -> dict[str, Any]:
    """One network on the pushes ``train``, its checkpoint the best of 20 checks of the mean standardised
    |error| on ``val``: AdamW (lr 1e-3, weight decay 1e-4), one-cycle schedule, smooth-L1, half of each
    batch mirrored across its travel. With ``clouds`` (S, N, 3) body frame, ``shape`` (P,) each push's and
    ``frame`` (P, 3, 3) body -> its travel frame at step 0: a PointNet that also reads each push's cloud (the
    mirrored half's cloud mirrored too; ``fit-outcome --pointnet``). ``minutes``: stop then, keeping the best
    so far."""
    if steps < MIN_STEPS:
        raise ValueError(f"steps must be at least {MIN_STEPS} (the network is checked 20 times), got {steps}")
    if clouds is not None and (shape is None or frame is None):
        raise ValueError("a PointNet correction trains on clouds with each push's shape and frame: pass all three")
    dev = torch.device(device)
    torch.manual_seed(seed)
    mu, sd = inputs[train].mean(0), inputs[train].std(0) + 1e-9
    ymu, ysd = targets[train].mean(0), targets[train].std(0) + 1e-9

    def tensor(a: np.ndarray, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        return torch.tensor(np.asarray(a), dtype=dtype, device=dev)

    x, xm = tensor((inputs - mu) / sd), tensor((inputs * MIRROR_INPUTS - mu) / sd)
    y, ym = tensor((targets - ymu) / ysd), tensor((targets * MIRROR_TARGETS - ymu) / ysd)
    if clouds is None:
        net: torch.nn.Module = OutcomeNet(width, inputs.shape[1]).to(dev)
    else:
        net = ToppleNet(width, INPUTS, tuple(point_widths), outputs=len(TARGETS)).to(dev)
        cloud_t, frame_t, shape_t = tensor(clouds), tensor(frame), tensor(shape, torch.int64)
        flip_y = torch.tensor([1.0, -1.0, 1.0], device=dev)

    def run(idx: torch.Tensor, mirrored: torch.Tensor | None = None) -> torch.Tensor:
        """The network on the pushes ``idx``, those ``mirrored`` (B,) mirrored across their travel."""
        inputs_in = x[idx] if mirrored is None else torch.where(mirrored[:, None], xm[idx], x[idx])
        if clouds is None:
            return net(inputs_in)
        cloud = torch.einsum("bij,bnj->bni", frame_t[idx], cloud_t[shape_t[idx]])
        if mirrored is not None:
            cloud = torch.where(mirrored[:, None, None], cloud * flip_y, cloud)
        return net(cloud, inputs_in)

    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=1e-3, total_steps=steps, pct_start=max(0.05, 2.0 / steps))
    train_t, val_t = tensor(train, torch.int64), tensor(val, torch.int64)
    best, best_state, started, done = np.inf, None, time.time(), steps
    for step in range(steps):
        idx = train_t[torch.randint(len(train_t), (batch,), device=dev)]
        m = torch.rand(batch, device=dev) < 0.5
        loss = torch.nn.functional.smooth_l1_loss(run(idx, m), torch.where(m[:, None], ym[idx], y[idx]))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % max(1, steps // 20) == 0 or step + 1 == steps:
            net.eval()
            with torch.no_grad():
                error = float(torch.cat([(run(part) - y[part]).abs() for part in val_t.split(8192)]).mean())
            net.train()
            if error < best:
                best, best_state = error, {k: t.detach().cpu().clone() for k, t in net.state_dict().items()}
            if progress is not None:
                progress(step + 1, error)
            if minutes is not None and time.time() - started > 60 * minutes:
                done = step + 1
                break
    return {"state_dict": best_state, "inputs_mean": mu, "inputs_std": sd, "targets_mean": ymu, "targets_std": ysd,
            "val_error": best, "seconds": time.time() - started, "steps": done}
