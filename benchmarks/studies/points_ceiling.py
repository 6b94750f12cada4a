"""Study: the information ceiling of a point representation — PyBullet itself, run at the data's step on the
convex hull of the points a model would see (with the body's true mass properties), against the truth.

A model fed a cloud cannot know more about contact than the cloud's hull tells; this is what a perfect model
of that input would score. Meshes: the external benchmark's (benchmarks/external_meshes.py, pybullet_data).

    python -m benchmarks.studies.points_ceiling [--work runs/external] [--points 256 512 1024] [--limit 0]
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np


from benchmarks.external_meshes import external_store  # noqa: E402
from physdyn.config import PhysicsConfig  # noqa: E402
from physdyn.eval.baselines import coulomb_slide  # noqa: E402
from physdyn.eval.metrics import rotation_angle_deg  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.predict.simulator import simulate_from_state  # noqa: E402
from physdyn.sim.cloud_body import cloud_body_spec  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="runs/external")
    ap.add_argument("--random", type=int, default=30)
    ap.add_argument("--random-from", type=int, default=0)
    ap.add_argument("--no-named", action="store_true")
    ap.add_argument("--points", type=int, nargs="+", default=[256, 512, 1024])
    ap.add_argument("--methods", nargs="+", default=["surface", "hull_surface"])
    ap.add_argument("--limit", type=int, default=0, help="at most this many pushes (0: all)")
    args = ap.parse_args()
    store = external_store(Path(args.work), args.random, 10, args.random_from, args.no_named)
    sims = np.arange(store.num_sims)
    if args.limit:
        sims = sims[:: max(1, len(sims) // args.limit)][: args.limit]
    rate, base = store.rate_hz, PhysicsConfig()
    bodies = {}
    rows: dict[str, list] = {}
    slide_err, moved, toppled = [], [], []
    variants = [("mesh hull", None, 0)] + [(f"{m} {n}", m, n) for m in args.methods for n in args.points]
    hull_sizes = []
    for m in sims:
        path = str(store.source[store.shape_id[m]])
        if path not in bodies:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                bodies[path] = prepare_body(path)
            hull_sizes.append(len(bodies[path].spec.hull_vertices))
        body = bodies[path]
        f = store.frames(int(m))
        T = f.stop - f.start
        p, q = store.com_position[f], store.orientation_xyzw[f]
        v0, w0 = store.linear_velocity[f.start], store.angular_velocity[f.start]
        phys = replace(base, lateral_friction_object=float(store.friction[m]) / base.lateral_friction_ground)
        true_disp = p[-1] - p[0]
        slide = coulomb_slide(p[:1], q[:1], v0[None], w0[None], T - 1, store.friction[m], rate)
        slide_err.append(float(np.linalg.norm((slide.com_position[0, -1] - p[0]) - true_disp)))
        toppled.append(bool(store.toppled[m]))
        spec = body.spec
        per_mass = (spec.principal_axes * spec.inertia_diag) @ spec.principal_axes.T / spec.mass
        for name, method, n in variants:
            sim_spec = spec if method is None else cloud_body_spec(body.points_body(n, method), per_mass)
            out = simulate_from_state(sim_spec, q[0], v0, w0, rate, T, phys)
            sp, sq = out["com_position"], out["orientation_xyzw"]
            rows.setdefault(name, []).append((float(np.linalg.norm((sp[-1] - sp[0]) - true_disp)),
                                              float(rotation_angle_deg(sq[-1], q[-1])), bool(out["topple_label"].any())))
    slide_err, toppled = np.asarray(slide_err), np.asarray(toppled)
    nt = ~toppled
    print(f"{len(bodies)} meshes (hull vertices: median {np.median(hull_sizes):.0f}, max {max(hull_sizes)}), {len(sims)} "
          f"pushes ({nt.sum()} do not topple); PyBullet at {1 / base.time_step:g} Hz on the hull of each set, the "
          f"body's own mass properties")
    print("| points | position / sliding | final position (cm) | rotation (deg) | topple acc. |")
    print("|---|---|---|---|---|")
    for name, vals in rows.items():
        pos, rot, top = (np.asarray(x) for x in zip(*vals))
        print(f"| {name} | {np.median(pos[nt]) / np.median(slide_err[nt]):.3f} | {100 * np.median(pos[nt]):.2f} | "
              f"{np.median(rot[nt]):.1f} | {np.mean(top == toppled):.3f} |")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)")
