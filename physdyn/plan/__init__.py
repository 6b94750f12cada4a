"""Planning a push: which push moves a mesh to a goal (a displacement on the plane, optionally a turn,
optionally upright)? ``plan_push(predictor, mesh, goal_xy, ...)`` searches within a wall-clock budget and
answers with the push, its post-push velocities and its predicted outcome; ``verify_push`` re-simulates a
push in PyBullet. The goal and its misses: ``goal``; the pushes: ``push``; what rolls candidates out:
``rollouts`` and ``screens``; the search: ``search``; the plan's files: ``files``. docs/plan.md."""

from physdyn.plan.goal import Goal
from physdyn.plan.planner import PlanOptions, plan_push, verify_push
from physdyn.plan.push import PushBounds

__all__ = ["Goal", "PlanOptions", "PushBounds", "plan_push", "verify_push"]
