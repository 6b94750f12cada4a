"""Choosing the push: ``plan_push`` runs a cross-entropy search over push parameters within a wall-clock
budget, each round a batch of candidate pushes rolled out at once, and answers with the best push.

The data flow: goal checks (``goal.py``) -> ``PushSpace`` (search coordinates -> push point, direction,
speed -> post-push velocities, ``push.py``) -> roll-outs (``rollouts.py``) -> the search keeps the best
(``search.py``); the screens come from ``screens.py``. The default search is screened: a fast ``LearnedRollout`` (the contact prior, or a
predictor's networks with nothing simulated) rolls out many candidates, corrected by what PyBullet found
near them, and a ``BulletRollout`` (PyBullet at 1/240 s on the mesh's hull) ranks the most promising;
``final_check`` rolls the best few out again at the conventions' step in the budget's last fifth and
answers. ``verify_push`` re-simulates the chosen push afterwards; the search never sees it. Why each part:
docs/plan.md ("Choosing the search"); keys of the result: docs/plan.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from physdyn.config import PhysicsConfig
from physdyn.errors import PredictionError
from physdyn.plan.goal import Goal, check_budget, check_goal, misses, outcome_keys
from physdyn.plan.push import PushBounds, PushResponse, PushSpace
from physdyn.plan.rollouts import BulletRollout, LearnedRollout
from physdyn.plan.screens import SCREENS, screen_predictor
from physdyn.plan.search import Screen, cross_entropy_search, final_check
from physdyn.predict.body import PreparedBody, initial_pose
from physdyn.predict.predictor import check_orientation
from physdyn.predict.simulator import simulate_from_state

VERIFY_SECONDS = PhysicsConfig().max_duration  # the check runs until rest, as a store's simulation does
SEARCHES = ("screened", "model", "pybullet")  # what rolls out the candidates (docs/plan.md)
DEFAULT_PYBULLET_STEP = 1.0 / 240.0  # ranks a screened search's candidates (docs/plan.md: the benchmark)
SCREEN_FACTOR = 16  # a screened search rolls out this many times as many candidates with the fast model
CHECK_SHARE = 0.2  # the last fifth of the budget re-checks the best candidates at the conventions' step
CHECK_POOL = 8  # ... at most this many


@dataclass(frozen=True)
class PlanOptions:
    """How ``plan_push`` searches (docs/plan.md, "The search").

    search: "screened" (``screen`` rolls out ``SCREEN_FACTOR`` times as many candidates as PyBullet at
    ``pybullet_step`` on the mesh's hull, which ranks the most promising), "model" (the predictor's model
    alone) or "pybullet" (PyBullet at ``pybullet_step`` alone). screen: "prior" (the contact prior), "model"
    (the predictor's networks with nothing simulated) or a ``Predictor``. check: the ``CHECK_POOL`` best
    candidates rolled out again at the conventions' step in the last ``CHECK_SHARE`` of the budget, the best
    by that check answering. seed: the search's. verify: also re-simulate the answer (``verify_push``, key
    ``verified``). scale: the mesh's units to metres. bounds: the pushes searched over.
    """

    search: str = "screened"
    screen: Any = "prior"
    pybullet_step: float = DEFAULT_PYBULLET_STEP
    check: bool = True
    seed: int = 0
    verify: bool = False
    scale: float = 1.0
    bounds: PushBounds = field(default_factory=PushBounds)


def check_search(search: Any, pybullet_step: Any, screen: Any) -> float:
    """The PyBullet step of a valid search (s), or a one-line ``PredictionError``."""
    if search not in SEARCHES:
        raise PredictionError(f"search must be one of {', '.join(SEARCHES)}, got {search!r}")
    try:
        time_step = float(pybullet_step)
    except (TypeError, ValueError):
        raise PredictionError(f"the PyBullet step must be a number of seconds, e.g. 1/240, got {pybullet_step!r}") from None
    if not 0 < time_step <= 0.1:
        raise PredictionError(f"the PyBullet step must be in (0, 0.1] s, e.g. 0.004167 (1/240), got {pybullet_step!r}")
    if search == "screened" and screen not in SCREENS and not hasattr(screen, "predict_many"):
        raise PredictionError(f"screen must be one of {', '.join(SCREENS)} (or a Predictor), got {screen!r}")
    return time_step


def horizon_seconds(speed_max: float, friction: float, gravity: float) -> float:
    """How long a candidate is rolled out: the Coulomb stopping time of the fastest push, v / (mu g), with
    half as long again and half a second for spinning and settling, at most the conventions' 7 s."""
    return float(min(1.5 * speed_max / (friction * abs(gravity)) + 0.5, PhysicsConfig().max_duration))


def plan_push(predictor: Any, mesh: Any, goal_xy: Any, goal_yaw: Any = None, upright: bool = False,
              budget_s: float = 1.0, orientation_xyzw: Any = None, options: PlanOptions | None = None) -> dict[str, Any]:
    """The push that moves ``mesh`` (a file path, a ``trimesh.Trimesh`` or a ``PreparedBody``, placed as
    ``predictor.predict`` places it, resting in ``orientation_xyzw``) by ``goal_xy`` (2,) m on the plane,
    turned by ``goal_yaw`` degrees about the vertical (counter-clockwise from above positive; None: any
    turn), not toppled if ``upright``: a cross-entropy search over the push point (height band, sideways
    offset), direction and speed, each round's candidates rolled out as one batch, for ``budget_s`` seconds
    of wall clock. ``options``: the search, its screen, the final check, the seed, the push bounds
    (default: the training pushes') and ``verify`` (``PlanOptions``). A goal not met within the budget is
    still answered: the best push and its predicted miss.

    Returns ``lin_vel``, ``ang_vel`` (3,) world frame (what ``predict`` takes), ``push_point``,
    ``push_direction``, ``push_speed``, ``push_impulse``, ``predicted`` (the answering model's trajectory,
    final pose, ``miss_m``, ``miss_yaw_deg``, ``met``), ``goal``, ``budget_s``, ``elapsed_s``,
    ``candidates``, ``screened``, ``checked``, ``rounds`` and the inputs (docs/plan.md); with
    ``options.verify``, ``verified``: PyBullet at the conventions' step on the mesh until at rest, a check
    the search never sees. Bad goals (not finite, beyond the speed bounds' reach), budgets and search
    settings raise ``PredictionError``.
    """
    options = options or PlanOptions()
    lo, hi, height, lateral = bounds = options.bounds.resolved()
    physics = predictor.physics or PhysicsConfig()
    goal = check_goal(goal_xy, goal_yaw, upright, hi, physics)
    budget = check_budget(budget_s)
    time_step = check_search(options.search, options.pybullet_step, options.screen)
    q0 = check_orientation(orientation_xyzw)
    # the predictor's own preparation, so a mesh it planned or predicted before is not prepared again
    body = predictor._bodies([mesh], [options.scale])[0]
    friction = physics.lateral_friction_object * physics.lateral_friction_ground
    seconds = horizon_seconds(hi, friction, physics.gravity)
    rollout = (LearnedRollout(predictor, body, q0, seconds) if options.search == "model"
               else BulletRollout(body.spec, q0, time_step, seconds, physics, predictor.rate_hz))
    fast = (LearnedRollout(screen_predictor(predictor, options.screen), body, q0, seconds)
            if options.search == "screened" else None)
    check_step = physics.time_step if options.check else None
    warm_up = rollout.warm_up() + (fast.warm_up() if fast is not None else 0.0)
    # the budget's clock: from here, the mesh's preparation (cached per predictor) and a cold process's
    # one-time set-up excluded, the push world, every round and the choice included
    started = time.perf_counter()
    start = (initial_pose(body.spec, q0), q0)
    rng = np.random.default_rng(options.seed)
    try:
        response = PushResponse(body.spec, q0, physics)
        try:
            space = PushSpace(response, bounds)
            search_deadline = started + budget * (1.0 - (CHECK_SHARE if check_step else 0.0))
            screen = None if fast is None else Screen(fast, SCREEN_FACTOR)
            best = cross_entropy_search(space, rollout, goal, start, search_deadline, rng, screen,
                                        CHECK_POOL if check_step else 0)
        finally:
            response.close()
        check_seconds, answered_by = [], rollout.name
        if check_step:
            # until at rest, as the verification runs: a candidate still turning at the search's horizon is
            # judged where it stops
            checker = BulletRollout(body.spec, q0, float(check_step), VERIFY_SECONDS, physics, predictor.rate_hz, record=True)
            try:
                found, check_seconds = final_check(best["pool"], checker, goal, start, started + budget)
            finally:
                checker.close()
            if found is not None:
                counts = {k: best[k] for k in ("candidates", "screened", "rounds", "round_seconds")}
                best, answered_by = {**found, **counts}, checker.name
    finally:
        rollout.close()
    elapsed = time.perf_counter() - started
    result = {
        "lin_vel": best["lin_vel"], "ang_vel": best["ang_vel"],
        "push_point": best["push_point"], "push_direction": best["push_direction"], "push_speed": float(best["push_speed"]),
        "push_impulse": best["impulse"],
        "predicted": outcome_keys(best["trajectory"], goal, best["displacement"], best["turn"], best["distance"],
                                  best["turn_miss"], best["toppled"], (best["final_com_position"], best["final_orientation_xyzw"])),
        "goal": goal.as_dict(),
        "budget_s": budget, "elapsed_s": elapsed, "candidates": int(best["candidates"]), "rounds": int(best["rounds"]),
        "round_s": [float(t) for t in best["round_seconds"]],
        "warm_up_s": warm_up, "search": options.search, "model": rollout.name, "horizon_s": seconds,
        "screen": None if fast is None else fast.name, "screened": int(best["screened"]),
        "checked": len(check_seconds), "check_s": [float(t) for t in check_seconds], "answered_by": answered_by,
        "orientation_xyzw": q0, "com_mesh": np.array(body.spec.com_mesh, dtype=np.float64), "mesh": body.name,
        "mesh_scale": body.scale, "rate_hz": predictor.rate_hz, "seed": int(options.seed),
        "bounds": {"speed_min": lo, "speed_max": hi, "height_fraction": height, "lateral_fraction": lateral},
    }
    if options.verify:
        result["verified"] = verify_push(body, q0, result["lin_vel"], result["ang_vel"], goal, predictor.rate_hz, physics)
    return result


def verify_push(body: PreparedBody, orientation_xyzw: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray, goal: Goal,
                rate_hz: float, physics: PhysicsConfig | None = None) -> dict[str, Any]:
    """PyBullet at the conventions' step on the mesh itself, from the resting pose in ``orientation_xyzw``
    (4,) with the planned velocities ``lin_vel``, ``ang_vel`` (3,), until at rest (or 7 s): the trajectory
    keys at ``rate_hz``, the final pose and the miss from ``goal``."""
    steps = int(round(VERIFY_SECONDS * rate_hz)) + 1
    sim = simulate_from_state(body.spec, orientation_xyzw, lin_vel, ang_vel, rate_hz, steps, physics)
    p, q = sim["com_position"], sim["orientation_xyzw"]
    displacement, turn, distance, turn_miss = misses(goal, p[0], q[0], p[-1:], q[-1:])
    trajectory = {"rate_hz": rate_hz, "time": np.arange(len(p)) / rate_hz, "com_position": p, "orientation_xyzw": q,
                  "linear_velocity": sim["linear_velocity"], "angular_velocity": sim["angular_velocity"],
                  "topple_probability": sim["topple_label"].astype(np.float64), "checkpoint": "pybullet"}
    return outcome_keys(trajectory, goal, displacement[0], float(turn[0]), float(distance[0]), float(turn_miss[0]),
                        bool(sim["topple_label"].any()), (p[-1], q[-1]))
