"""A plan's turn, checked outside the planner: the returned push is simulated here and its yaw measured with
SciPy, so a planner that turns the wrong way (or by the wrong amount) for a goal yaw fails, whatever the
planner's own miss function says."""

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from physdyn.plan import PlanOptions, plan_push
from physdyn.plan.push import PushResponse
from physdyn.predict.body import prepare_body
from physdyn.predict.predictor import load_predictor
from physdyn.predict.simulator import simulate_from_state

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
RATE_HZ = 15.0
STEPS = 106  # 7 s: every push here is at rest by then


@pytest.fixture(scope="module")
def box():
    return prepare_body(trimesh.creation.box((0.1, 0.16, 0.12)))


def _simulate(box, lin_vel, ang_vel):
    sim = simulate_from_state(box.spec, IDENTITY, lin_vel, ang_vel, RATE_HZ, STEPS)
    p, q = sim["com_position"], sim["orientation_xyzw"]
    turn = Rotation.from_quat(q[-1]) * Rotation.from_quat(q[0]).inv()
    return p[-1, :2] - p[0, :2], math.degrees(turn.as_euler("ZYX")[0]), bool(sim["topple_label"].any())


def _off_centre_push(box):
    """A push 1.5 cm off the centre of mass, 20 deg from x at 1.1 m/s: it slides about 26 cm and turns
    about 56 deg clockwise (negative about z)."""
    heading = math.radians(20.0)
    direction = np.array([[math.cos(heading), math.sin(heading), 0.0]])
    with PushResponse(box.spec, IDENTITY) as response:
        point = response.surface_points(direction, np.array([response.com[2]]), np.array([0.015]))
        v, w = response.velocities(point, box.spec.mass * 1.1 * direction)
    return _simulate(box, v[0], w[0])


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_planned_push_turns_the_box_by_the_goal_yaw_in_an_independent_simulation(box, sign):
    displacement, turn_deg, _ = _off_centre_push(box)
    assert turn_deg < -40  # the goal needs a real turn, so a sign error cannot hide inside the tolerance
    goal_yaw = sign * abs(turn_deg)
    plan = plan_push(load_predictor(), box, displacement, goal_yaw, upright=True, budget_s=1.5, options=PlanOptions(seed=0))
    reached, turned, toppled = _simulate(box, plan["lin_vel"], plan["ang_vel"])
    assert not toppled
    assert np.sign(turned) == np.sign(goal_yaw), (turned, goal_yaw)
    assert abs(turned - goal_yaw) < 25, (turned, goal_yaw)
    assert np.linalg.norm(reached - displacement) < 0.05
