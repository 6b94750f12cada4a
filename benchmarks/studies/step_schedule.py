"""Where does PyBullet need its fine step? Most of what the shipped predictors lose is lost while the push's
contact settles (impulse_start.py: from the truth's state at 0.4 s the contact prior alone beats PyBullet at
1/120 s in position and rotation). So spend the fine step there only, and continue (1) with the contact prior, or (2) with PyBullet at
a coarse step: which continuation is as accurate for less?

For every push of a frontier set, on the mesh's own hull, from the recorded step-0 state as
benchmarks/frontier.py's rows are:
- ``prior``: PyBullet at 1/FINE s for the first S seconds, then the contact prior from that state (its
  displacement added; toppled where the simulated part tilted past 45 degrees: the prior never topples);
- ``schedule``: PyBullet at 1/FINE s for the first frames, then at 1/COARSE s to the truth's horizon
  (frontier.py's ``roll_out`` with a schedule, recorded and stopped at rest as its rows are).
Scored as the frontier scores. CPU ms a push, in this one process (bodies prepared and built outside the
timing): ``start`` the simulated start's steps and ``continuation`` the prior's prediction after it (its
body prepared before); ``whole`` a schedule's or a fixed step's whole roll-out. The frontier measures the
chosen schedule's cost, build included, beside every fixed step.

    python benchmarks/studies/step_schedule.py                 # the pybullet set, ~1 minute

Only the pybullet set: the wheel set is for measuring, never for choosing (frontier.py measures the chosen
schedule on both). docs/ablations.md, "The push's first milliseconds".
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import frontier as fr  # noqa: E402
from frontier_sets import collect_set, requests_from_store, truth_store  # noqa: E402

from physdyn.config import PhysicsConfig, config_from_dict  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.geometry.rotations import quat_conjugate, quat_multiply  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.predict.predictor import contact_prior_predictor  # noqa: E402
from physdyn.sim.bullet import pb  # noqa: E402
from physdyn.sim.trajectory import place_at_rest, topple_labels  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402

THEN_PRIOR = ((120, 3), (120, 6), (120, 8), (240, 3), (240, 6), (240, 8))  # (fine hz, recorded frames)
SCHEDULES = ((240, 8, 120), (240, 8, 60), (240, 6, 60), (240, 4, 60), (480, 4, 60), (240, 8, 30))


def then_prior(world: PhysicsWorld, bodies: dict, req: fr.Requests, frames: int, rate_hz: float) -> fr.Outcome:
    """The simulated start, then the prior; ``ms["continuation"]``: the prior's CPU ms a push (its body prepared)."""
    prior = contact_prior_predictor()
    fr.warm_up(prior, next(iter(bodies.values())).mesh)
    out = fr.Outcome.empty(len(req))
    spent = fine = 0.0
    steps = int(round(frames / rate_hz / world.physics.time_step))
    for r in range(len(req)):
        body_of = bodies[req.mesh[r]]
        spec = body_of.spec
        body = world.add_body(spec)
        p0 = place_at_rest(world, body, spec, req.q0[r])
        pb.resetBaseVelocity(body, req.v0[r].tolist(), req.w0[r].tolist(), physicsClientId=world.client)
        world.set_object_friction(body, req.friction[r] / world.physics.lateral_friction_ground)
        t0 = time.process_time()
        for _ in range(steps):
            world.step(1)
        fine += time.process_time() - t0
        p, q_base = pb.getBasePositionAndOrientation(body, physicsClientId=world.client)
        v, w = pb.getBaseVelocity(body, physicsClientId=world.client)
        world.remove_body(body)
        q = quat_multiply(np.asarray(q_base), quat_conjugate(spec.principal_quat_xyzw))
        rest = max(int(req.steps[r]) - frames, 1) / rate_hz
        t0 = time.process_time()
        result = prior.predict(body_of, v, w, seconds=rest, orientation_xyzw=q)
        spent += time.process_time() - t0
        path = result["com_position"]
        out.disp[r] = np.asarray(p) - p0 + path[-1] - path[0]
        out.q[r] = result["orientation_xyzw"][-1]
        out.toppled[r] = bool(topple_labels(np.stack([req.q0[r], q]))[0].any())
    out.ms["continuation"], out.ms["start"] = 1000 * spent / len(req), 1000 * fine / len(req)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", default="runs/frontier")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the meshes' preparation notes
    store = truth_store(collect_set("pybullet", Path(args.work), 60), 5)
    req = requests_from_store(store)
    rate = store.rate_hz
    physics = config_from_dict(PhysicsConfig, store.attrs["physics"])
    bodies = {key: prepare_body(load_mesh(key)) for key in dict.fromkeys(req.mesh)}

    def show(label: str, out: fr.Outcome) -> None:
        s = fr.score(req, out)
        cost = "; ms a push: " + ", ".join(f"{k} {v:.2f}" for k, v in out.ms.items()) if out.ms else ""
        print(f"{label:52s} position / sliding {s['position_over_sliding']:.3f}, rotation {s['rotation_deg']:.1f} deg, "
              f"topple {s['topple_accuracy']:.3f}{cost}", flush=True)

    for hz, frames in THEN_PRIOR:
        with PhysicsWorld(replace(physics, time_step=1.0 / hz)) as world:
            show(f"1/{hz} s for {frames / rate:.2f} s, then the contact prior", then_prior(world, bodies, req, frames, rate))
    def roll_outs(hz: int, plan: tuple[int, int, int] | None) -> fr.Outcome:
        """frontier.py's roll-outs; ms["whole"]: CPU ms a push (the body built before, outside the timing)."""
        out, spent = fr.Outcome.empty(len(req)), 0.0
        with PhysicsWorld(replace(physics, time_step=1.0 / hz)) as world:
            for r in range(len(req)):
                spec = bodies[req.mesh[r]].spec
                shape = world.collision_shape(spec)
                t0 = time.process_time()
                fr.roll_out(world, spec, shape, req, r, rate, out, plan)
                spent += time.process_time() - t0
        out.ms["whole"] = 1000 * spent / len(req)
        return out

    for plan in SCHEDULES:
        show(f"1/{plan[0]} s for {plan[1] / rate:.2f} s, then 1/{plan[2]} s", roll_outs(plan[0], plan))
    for hz in (240, 120, 60):
        show(f"1/{hz} s throughout (the frontier's row)", roll_outs(hz, None))


if __name__ == "__main__":
    main()
