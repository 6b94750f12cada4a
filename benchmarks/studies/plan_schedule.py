"""Does `physdyn plan` gain from PyBullet's step schedule? The planner ranks its screened candidates with
PyBullet at 1/240 s; the step schedule (1/240 s for a push's first 0.53 s, while its contact settles, then
1/60 s: benchmarks/frontier.py's ``SCHEDULES``) is nearly as accurate at about 1/120 s's cost, so the same
budget could rank more candidates. It is also a stronger PyBullet-alone planner to compare with.

For the length of the run, ``physdyn.predict.planner.BulletRollout`` built with the step ``SCHEDULE_MARK``
(a stand-in value, never a real step) rolls out on the schedule; every other step is untouched, the final
check at the conventions' 1/960 s included. Then benchmarks/planning.py runs as usual with the planners below.

    python benchmarks/studies/plan_schedule.py --goals 50 --budgets 1      # ~7 minutes

docs/plan.md, "The step schedule in the planner".
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import planning  # noqa: E402

from physdyn.geometry.rotations import quat_conjugate, quat_multiply, tilt_angle  # noqa: E402
from physdyn.predict import planner  # noqa: E402
from physdyn.predict.planner import TOPPLE_ANGLE, Outcome  # noqa: E402
from physdyn.sim.bullet import pb  # noqa: E402
from physdyn.sim.trajectory import place_at_rest  # noqa: E402

SCHEDULE_MARK = 1 / 241  # the step a planner names to get the schedule
FINE, FINE_SECONDS, COARSE = 1 / 240, 8 / 15, 1 / 60  # frontier.py's SCHEDULES[0] at 15 Hz

ORIGINAL_CALL = planner.BulletRollout.__call__


def scheduled_call(self, lin_vel: np.ndarray, ang_vel: np.ndarray) -> Outcome:
    """BulletRollout.__call__ on the schedule, with its rest rule (checked every 1/60 s), frames at rate_hz and
    topple rule; the final state only (the planner's ranking records no trajectory)."""
    if self.physics.time_step != SCHEDULE_MARK:
        return ORIGINAL_CALL(self, lin_vel, ang_vel)
    assert not self.record, "the study schedules the ranking only"
    cid, phys = self.world.client, self.physics
    principal = quat_conjugate(self.spec.principal_quat_xyzw)
    positions, quats = np.empty((len(lin_vel), 3)), np.empty((len(lin_vel), 4))
    toppled = np.zeros(len(lin_vel), dtype=bool)
    check = planner.BulletRollout.REST_CHECK_S  # 1/60 s: four fine steps or one coarse step
    per_frame = int(round(1.0 / (self.rate_hz * check)))
    fine_checks = int(round(FINE_SECONDS / check))
    total = int(math.ceil(self.seconds / check - 1e-9))
    rest_needed = int(math.ceil(phys.rest_duration / check - 1e-9))
    for i, (v, w) in enumerate(zip(lin_vel, ang_vel)):
        self.world.set_time_step(FINE)
        place_at_rest(self.world, self.body, self.spec, self.orientation)
        pb.resetBaseVelocity(self.body, list(map(float, v)), list(map(float, w)), physicsClientId=cid)
        k = rest = 0
        while True:
            if k % per_frame == 0 and not toppled[i]:
                orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=cid)[1]
                toppled[i] = tilt_angle(self.orientation, quat_multiply(np.asarray(orn), principal)) > TOPPLE_ANGLE
            if k >= total or rest >= rest_needed:
                break
            if k == fine_checks:
                self.world.set_time_step(COARSE)
            self.world.step(int(round(check / self.world.physics.time_step)))
            k += 1
            lv, av = pb.getBaseVelocity(self.body, physicsClientId=cid)
            still = np.dot(lv, lv) < phys.rest_linear_speed**2 and np.dot(av, av) < phys.rest_angular_speed**2
            rest = rest + 1 if still else 0
        pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=cid)
        positions[i], quats[i] = pos, orn
        toppled[i] |= tilt_angle(self.orientation, quat_multiply(np.asarray(orn), principal)) > TOPPLE_ANGLE
    return Outcome(positions, quat_multiply(quats, principal), toppled, None)


def main() -> None:
    planner.BulletRollout.__call__ = scheduled_call
    planning.PLANNERS.update({
        "physdyn (default; the ranker on the step schedule)": {"pybullet_step": SCHEDULE_MARK},
        "pybullet step schedule, check": {"search": "pybullet", "pybullet_step": SCHEDULE_MARK},
    })
    if "--planners" not in sys.argv:
        sys.argv += ["--planners", "physdyn (default: contact-prior screen, PyBullet 1/240 s ranks, check)",
                     "physdyn (default; the ranker on the step schedule)", "pybullet 1/240 s, check",
                     "pybullet 1/120 s, check", "pybullet step schedule, check"]
    planning.main()


if __name__ == "__main__":
    main()
