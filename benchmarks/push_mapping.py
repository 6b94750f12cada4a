"""How far the ideal free-body impulse formula is from PyBullet's response to the same push, and what the
PyBullet step costs: the measurement behind ``physdyn.plan.push`` (docs/plan.md, "The push").

    python benchmarks/push_mapping.py                 # 20 external meshes x 10 generator pushes

Pushes are drawn as the dataset generator draws them (``physdyn.sim.impulse.sample_initial_condition``: a
stable pose, a heading, a point near the centre-of-mass height, 0.5-2 m/s) on the meshes of
benchmarks/external_meshes.py. PyBullet's response is the generator's: a force J / dt over one physics step
(1/960 s) at the point, the ground reacting (``PushResponse.velocities``). The formula: v = J / m,
w = I^-1 (r x J) (``free_body_velocities``).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from external_meshes import collect_meshes  # noqa: E402

from physdyn.config import DataConfig, PhysicsConfig  # noqa: E402
from physdyn.geometry.poses import stable_orientations  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.plan.push import PushResponse, free_body_velocities  # noqa: E402
from physdyn.sim.impulse import sample_initial_condition  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", default="runs/external", help="where benchmarks/external_meshes.py keeps its meshes")
    parser.add_argument("--meshes", type=int, default=20)
    parser.add_argument("--pushes", type=int, default=10, help="per mesh")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    folder = Path(args.work) / "meshes"
    if not folder.is_dir():
        collect_meshes(folder, 30)
    rng = np.random.default_rng(0)
    rows, seconds = [], []
    with PhysicsWorld(PhysicsConfig()) as world:
        for path in sorted(folder.glob("*.obj"))[: args.meshes]:
            body = prepare_body(path)
            rotations, probabilities = stable_orientations(body.mesh, body.spec.com_mesh)
            handle = world.add_body(body.spec)
            for _ in range(args.pushes):
                init, _ = sample_initial_condition(rng, world, handle, body.spec, rotations, probabilities, DataConfig())
                with PushResponse(body.spec, init.orientation_xyzw) as response:
                    v, w = response.velocities(init.impulse_point[None], init.impulse[None])
                    t0 = time.perf_counter()  # what a push costs in a planner's batch: the world is made already
                    response.velocities(np.repeat(init.impulse_point[None], 16, 0), np.repeat(init.impulse[None], 16, 0))
                    seconds.append((time.perf_counter() - t0) / 16)
                    vf, wf = free_body_velocities(body.spec, init.orientation_xyzw, response.com, init.impulse_point[None], init.impulse[None])
                speed = float(np.linalg.norm(init.impulse)) / body.spec.mass
                rows.append([np.linalg.norm(v[0, :2] - vf[0, :2]) / speed, abs(w[0, 2] - wf[0, 2]) / max(abs(wf[0, 2]), 1e-9),
                             np.linalg.norm(w[0, :2] - wf[0, :2]), np.linalg.norm(w[0, :2]), abs(v[0, 2] - vf[0, 2])])
            world.remove_body(handle)
    r = np.asarray(rows)
    pct = lambda col: (np.median(r[:, col]), np.percentile(r[:, col], 90))  # noqa: E731
    print(f"{len(r)} pushes on {args.meshes} external meshes; formula against PyBullet's one-step response (median, 90th percentile):")
    print("  horizontal speed, relative: %.2f %%, %.1f %%" % tuple(100 * x for x in pct(0)))
    print("  yaw rate, relative: %.2f %%, %.1f %%" % tuple(100 * x for x in pct(1)))
    print("  tilt rate |w_xy|, absolute: %.2f, %.1f rad/s (PyBullet's own median %.1f rad/s)" % (*pct(2), np.median(r[:, 3])))
    print("  vertical velocity, absolute: %.3f, %.2f m/s" % pct(4))
    print(f"  PyBullet step per push: median {1e6 * np.median(seconds):.0f} us")


if __name__ == "__main__":
    main()
