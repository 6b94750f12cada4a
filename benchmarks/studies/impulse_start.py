"""Is the turn lost in the push's first milliseconds? The recorded step-0 state still tilts (the push's spin
about a horizontal axis), so the ground's next contact solve is an impulse: part of the first 1/15 s's
change of spin and speed happens within the first 1/960 s steps. If that impulse were what the shipped
predictors miss, an impact model of one step (a small contact solve at step 0) would be the lever.

For every push of a frontier set, PyBullet at the truth's step (1/960 s) on the mesh's own hull, restarted
from the recorded step-0 state as benchmarks/frontier.py's rows are, gives (1) the change of spin and speed
after k physics steps as a fraction of the change over the first 1/15 s (a steady deceleration would give
k / 64), and (2) its state after k steps, from which `fast` and the contact prior then predict the rest
(their displacement added to what the truth moved in those k steps). Scored as the frontier scores
(non-toppling medians; position as a fraction of Coulomb sliding's). Starting from the truth after k steps
tells what knowing the first k / 960 s exactly is worth.

    python -m benchmarks.studies.impulse_start                 # the pybullet set, ~30 s
    python -m benchmarks.studies.impulse_start --steps 0 2 384

Needs the frontier's truth store (runs/frontier/pybullet/meshes_60_truth_x5.zarr, made by
benchmarks/frontier.py on first use). Only the pybullet set: the wheel set is for measuring, not for
choosing a lever. docs/research/impact-phase.md.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from benchmarks import frontier as fr  # noqa: E402
from benchmarks.frontier_sets import collect_set, requests_from_store, truth_store  # noqa: E402

from physdyn.config import PhysicsConfig, config_from_dict  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.geometry.rotations import quat_conjugate, quat_multiply  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.predict.predictor import contact_prior_predictor, load_predictor  # noqa: E402
from physdyn.sim.bullet import pb  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402

FIRST_FRAME = 64  # physics steps of 1/960 s in the first recorded step (15 Hz)
FRACTION_STEPS = (1, 2, 4, 8, 16, 32)


def truth_states(req: fr.Requests, physics: PhysicsConfig, parsed: dict, steps: list[int]) -> dict[str, np.ndarray]:
    """PyBullet from each request's step-0 state: position, mesh-frame orientation and velocities after
    each of ``steps`` physics steps (R, len(steps), .), and spin and speed after every step of the first
    recorded frame (R, FIRST_FRAME + 1)."""
    R, K = len(req), len(steps)
    out = {"p": np.zeros((R, K, 3)), "q": np.zeros((R, K, 4)), "v": np.zeros((R, K, 3)), "w": np.zeros((R, K, 3)),
           "spin": np.zeros((R, FIRST_FRAME + 1)), "speed": np.zeros((R, FIRST_FRAME + 1))}
    specs: dict[str, object] = {}
    with PhysicsWorld(physics) as world:
        for r in range(R):
            spec = specs.get(req.mesh[r]) or specs.setdefault(req.mesh[r], prepare_body(parsed[req.mesh[r]]).spec)
            body = fr.pushed_body(world, spec, req, r)
            for k in range(max(max(steps), FIRST_FRAME) + 1):
                v, w = pb.getBaseVelocity(body, physicsClientId=world.client)
                if k <= FIRST_FRAME:
                    out["spin"][r, k], out["speed"][r, k] = w[2], np.hypot(v[0], v[1])
                if k in steps:
                    j = steps.index(k)
                    p, q_base = pb.getBasePositionAndOrientation(body, physicsClientId=world.client)
                    out["p"][r, j], out["v"][r, j], out["w"][r, j] = p, v, w
                    # PyBullet's base frame is the principal frame: R_mesh = R_base A^T
                    out["q"][r, j] = quat_multiply(np.asarray(q_base), quat_conjugate(spec.principal_quat_xyzw))
                world.step(1)
            world.remove_body(body)
    return out


def print_fractions(req: fr.Requests, states: dict[str, np.ndarray]) -> None:
    still = ~req.toppled
    print(f"step 0, {still.sum()} non-toppling pushes: median spin about a horizontal axis "
          f"{np.median(np.linalg.norm(req.w0[still, :2], axis=1)):.1f} rad/s, about the vertical "
          f"{np.median(np.abs(req.w0[still, 2])):.1f} rad/s")
    for name in ("spin", "speed"):
        x = states[name]
        whole = x[:, FIRST_FRAME] - x[:, 0]
        print(f"{name}: the first 1/15 s changes it by {np.median(np.abs(whole[still] / np.abs(x[still, 0]))):.1%} "
              f"of its step-0 value (median, {still.sum()} non-toppling pushes)")
        for k in FRACTION_STEPS:
            frac = ((x[:, k] - x[:, 0]) / np.where(np.abs(whole) > 1e-9, whole, np.nan))[still]
            print(f"  after {k:2d} physics steps ({1000 * k / 960:4.1f} ms): {np.nanmedian(frac):.2f} of that change "
                  f"(quartiles {np.nanpercentile(frac, 25):.2f}-{np.nanpercentile(frac, 75):.2f}; "
                  f"a steady rate: {k / FIRST_FRAME:.2f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", default="runs/frontier")
    parser.add_argument("--steps", type=int, nargs="+", default=[0, 1, 2, 4, 8, 16, 64, 384],
                        help="physics steps (1/960 s) of truth before the predictors take over")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the meshes' preparation notes, once per prediction
    steps = sorted(set(args.steps) | {0})
    meshes = collect_set("pybullet", Path(args.work), 60)
    store = truth_store(meshes, 5)
    req = requests_from_store(store)
    parsed = {key: load_mesh(key) for key in dict.fromkeys(req.mesh)}
    states = truth_states(req, config_from_dict(PhysicsConfig, store.attrs["physics"]), parsed, steps)
    print_fractions(req, states)
    for name, predictor in (("fast", load_predictor("fast")), ("contact_prior", contact_prior_predictor())):
        for j, k in enumerate(steps):
            out = fr.Outcome.empty(len(req))
            for r in range(len(req)):
                result = predictor.predict(parsed[req.mesh[r]], states["v"][r, j], states["w"][r, j],
                                           seconds=req.steps[r] / predictor.rate_hz, orientation_xyzw=states["q"][r, j])
                p = result["com_position"]
                out.disp[r] = states["p"][r, j] - states["p"][r, 0] + p[-1] - p[0]
                out.q[r], out.toppled[r] = result["orientation_xyzw"][-1], result["toppled"]
            s = fr.score(req, out)
            print(f"{name:13s} from the truth after {k:3d} steps ({1000 * k / 960:5.1f} ms): position / sliding "
                  f"{s['position_over_sliding']:.3f}, rotation {s['rotation_deg']:.1f} deg, topple {s['topple_accuracy']:.3f}",
                  flush=True)


if __name__ == "__main__":
    main()
