"""The search for the push: cross-entropy rounds over the search coordinates within a deadline
(``cross_entropy_search``), a fast screen corrected by what the accurate roll-out found near its
candidates (``_nearest_corrections``), and the final check of the best few at a finer step (``final_check``).
Why each part: docs/plan.md ("Choosing the search")."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from physdyn.geometry.rotations import wrap_angle
from physdyn.plan.goal import Goal, costs, goal_misses, misses, well_inside
from physdyn.plan.push import PushSpace
from physdyn.plan.rollouts import Outcome

POPULATION = 64  # candidates a round, at most
ELITES = 8  # kept to refit the search distribution
FIRST_ROUND = 16  # a small first round measures what a candidate costs, so later rounds fit the budget
MIN_ROUND = 4


@dataclass(frozen=True)
class Screen:
    """A fast roll-out that screens each round: it rolls out ``factor`` times as many candidates as the
    accurate roll-out keeps; with ``correct``, its outcomes are first shifted by the accurate roll-out's
    differences from it at the nearest candidates both rolled out."""

    rollout: Callable[[np.ndarray, np.ndarray], Outcome]
    factor: int = 16
    correct: bool = True


def cross_entropy_search(space: PushSpace, rollout: Callable[[np.ndarray, np.ndarray], Outcome], goal: Goal,
                         start: tuple[np.ndarray, np.ndarray], deadline: float, rng: np.random.Generator,
                         screen: Screen | None = None, pool_size: int = 0) -> dict[str, Any]:
    """Rounds of candidates drawn from a Gaussian over the search coordinates (the heading wraps around),
    the ``ELITES`` best refit it; the best candidate ever seen is kept. A round starts only when the
    measured cost per candidate says it ends before ``deadline`` (``time.perf_counter()``), shrunk to fit;
    the first round always runs. ``start``: the resting centre of mass (3,) and orientation (4,). With
    ``screen``, each round draws ``screen.factor`` times as many candidates, rolls them all out with
    ``screen.rollout`` and only its best ones with ``rollout``: elites, the best push and the answer's
    outcome are ``rollout``'s alone. Returns the best push, its
    outcome and the counts (``candidates``: rolled out by ``rollout``; ``screened``: by ``screen``), and
    in ``pool`` the ``pool_size`` best candidates seen, best first."""
    mean = space.toward(goal)
    std = np.array([0.05, 0.3, 0.2, 0.15])  # heading +/- 18 deg, speed +/- 0.2 m/s around the straight push
    best: dict[str, Any] | None = None
    pool: list[dict[str, Any]] = []
    seen_u: list[np.ndarray] = []  # candidates both models rolled out, and the accurate one's differences
    seen_dxy: list[np.ndarray] = []
    seen_dturn: list[np.ndarray] = []
    evaluated = rounds = screened = 0
    per_candidate = None
    size = FIRST_ROUND
    round_seconds: list[float] = []
    while True:
        if per_candidate is not None:
            size = min(POPULATION, int((deadline - time.perf_counter()) / per_candidate))
            if size < MIN_ROUND:
                break
        t0 = time.perf_counter()
        drawn = size if screen is None else size * max(int(screen.factor), 1)
        u = mean + std * rng.standard_normal((drawn, 4))
        u[0] = mean  # the distribution's centre itself: the straight push first, then the best guess so far
        if rounds == 0:  # half the first round spread over the whole space: the straight push may be wrong
            u[drawn // 2 :] = rng.uniform(size=(drawn - drawn // 2, 4))
        u[:, 0] = np.mod(u[:, 0], 1.0)
        u[:, 1:] = np.clip(u[:, 1:], 0.0, 1.0)
        pushes = space.pushes(u)
        if screen is not None:  # the fast model keeps the `size` most promising for the accurate one
            fast = screen.rollout(pushes["lin_vel"], pushes["ang_vel"])
            raw_xy, raw_turn = misses(goal, *start, fast.com_position, fast.orientation_xyzw)[:2]
            fast_xy, fast_turn = raw_xy, raw_turn
            if seen_u and screen.correct:
                # the accurate model's differences from the fast one at the nearest candidates it rolled out
                d_xy, d_turn = _nearest_corrections(u, np.concatenate(seen_u), np.concatenate(seen_dxy), np.concatenate(seen_dturn))
                fast_xy, fast_turn = raw_xy + d_xy, raw_turn + d_turn
            keep = np.argsort(costs(goal, *goal_misses(goal, fast_xy, fast_turn), fast.toppled), kind="stable")[:size]
            u, raw_xy, raw_turn = u[keep], raw_xy[keep], raw_turn[keep]
            pushes = {k: v[keep] for k, v in pushes.items()}
            screened += drawn
        outcome = rollout(pushes["lin_vel"], pushes["ang_vel"])
        displacement, turn, distance, turn_miss = misses(goal, *start, outcome.com_position, outcome.orientation_xyzw)
        if screen is not None:
            seen_u.append(u.copy())
            seen_dxy.append(displacement - raw_xy)
            seen_dturn.append(wrap_angle(turn - raw_turn))
        cost = costs(goal, distance, turn_miss, outcome.toppled)
        evaluated += size
        rounds += 1
        i = int(np.argmin(cost))
        if best is None or cost[i] < best["cost"]:
            best = _candidate(i, cost, pushes, outcome, displacement, turn, distance, turn_miss)
        if pool_size:  # the best few of the whole search, for a check at a finer step
            pool += [_candidate(int(j), cost, pushes, outcome, displacement, turn, distance, turn_miss)
                     for j in np.argsort(cost)[:pool_size]]
            pool = sorted(pool, key=lambda c: c["cost"])[:pool_size]
        elites = u[np.argsort(cost)[: min(ELITES, size)]]
        # the heading's mean on the circle, its spread from the wrapped offsets
        angle = 2.0 * np.pi * elites[:, 0]
        centre = math.atan2(np.sin(angle).mean(), np.cos(angle).mean()) / (2.0 * np.pi)
        offsets = wrap_angle(2.0 * np.pi * (elites[:, 0] - centre)) / (2.0 * np.pi)
        new_mean = np.concatenate([[centre % 1.0], elites[:, 1:].mean(axis=0)])
        new_std = np.concatenate([[np.sqrt(np.mean(offsets**2))], elites[:, 1:].std(axis=0)])
        mean = new_mean
        std = np.maximum(0.7 * new_std + 0.3 * std, 0.01)  # smoothed, and never collapsed to a point
        elapsed = time.perf_counter() - t0
        round_seconds.append(elapsed)
        per_candidate = elapsed / size
        if well_inside(goal, best["distance"], best["turn_miss"], best["toppled"]):
            break
    assert best is not None
    return {**best, "candidates": evaluated, "screened": screened, "rounds": rounds, "round_seconds": round_seconds,
            "pool": pool}


def _nearest_corrections(u: np.ndarray, seen: np.ndarray, d_xy: np.ndarray, d_turn: np.ndarray,
                         k: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """For each row of u (B, 4), the inverse-distance average of the corrections (d_xy (S, 2), d_turn (S,))
    at its ``k`` nearest rows of ``seen`` (S, 4) in search coordinates, the heading's wrapped around.
    Turns are averaged on the circle."""
    diff = u[:, None, :] - seen[None, :, :]
    diff[..., 0] = diff[..., 0] - np.round(diff[..., 0])  # the heading: a fraction of a turn, wrapped
    dist = np.sqrt((diff**2).sum(-1)) + 1e-6
    k = min(k, len(seen))
    near = np.argpartition(dist, k - 1, axis=1)[:, :k]
    w = 1.0 / np.take_along_axis(dist, near, axis=1)
    w = w / w.sum(axis=1, keepdims=True)
    xy = (w[..., None] * d_xy[near]).sum(axis=1)
    turn = np.arctan2((w * np.sin(d_turn[near])).sum(axis=1), (w * np.cos(d_turn[near])).sum(axis=1))
    return xy, turn


def _candidate(i: int, cost: np.ndarray, pushes: dict, outcome: Outcome, displacement: np.ndarray, turn: np.ndarray,
               distance: np.ndarray, turn_miss: np.ndarray) -> dict[str, Any]:
    """Candidate i of a round: its push, its outcome and its misses."""
    return {"cost": float(cost[i]), **{k: v[i] for k, v in pushes.items()},
            "final_com_position": outcome.com_position[i], "final_orientation_xyzw": outcome.orientation_xyzw[i],
            "displacement": displacement[i], "turn": float(turn[i]), "distance": float(distance[i]),
            "turn_miss": float(turn_miss[i]), "toppled": bool(outcome.toppled[i]),
            "trajectory": None if outcome.trajectories is None else outcome.trajectories[i]}


def final_check(pool: list[dict[str, Any]], check: Callable[[np.ndarray, np.ndarray], Outcome], goal: Goal,
                start: tuple[np.ndarray, np.ndarray], deadline: float) -> tuple[dict[str, Any] | None, list[float]]:
    """The search's best candidates (``pool``, best first) rolled out again by ``check`` (PyBullet at a finer
    step), one at a time while the measured cost of one says it ends before ``deadline``; the first always
    runs. ``start``: the resting centre of mass (3,) and orientation (4,). Returns the best by ``check``'s
    outcome (its misses, pose and, when ``check`` records one, its trajectory replace the search's) and the
    seconds each check took."""
    best, seconds = None, []
    for cand in pool:
        if seconds and time.perf_counter() + max(seconds) > deadline:
            break
        t0 = time.perf_counter()
        outcome = check(cand["lin_vel"][None], cand["ang_vel"][None])
        displacement, turn, distance, turn_miss = misses(goal, *start, outcome.com_position, outcome.orientation_xyzw)
        cost = costs(goal, distance, turn_miss, outcome.toppled)
        seconds.append(time.perf_counter() - t0)
        if best is None or cost[0] < best["cost"]:
            pushes = {k: cand[k][None] for k in ("push_direction", "push_point", "push_speed", "impulse", "lin_vel", "ang_vel")}
            best = _candidate(0, cost, pushes, outcome, displacement, turn, distance, turn_miss)
    return best, seconds
