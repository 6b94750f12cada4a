"""Where does PyBullet need its fine step? Most of what the shipped predictors lose is lost while the push's
contact settles (impulse_start.py: from the truth's state at 0.4 s the contact prior alone beats PyBullet at
1/120 s in position and rotation). So spend the fine step there only, and continue (1) with the contact prior, or (2) with PyBullet at
a coarse step: which continuation is as accurate for less?

For every push of a frontier set, on the mesh's own hull, from the recorded step-0 state as
benchmarks/frontier.py's rows are:
- ``prior``: PyBullet at 1/FINE s for the first frames, then the contact prior from that state (its path
  added; toppled where the simulated part tilted past 45 degrees: the prior never topples);
- ``schedule``: PyBullet at 1/FINE s for the first frames, then at 1/COARSE s to the truth's horizon
  (frontier.py's ``roll_out`` with a schedule, recorded and stopped at rest as its rows are).
Scored as the frontier scores. CPU ms a push, in this one process, the fastest of ``--repeats`` timings
of each push (bodies prepared and their collision shapes built outside the timing): ``whole`` from placing the body to the answer, for every
row alike, and for the prior rows ``continuation``, the prior's part of it. The frontier measures the chosen
schedule's cost, build included and the fastest of three, beside every fixed step.

    python -m benchmarks.studies.step_schedule                 # the pybullet set, ~2 minutes

Only the pybullet set: the wheel set is for measuring, never for choosing (frontier.py measures the chosen
schedule on both). docs/research/impact-phase.md.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks import frontier as fr  # noqa: E402
from benchmarks.frontier_sets import collect_set, requests_from_store, truth_store  # noqa: E402

from physdyn.config import PhysicsConfig, config_from_dict  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.predict.predictor import contact_prior_predictor  # noqa: E402
from physdyn.sim.trajectory import record  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402

THEN_PRIOR = ((120, 3), (120, 6), (120, 8), (240, 3), (240, 6), (240, 8))  # (fine hz, recorded frames)
SCHEDULES = ((240, 8, 120), (240, 8, 60), (240, 6, 60), (240, 4, 60), (480, 4, 60), (240, 8, 30))


def then_prior(world: PhysicsWorld, bodies: dict, req: fr.Requests, frames: int, rate_hz: float,
               repeats: int) -> fr.Outcome:
    """The simulated start (recorded as frontier.py's ``roll_out`` records, stopping early at rest), then the
    prior from its last state. ``ms``: CPU ms a push, the fastest of ``repeats``: ``whole`` from placing the
    body to the prior's answer (as the other rows' ``whole``), ``continuation`` the prior's part (its body
    prepared before)."""
    prior = contact_prior_predictor()
    fr.warm_up(prior, next(iter(bodies.values())).mesh)
    out = fr.Outcome.empty(len(req))
    whole = continuation = 0.0
    for r in range(len(req)):
        body_of = bodies[req.mesh[r]]
        spec = body_of.spec
        shape = world.collision_shape(spec)
        fastest = (np.inf, np.inf)
        for _ in range(repeats):
            t0 = time.process_time()
            body = fr.pushed_body(world, spec, req, r, shape)
            start = record(world, body, spec, rate_hz, max_frames=min(frames, int(req.steps[r])) + 1)
            world.remove_body(body)
            path, turns, toppled = start.com_position, start.orientation_xyzw, start.topple_step >= 0
            t1 = time.process_time()
            left = int(req.steps[r]) + 1 - len(start)
            if left > 0 and len(start) == frames + 1:  # neither at rest nor at the horizon: the prior goes on
                v, w = start.linear_velocity[-1], start.angular_velocity[-1]
                result = prior.predict(body_of, v, w, seconds=left / rate_hz, orientation_xyzw=turns[-1])
                path = np.concatenate([path, path[-1] + result["com_position"][1:] - result["com_position"][0]])
                turns = np.concatenate([turns, result["orientation_xyzw"][1:]])
            t2 = time.process_time()
            fastest = (min(fastest[0], t2 - t0), min(fastest[1], t2 - t1))
        whole, continuation = whole + fastest[0], continuation + fastest[1]
        out.set(r, path, turns, toppled)
    out.ms["whole"], out.ms["continuation"] = 1000 * whole / len(req), 1000 * continuation / len(req)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", default="runs/frontier")
    parser.add_argument("--repeats", type=int, default=3, help="timings of each push, the fastest kept (as the frontier's)")
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
            show(f"1/{hz} s for {frames / rate:.2f} s, then the contact prior",
                 then_prior(world, bodies, req, frames, rate, args.repeats))
    def roll_outs(hz: int, plan: tuple[int, int, int] | None) -> fr.Outcome:
        """frontier.py's roll-outs; ms["whole"]: CPU ms a push, the fastest of ``--repeats`` (the body built before)."""
        out, spent = fr.Outcome.empty(len(req)), 0.0
        with PhysicsWorld(replace(physics, time_step=1.0 / hz)) as world:
            for r in range(len(req)):
                spec = bodies[req.mesh[r]].spec
                shape = world.collision_shape(spec)
                spent += fr.best_of(args.repeats, lambda _: fr.roll_out(world, spec, shape, req, r, rate, out, plan))[0]
        out.ms["whole"] = 1000 * spent / len(req)
        return out

    for plan in SCHEDULES:
        show(f"1/{plan[0]} s for {plan[1] / rate:.2f} s, then 1/{plan[2]} s", roll_outs(plan[0], plan))
    for hz in (240, 120, 60):
        show(f"1/{hz} s throughout (the frontier's row)", roll_outs(hz, None))


if __name__ == "__main__":
    main()
