"""What the user asks of a plan and how far a candidate falls short: the ``Goal``, the checks of the user's
numbers, the misses (distance, turn) and the cost the search ranks by, and the outcome keys of a plan."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from physdyn.config import PhysicsConfig
from physdyn.errors import PredictionError
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, wrap_angle
from physdyn.predict.request_checks import positive_number

SUCCESS_DISTANCE_M = 0.02  # a goal is met within 2 cm ...
SUCCESS_TURN_DEG = 15.0  # ... and 15 degrees
REACH_MARGIN = 1.5  # a goal up to this times the Coulomb slide of the fastest push is tried (spins and rolls go further)
TOPPLE_COST = 100.0  # an upright goal's toppled candidate ranks below every upright one


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
    """The budget in seconds, or a one-line ``PredictionError``."""
    return positive_number(budget_s, "budget", "--budget 1", unit=" of seconds")


def turn_about_vertical(q0_xyzw: np.ndarray, q1_xyzw: np.ndarray) -> np.ndarray:
    """The turn (rad, (-pi, pi], counter-clockwise from above positive) about world z from q0 to q1: the twist
    about z of the world-frame rotation R1 R0^T (for an object that stays upright, its whole rotation)."""
    rel = quat_multiply(q1_xyzw, quat_conjugate(np.broadcast_to(q0_xyzw, np.shape(q1_xyzw))))
    return wrap_angle(2.0 * np.arctan2(rel[..., 2], rel[..., 3]))


def misses(goal: Goal, start: np.ndarray, orientation0: np.ndarray, outcome_position: np.ndarray,
           outcome_orientation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per candidate: the displacement on the plane (B, 2), the turn (B,) rad, the distance to the goal (B,) m
    and the turn's difference from the goal's (B,) rad, absolute (zero without a goal yaw).
    start: (3,) the resting centre of mass; orientation0: (4,); outcome_position (B, 3), outcome_orientation (B, 4)."""
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
    """Lower is better: the misses (B,) in units of the success tolerances, squared and added; a topple when
    the goal is upright adds ``TOPPLE_COST``."""
    cost = (distance / SUCCESS_DISTANCE_M) ** 2 + (turn_miss / math.radians(SUCCESS_TURN_DEG)) ** 2
    return cost + (TOPPLE_COST * np.asarray(toppled, dtype=np.float64) if goal.upright else 0.0)


def well_inside(goal: Goal, distance: float, turn_miss: float, toppled: bool) -> bool:
    """Within a quarter of the tolerances (and upright where asked): more search only spends the budget."""
    return (distance < 0.25 * SUCCESS_DISTANCE_M and turn_miss < math.radians(0.25 * SUCCESS_TURN_DEG)
            and not (goal.upright and toppled))


def outcome_keys(trajectory: dict | None, goal: Goal, displacement: Any, turn: float, distance: float, turn_miss: float,
                 toppled: bool, final_pose: tuple[Any, Any]) -> dict[str, Any]:
    """A plan's ``predicted`` or ``verified``: the trajectory keys when there is a trajectory, the final pose
    (``final_pose``: position (3,), orientation (4,)), the turn, the misses and whether the goal is met."""
    keys = ("rate_hz", "time", "com_position", "orientation_xyzw", "linear_velocity", "angular_velocity", "topple_probability")
    out = {k: trajectory[k] for k in keys} if trajectory is not None else {}
    met = bool(distance <= SUCCESS_DISTANCE_M and turn_miss <= math.radians(SUCCESS_TURN_DEG) and not (goal.upright and toppled))
    out.update({
        "final_com_position": np.asarray(final_pose[0], dtype=np.float64),
        "final_orientation_xyzw": np.asarray(final_pose[1], dtype=np.float64),
        "displacement_xy": np.asarray(displacement, dtype=np.float64), "turn_deg": math.degrees(turn), "toppled": bool(toppled),
        "miss_m": float(distance), "miss_yaw_deg": None if goal.yaw is None else math.degrees(turn_miss), "met": met,
    })
    return out
