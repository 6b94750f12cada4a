"""Choosing the push: a cross-entropy search over push parameters, each round a batch of candidate pushes
rolled out at once by a model, within a wall-clock budget (``plan_push``; ``Predictor.plan`` calls it).

The data flow: goal checks -> ``PushSpace`` (search coordinates -> push point, direction, speed ->
post-push velocities, ``push.py``) -> roll-outs -> ``Outcome`` (final pose, miss) -> the search keeps the
best. The default search is screened: a fast ``LearnedRollout`` (the contact prior alone, or a predictor's
networks without simulator) rolls out many candidates, corrected by what PyBullet found near them, and a
``BulletRollout`` (PyBullet at 1/240 s on the mesh's hull) ranks the most promising; ``final_check`` rolls
the best few out again at the conventions' step in the budget's last fifth and answers. ``verify``
re-simulates the chosen push afterwards; the search never sees it. Why each part: docs/plan.md
("Choosing the search"); keys of the result: docs/plan.md.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
import torch

from physdyn.config import ImpulseConfig, PhysicsConfig
from physdyn.errors import PredictionError, PredictionWarning
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, tilt_angle, wrap_angle
from physdyn.predict.body import PreparedBody, initial_pose
from physdyn.predict.push import PushResponse
from physdyn.predict.simulator import simulate_from_state
from physdyn.sim.bullet import pb
from physdyn.sim.trajectory import TOPPLE_ANGLE, place_at_rest
from physdyn.sim.world import PhysicsWorld

SUCCESS_DISTANCE_M = 0.02  # the "met": within 2 cm ...
SUCCESS_TURN_DEG = 15.0  # ... and 15 degrees
REACH_MARGIN = 1.5  # a goal up to this times the Coulomb slide of the fastest push is tried (spins and rolls go further)
VERIFY_SECONDS = PhysicsConfig().max_duration  # the check runs until rest, as a store's simulation does
POPULATION = 64  # candidates a round, at most
ELITES = 8  # kept to refit the search distribution
FIRST_ROUND = 16  # a small first round measures what a candidate costs, so later rounds fit the budget
MIN_ROUND = 4
TOPPLE_COST = 100.0  # an upright goal's toppled candidate ranks below every upright one
SEARCHES = ("screened", "model", "pybullet")  # what rolls out the candidates (docs/plan.md)
SCREENS = ("prior", "model")  # the fast model of a screened search
DEFAULT_PYBULLET_STEP = 1.0 / 240.0  # ranks a screened search's candidates (docs/plan.md: the benchmark)
SCREEN_FACTOR = 16  # a screened search rolls out this many times as many candidates with the fast model
CHECK_SHARE = 0.2  # the last fifth of the budget re-checks the best candidates at the conventions' step
CHECK_POOL = 8  # ... at most this many


# --------------------------------------------------------------------------------------------------
# What the user asks for
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Goal:
    """Displacement of the centre of mass on the plane, ``xy`` (2,) m, world frame; optional turn about the
    vertical between the rest poses, ``yaw`` rad (counter-clockwise seen from above is positive); and
    whether the object must stay upright."""

    xy: np.ndarray
    yaw: float | None = None
    upright: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {"xy": [float(v) for v in self.xy], "yaw_deg": None if self.yaw is None else math.degrees(self.yaw),
                "upright": self.upright}


def farthest_reach(speed_max: float, friction: float, gravity: float) -> float:
    """The farthest the fastest push can slide the centre of mass, with ``REACH_MARGIN``: v^2 / (2 mu g)."""
    return REACH_MARGIN * speed_max**2 / (2.0 * friction * abs(gravity))


def check_goal(goal_xy: Any, goal_yaw_deg: Any, upright: Any, speed_max: float, physics: PhysicsConfig) -> Goal:
    """A ``Goal`` from the user's numbers, or a one-line ``PredictionError`` naming the problem and the fix."""
    try:
        xy = np.asarray(goal_xy, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise PredictionError(f"goal must be two numbers DX DY (m), got {goal_xy!r}") from None
    if xy.size != 2:
        raise PredictionError(f"goal must be two numbers DX DY (m), got {xy.size}")
    if not np.isfinite(xy).all():
        raise PredictionError(f"goal must be finite, got {xy[0]:g} {xy[1]:g}; pass the displacement in metres, e.g. --goal 0.3 0.1")
    friction = physics.lateral_friction_object * physics.lateral_friction_ground
    reach = farthest_reach(speed_max, friction, physics.gravity)
    if np.linalg.norm(xy) > reach:
        raise PredictionError(f"goal {np.linalg.norm(xy):.3f} m away is beyond what a push of at most {speed_max:g} m/s "
                              f"can slide the object (about {reach:.2f} m at friction {friction:g}); choose a nearer goal "
                              "or raise the speed bound")
    yaw = None
    if goal_yaw_deg is not None:
        try:
            deg = float(goal_yaw_deg)
        except (TypeError, ValueError):
            raise PredictionError(f"goal yaw must be a number of degrees, got {goal_yaw_deg!r}") from None
        if not math.isfinite(deg):
            raise PredictionError(f"goal yaw must be finite, got {goal_yaw_deg!r}; pass degrees in (-180, 180], e.g. --goal-yaw 30")
        yaw = wrap_angle(math.radians(deg))
    if not isinstance(upright, (bool, np.bool_)):
        raise PredictionError(f"upright must be true or false, got {upright!r}")
    return Goal(xy=xy, yaw=yaw, upright=bool(upright))


def check_budget(budget_s: Any) -> float:
    try:
        budget = float(budget_s)
    except (TypeError, ValueError):
        raise PredictionError(f"budget must be a number of seconds, got {budget_s!r}") from None
    if not math.isfinite(budget) or budget <= 0:
        raise PredictionError(f"budget must be a positive number of seconds, got {budget_s!r}; e.g. --budget 1")
    return budget


def check_bounds(speed_min: Any, speed_max: Any, height_fraction: Any, lateral_fraction: Any) -> tuple[float, float, float, float]:
    values = []
    for name, value in (("speed_min", speed_min), ("speed_max", speed_max), ("height_fraction", height_fraction),
                        ("lateral_fraction", lateral_fraction)):
        try:
            values.append(float(value))
        except (TypeError, ValueError):
            raise PredictionError(f"{name} must be a number, got {value!r}") from None
        if not math.isfinite(values[-1]) or values[-1] < 0:
            raise PredictionError(f"{name} must be a finite number >= 0, got {value!r}")
    lo, hi, height, lateral = values
    if not 0 < lo <= hi <= 10.0:
        raise PredictionError(f"speed bounds must satisfy 0 < speed_min <= speed_max <= 10 m/s, got {lo:g} and {hi:g}")
    if height > 0.5 or lateral > 1.0:
        raise PredictionError(f"height_fraction must be at most 0.5 and lateral_fraction at most 1, got {height:g} and {lateral:g}")
    return lo, hi, height, lateral


def turn_about_vertical(q0_xyzw: np.ndarray, q1_xyzw: np.ndarray) -> np.ndarray:
    """The turn (rad, (-pi, pi], counter-clockwise from above positive) about world z from q0 to q1: the twist
    about z of the world-frame rotation R1 R0^T (for an object that stays upright, its whole rotation)."""
    rel = quat_multiply(q1_xyzw, quat_conjugate(np.broadcast_to(q0_xyzw, np.shape(q1_xyzw))))
    return wrap_angle(2.0 * np.arctan2(rel[..., 2], rel[..., 3]))


# --------------------------------------------------------------------------------------------------
# The pushes searched over
# --------------------------------------------------------------------------------------------------
class PushSpace:
    """Search coordinates u (B, 4) in [0, 1] -> pushes. u = (heading of the push / 2 pi, height in the band,
    sideways offset, speed): the point is where a horizontal ray at that height, offset sideways of the
    centre of mass by up to ``lateral_fraction`` of the half-width, meets the surface (as the generator
    draws it, ``physdyn.sim.impulse``); the band is the centre-of-mass height +/- ``height_fraction`` of the
    object's height; the impulse is mass x speed along the heading."""

    def __init__(self, response: PushResponse, speed_min: float, speed_max: float, height_fraction: float,
                 lateral_fraction: float):
        self.response = response
        self.speed = (speed_min, speed_max)
        top, com_z = response.top, float(response.com[2])
        lo = max(com_z - height_fraction * top, 0.05 * top)
        hi = min(com_z + height_fraction * top, 0.95 * top)
        self.height = (min(lo, hi), max(lo, hi))
        self.lateral_fraction = lateral_fraction

    def pushes(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """``push_direction``, ``push_point`` (B, 3) world; ``push_speed`` (B,); ``impulse`` (B, 3) N s;
        ``lin_vel``, ``ang_vel`` (B, 3): the state right after the push."""
        heading = 2.0 * np.pi * u[:, 0]
        direction = np.stack([np.cos(heading), np.sin(heading), np.zeros(len(u))], axis=1)
        height = self.height[0] + u[:, 1] * (self.height[1] - self.height[0])
        lateral = (2.0 * u[:, 2] - 1.0) * self.lateral_fraction * self.response.half_width(direction)
        speed = self.speed[0] + u[:, 3] * (self.speed[1] - self.speed[0])
        point = self.response.surface_points(direction, height, lateral)
        impulse = self.response.spec.mass * speed[:, None] * direction
        lin, ang = self.response.velocities(point, impulse)
        return {"push_direction": direction, "push_point": point, "push_speed": speed, "impulse": impulse,
                "lin_vel": lin, "ang_vel": ang}

    def toward(self, goal: Goal, friction: float, gravity: float) -> np.ndarray:
        """(4,) search coordinates of a straight push toward the goal at the speed a Coulomb slide needs:
        where the first round's distribution is centred."""
        heading = math.atan2(goal.xy[1], goal.xy[0]) % (2.0 * np.pi)
        speed = math.sqrt(2.0 * friction * abs(gravity) * float(np.linalg.norm(goal.xy)))
        s = np.clip((speed - self.speed[0]) / max(self.speed[1] - self.speed[0], 1e-9), 0.0, 1.0)
        return np.array([heading / (2.0 * np.pi), 0.5, 0.5, s])


# --------------------------------------------------------------------------------------------------
# Roll-outs: post-push velocities (B, 3), (B, 3) -> final poses
# --------------------------------------------------------------------------------------------------
@dataclass
class Outcome:
    """Where each candidate ends: ``com_position`` (B, 3), ``orientation_xyzw`` (B, 4), ``toppled`` (B,);
    ``trajectories``: the per-candidate results of ``Predictor.predict`` when the roll-out has them."""

    com_position: np.ndarray
    orientation_xyzw: np.ndarray
    toppled: np.ndarray
    trajectories: list | None = None


class LearnedRollout:
    """The predictor's model, all candidates of a round in one ``predict_many`` call."""

    def __init__(self, predictor: Any, body: PreparedBody, orientation_xyzw: np.ndarray, seconds: float):
        self.predictor, self.body, self.orientation, self.seconds = predictor, body, orientation_xyzw, seconds
        self.name = predictor.name

    def warm_up(self) -> float:
        """A predictor's first roll-out in a process sets things up once (torch, the simulated start's world):
        1-2 s on a loaded core. One candidate of the first plan pays it before the budget's clock starts.
        Returns the seconds it took (0 when this predictor was warm)."""
        if self.predictor.warmed_up:
            return 0.0
        t0 = time.perf_counter()
        self(np.array([[0.5, 0.0, 0.0]]), np.zeros((1, 3)))
        self.predictor.warmed_up = True
        return time.perf_counter() - t0

    def __call__(self, lin_vel: np.ndarray, ang_vel: np.ndarray) -> Outcome:
        # One thread: a round of a few dozen candidates is too small to split, and on a shared 2-core machine
        # two threads made a round of 16 four times slower (1.0 s against 0.22 s, measured).
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", PredictionWarning)  # the mesh's notes were issued when it was prepared
                results = self.predictor.predict_many([self.body] * len(lin_vel), lin_vel, ang_vel, self.seconds,
                                                      self.orientation)
        finally:
            torch.set_num_threads(threads)
        return Outcome(np.stack([r["com_position"][-1] for r in results]),
                       np.stack([r["orientation_xyzw"][-1] for r in results]),
                       np.array([r["toppled"] for r in results]), results)

    def close(self) -> None:
        pass


class BulletRollout:
    """PyBullet at ``time_step`` as the planner's model: one world and one body reused for every candidate,
    each simulated from the resting pose until at rest (the conventions' rest rule) or ``seconds``. A
    candidate has toppled when its tilt passed 45 degrees at any frame of ``rate_hz`` (the conventions'
    rule, as a store's labels and ``verify_push`` apply it), not only at its last pose: a body that rolls
    over and lands upright has toppled."""

    REST_CHECK_S = 1.0 / 60.0

    def __init__(self, spec: Any, orientation_xyzw: np.ndarray, time_step: float, seconds: float,
                 physics: PhysicsConfig | None = None, rate_hz: float = 15.0, record: bool = False):
        self.physics = replace(physics or PhysicsConfig(), time_step=float(time_step))
        self.spec, self.orientation, self.seconds = spec, np.asarray(orientation_xyzw, dtype=np.float64), seconds
        self.rate_hz = float(rate_hz)
        self.record = record  # keep each candidate's trajectory at rate_hz (the final check's answer has one)
        self.world = PhysicsWorld(self.physics)
        self.body = self.world.add_body(spec)
        self.name = f"pybullet@1/{round(1.0 / time_step)}s"

    def warm_up(self) -> float:
        return 0.0

    def __call__(self, lin_vel: np.ndarray, ang_vel: np.ndarray) -> Outcome:
        cid, phys = self.world.client, self.physics
        chunk = max(1, int(round(self.REST_CHECK_S / phys.time_step)))
        total = int(math.ceil(self.seconds / phys.time_step))
        rest_needed = int(math.ceil(phys.rest_duration / phys.time_step))
        frame = max(1, int(round(1.0 / (self.rate_hz * phys.time_step))))
        chunk = math.gcd(chunk, frame)  # the frames fall on chunk boundaries
        principal = quat_conjugate(self.spec.principal_quat_xyzw)
        positions, quats = np.empty((len(lin_vel), 3)), np.empty((len(lin_vel), 4))
        toppled = np.zeros(len(lin_vel), dtype=bool)
        trajectories = [] if self.record else None
        for i, (v, w) in enumerate(zip(lin_vel, ang_vel)):
            place_at_rest(self.world, self.body, self.spec, self.orientation)
            pb.resetBaseVelocity(self.body, list(map(float, v)), list(map(float, w)), physicsClientId=cid)
            steps = rest = 0
            track: list[tuple] = []
            recorded_last = False  # whether the final pose is the last recorded frame
            while True:
                recorded_last = steps % frame == 0
                if recorded_last:
                    pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=cid)
                    if not toppled[i]:  # R_mesh = R_base A^T
                        toppled[i] = tilt_angle(self.orientation, quat_multiply(np.asarray(orn), principal)) > TOPPLE_ANGLE
                    if self.record:
                        track.append((pos, orn, *pb.getBaseVelocity(self.body, physicsClientId=cid)))
                if steps >= total or rest >= rest_needed:
                    break
                self.world.step(chunk)
                steps += chunk
                lv, av = pb.getBaseVelocity(self.body, physicsClientId=cid)
                still = np.dot(lv, lv) < phys.rest_linear_speed**2 and np.dot(av, av) < phys.rest_angular_speed**2
                rest = rest + chunk if still else 0
            pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=cid)
            positions[i], quats[i] = pos, orn
            if not recorded_last:  # stopped between two frames: its final pose is checked here
                toppled[i] |= tilt_angle(self.orientation, quat_multiply(np.asarray(orn), principal)) > TOPPLE_ANGLE
            if self.record:
                trajectories.append(self._trajectory(track if not recorded_last else track[:-1], pos, orn))
        # PyBullet's base frame is the principal frame: back to the mesh frame, R_mesh = R_base A^T
        quats = quat_multiply(quats, principal)
        return Outcome(positions, quats, toppled, trajectories)

    def _trajectory(self, track: list[tuple], pos: Any, orn: Any) -> dict[str, Any]:
        """The recorded frames before the final state, then the final state (where the roll-out stopped, on a
        frame or between two), as the trajectory keys of a prediction, in the mesh frame; topple "probability"
        0 or 1 by the 45 degree rule, from the first frame past it on."""
        p = np.array([t[0] for t in track] + [pos], dtype=np.float64)
        q = quat_multiply(np.array([t[1] for t in track] + [orn], dtype=np.float64),
                          quat_conjugate(self.spec.principal_quat_xyzw))
        last_v, last_w = pb.getBaseVelocity(self.body, physicsClientId=self.world.client)
        v = np.array([t[2] for t in track] + [last_v], dtype=np.float64)
        w = np.array([t[3] for t in track] + [last_w], dtype=np.float64)
        over = np.maximum.accumulate(tilt_angle(self.orientation, q) > TOPPLE_ANGLE)
        return {"rate_hz": self.rate_hz, "time": np.arange(len(p)) / self.rate_hz, "com_position": p,
                "orientation_xyzw": q, "linear_velocity": v, "angular_velocity": w,
                "topple_probability": over.astype(np.float64), "checkpoint": self.name}

    def close(self) -> None:
        self.world.close()


# --------------------------------------------------------------------------------------------------
# Misses and the search
# --------------------------------------------------------------------------------------------------
def misses(goal: Goal, start: np.ndarray, orientation0: np.ndarray, outcome_position: np.ndarray,
           outcome_orientation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per candidate: the displacement on the plane (B, 2), the turn (B,) rad, the distance to the goal (B,) m
    and the turn's difference from the goal's (B,) rad, absolute (zero without a goal yaw)."""
    displacement = outcome_position[:, :2] - start[:2]
    turn = turn_about_vertical(orientation0, outcome_orientation)
    return (displacement, turn, *goal_misses(goal, displacement, turn))


def goal_misses(goal: Goal, displacement: np.ndarray, turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Displacements (B, 2) and turns (B,) -> the distance to the goal (B,) m and the turn's absolute
    difference from the goal's (B,) rad (zero without a goal yaw)."""
    distance = np.linalg.norm(displacement - goal.xy, axis=1)
    turn_miss = np.zeros(len(turn)) if goal.yaw is None else np.abs(wrap_angle(turn - goal.yaw))
    return distance, turn_miss


def costs(goal: Goal, distance: np.ndarray, turn_miss: np.ndarray, toppled: np.ndarray) -> np.ndarray:
    """Lower is better: the misses in units of the success tolerances, squared and added; a topple when the
    goal is upright adds ``TOPPLE_COST``."""
    cost = (distance / SUCCESS_DISTANCE_M) ** 2 + (turn_miss / math.radians(SUCCESS_TURN_DEG)) ** 2
    return cost + (TOPPLE_COST * np.asarray(toppled, dtype=np.float64) if goal.upright else 0.0)


def cross_entropy_search(space: PushSpace, rollout: Callable[[np.ndarray, np.ndarray], Outcome], goal: Goal,
                         start: np.ndarray, orientation0: np.ndarray, deadline: float, rng: np.random.Generator,
                         friction: float, gravity: float, screen: Callable[[np.ndarray, np.ndarray], Outcome] | None = None,
                         screen_factor: int = 16, pool_size: int = 0, correct: bool = True) -> dict[str, Any]:
    """Rounds of candidates drawn from a Gaussian over the search coordinates (the heading wraps around),
    the ``ELITES`` best refit it; the best candidate ever seen is kept. A round starts only when the
    measured cost per candidate says it ends before ``deadline`` (``time.perf_counter()``), shrunk to fit;
    the first round always runs. With ``screen`` (a fast roll-out), each round draws ``screen_factor``
    times as many candidates, rolls them all out with ``screen`` and only its best ones with ``rollout``:
    elites, the best push and the answer's outcome are ``rollout``'s alone. Returns the best push, its
    outcome and the counts (``candidates``: rolled out by ``rollout``; ``screened``: by ``screen``), and
    in ``pool`` the ``pool_size`` best candidates seen, best first."""
    mean = space.toward(goal, friction, gravity)
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
        drawn = size if screen is None else size * max(int(screen_factor), 1)
        u = mean + std * rng.standard_normal((drawn, 4))
        u[0] = mean  # the distribution's centre itself: the straight push first, then the best guess so far
        if rounds == 0:  # half the first round spread over the whole space: the straight push may be wrong
            u[drawn // 2 :] = rng.uniform(size=(drawn - drawn // 2, 4))
        u[:, 0] = np.mod(u[:, 0], 1.0)
        u[:, 1:] = np.clip(u[:, 1:], 0.0, 1.0)
        pushes = space.pushes(u)
        if screen is not None:  # the fast model keeps the `size` most promising for the accurate one
            fast = screen(pushes["lin_vel"], pushes["ang_vel"])
            raw_xy, raw_turn = misses(goal, start, orientation0, fast.com_position, fast.orientation_xyzw)[:2]
            fast_xy, fast_turn = raw_xy, raw_turn
            if seen_u and correct:
                # the accurate model's differences from the fast one at the nearest candidates it rolled out
                d_xy, d_turn = _nearest_corrections(u, np.concatenate(seen_u), np.concatenate(seen_dxy), np.concatenate(seen_dturn))
                fast_xy, fast_turn = raw_xy + d_xy, raw_turn + d_turn
            keep = np.argsort(costs(goal, *goal_misses(goal, fast_xy, fast_turn), fast.toppled), kind="stable")[:size]
            u, raw_xy, raw_turn = u[keep], raw_xy[keep], raw_turn[keep]
            pushes = {k: v[keep] for k, v in pushes.items()}
            screened += drawn
        outcome = rollout(pushes["lin_vel"], pushes["ang_vel"])
        displacement, turn, distance, turn_miss = misses(goal, start, orientation0, outcome.com_position, outcome.orientation_xyzw)
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
        if best["distance"] < 0.25 * SUCCESS_DISTANCE_M and best["turn_miss"] < math.radians(0.25 * SUCCESS_TURN_DEG) \
                and not (goal.upright and best["toppled"]):
            break  # well inside the tolerance: more rounds only spend the budget
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
                start: np.ndarray, orientation0: np.ndarray, deadline: float) -> tuple[dict[str, Any] | None, int]:
    """The search's best candidates (``pool``, best first) rolled out again by ``check`` (PyBullet at a finer
    step), one at a time while the measured cost of one says it ends before ``deadline``; the first always
    runs. Returns the best by ``check``'s outcome (its misses, pose and, when ``check`` records one, its
    trajectory replace the search's) and the seconds each check took."""
    best, seconds = None, []
    for cand in pool:
        if seconds and time.perf_counter() + max(seconds) > deadline:
            break
        t0 = time.perf_counter()
        outcome = check(cand["lin_vel"][None], cand["ang_vel"][None])
        displacement, turn, distance, turn_miss = misses(goal, start, orientation0, outcome.com_position, outcome.orientation_xyzw)
        cost = costs(goal, distance, turn_miss, outcome.toppled)
        seconds.append(time.perf_counter() - t0)
        if best is None or cost[0] < best["cost"]:
            pushes = {k: cand[k][None] for k in ("push_direction", "push_point", "push_speed", "impulse", "lin_vel", "ang_vel")}
            best = _candidate(0, cost, pushes, outcome, displacement, turn, distance, turn_miss)
    return best, seconds


def horizon_seconds(speed_max: float, friction: float, gravity: float) -> float:
    """How long a candidate is rolled out: the Coulomb stopping time of the fastest push, v / (mu g), with
    half as long again and half a second for spinning and settling, at most the conventions' 7 s."""
    return float(min(1.5 * speed_max / (friction * abs(gravity)) + 0.5, PhysicsConfig().max_duration))


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


def screen_predictor(predictor: Any, screen: Any) -> Any:
    """The fast model of a screened search: the contact prior, the predictor's networks without simulator (each
    made once per predictor), or a ``Predictor`` given."""
    if screen == "prior":
        return predictor.contact_prior()
    if screen == "model":
        return predictor.without_simulator()
    return screen


def resolve_bounds(speed_min: Any = None, speed_max: Any = None, height_fraction: Any = None,
                   lateral_fraction: Any = None) -> tuple[float, float, float, float]:
    """The push bounds, each None taken from the training pushes' (``ImpulseConfig``), checked by ``check_bounds``."""
    defaults = ImpulseConfig()
    return check_bounds(defaults.speed_min if speed_min is None else speed_min,
                        defaults.speed_max if speed_max is None else speed_max,
                        defaults.height_fraction if height_fraction is None else height_fraction,
                        defaults.lateral_fraction if lateral_fraction is None else lateral_fraction)


def plan_push(predictor: Any, mesh: Any, goal_xy: Any, goal_yaw: Any = None, upright: bool = False, budget_s: float = 1.0,
              scale: float = 1.0, orientation_xyzw: Any = None, seed: int = 0, speed_min: float | None = None,
              speed_max: float | None = None, height_fraction: float | None = None, lateral_fraction: float | None = None,
              verify: bool = False, search: str = "screened", pybullet_step: float = DEFAULT_PYBULLET_STEP,
              screen: Any = "prior", check: bool = True) -> dict[str, Any]:
    """``Predictor.plan``: see its docstring. ``search``: "screened" (``screen`` rolls out ``SCREEN_FACTOR``
    times as many candidates as PyBullet at ``pybullet_step``, which ranks the most promising), "model"
    (the predictor's model alone) or "pybullet" (PyBullet at ``pybullet_step`` alone). ``screen``: "prior"
    (``contact_prior_predictor``), "model" (``Predictor.without_simulator``) or a ``Predictor``. ``check``:
    the ``CHECK_POOL`` best candidates rolled out again at the conventions' step in the last ``CHECK_SHARE``
    of the budget, the best by that check answering."""
    from physdyn.predict.predictor import check_orientation  # the predictor imports this module to plan

    lo, hi, height, lateral = resolve_bounds(speed_min, speed_max, height_fraction, lateral_fraction)
    physics = predictor.physics or PhysicsConfig()
    goal = check_goal(goal_xy, goal_yaw, upright, hi, physics)
    budget = check_budget(budget_s)
    time_step = check_search(search, pybullet_step, screen)
    q0 = check_orientation(orientation_xyzw)
    body = predictor._bodies([mesh], [scale])[0]
    friction = physics.lateral_friction_object * physics.lateral_friction_ground
    seconds = horizon_seconds(hi, friction, physics.gravity)
    rollout = (LearnedRollout(predictor, body, q0, seconds) if search == "model"
               else BulletRollout(body.spec, q0, time_step, seconds, physics, predictor.rate_hz))
    fast = LearnedRollout(screen_predictor(predictor, screen), body, q0, seconds) if search == "screened" else None
    check_step = physics.time_step if check else None
    warm_up = rollout.warm_up() + (fast.warm_up() if fast is not None else 0.0)
    # the budget's clock: from here, the mesh's preparation (cached per predictor) and a cold process's
    # one-time set-up excluded, the push world, every round and the choice included
    started = time.perf_counter()
    start = initial_pose(body.spec, q0)
    rng = np.random.default_rng(seed)
    try:
        response = PushResponse(body.spec, q0, physics)
        try:
            space = PushSpace(response, lo, hi, height, lateral)
            search_deadline = started + budget * (1.0 - (CHECK_SHARE if check_step else 0.0))
            best = cross_entropy_search(space, rollout, goal, start, q0, search_deadline, rng, friction, physics.gravity,
                                        fast, SCREEN_FACTOR, CHECK_POOL if check_step else 0)
        finally:
            response.close()
        check_seconds, answered_by = [], rollout.name
        if check_step:
            # until at rest, as the verification runs: a candidate still turning at the search's horizon is
            # judged where it stops
            checker = BulletRollout(body.spec, q0, float(check_step), VERIFY_SECONDS, physics, predictor.rate_hz, record=True)
            try:
                found, check_seconds = final_check(best["pool"], checker, goal, start, q0, started + budget)
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
        "predicted": _outcome_keys(best["trajectory"], goal, best["displacement"], best["turn"], best["distance"],
                                   best["turn_miss"], best["toppled"], best["final_com_position"], best["final_orientation_xyzw"]),
        "goal": goal.as_dict(),
        "budget_s": budget, "elapsed_s": elapsed, "candidates": int(best["candidates"]), "rounds": int(best["rounds"]),
        "round_s": [float(t) for t in best["round_seconds"]],
        "warm_up_s": warm_up, "search": search, "model": rollout.name, "horizon_s": seconds,
        "screen": None if fast is None else fast.name, "screened": int(best["screened"]),
        "checked": len(check_seconds), "check_s": [float(t) for t in check_seconds], "answered_by": answered_by,
        "orientation_xyzw": q0, "com_mesh": np.array(body.spec.com_mesh, dtype=np.float64), "mesh": body.name,
        "mesh_scale": body.scale, "rate_hz": predictor.rate_hz, "seed": int(seed),
        "bounds": {"speed_min": lo, "speed_max": hi, "height_fraction": height, "lateral_fraction": lateral},
    }
    if verify:
        result["verified"] = verify_push(body, q0, result["lin_vel"], result["ang_vel"], goal, predictor.rate_hz, physics)
    return result


def verify_push(body: PreparedBody, orientation_xyzw: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray, goal: Goal,
                rate_hz: float, physics: PhysicsConfig | None = None) -> dict[str, Any]:
    """PyBullet at the conventions' step on the mesh itself, from the resting pose with the planned
    velocities, until at rest (or 7 s): the trajectory keys, the final pose and the miss."""
    steps = int(round(VERIFY_SECONDS * rate_hz)) + 1
    sim = simulate_from_state(body.spec, orientation_xyzw, lin_vel, ang_vel, rate_hz, steps, physics)
    p, q = sim["com_position"], sim["orientation_xyzw"]
    displacement, turn, distance, turn_miss = misses(goal, p[0], q[0], p[-1:], q[-1:])
    trajectory = {"rate_hz": rate_hz, "time": np.arange(len(p)) / rate_hz, "com_position": p, "orientation_xyzw": q,
                  "linear_velocity": sim["linear_velocity"], "angular_velocity": sim["angular_velocity"],
                  "topple_probability": sim["topple_label"].astype(np.float64), "checkpoint": "pybullet"}
    return _outcome_keys(trajectory, goal, displacement[0], float(turn[0]), float(distance[0]), float(turn_miss[0]),
                         bool(sim["topple_label"].any()), p[-1], q[-1])


def _outcome_keys(trajectory: dict | None, goal: Goal, displacement, turn, distance, turn_miss, toppled, final_p, final_q) -> dict[str, Any]:
    keys = ("rate_hz", "time", "com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability")
    out = {k: trajectory[k] for k in keys} if trajectory is not None else {}
    met = bool(distance <= SUCCESS_DISTANCE_M and turn_miss <= math.radians(SUCCESS_TURN_DEG) and not (goal.upright and toppled))
    out.update({
        "final_com_position": np.asarray(final_p, dtype=np.float64), "final_orientation_xyzw": np.asarray(final_q, dtype=np.float64),
        "displacement_xy": np.asarray(displacement, dtype=np.float64), "turn_deg": math.degrees(turn), "toppled": bool(toppled),
        "miss_m": float(distance), "miss_yaw_deg": None if goal.yaw is None else math.degrees(turn_miss), "met": met,
    })
    return out
