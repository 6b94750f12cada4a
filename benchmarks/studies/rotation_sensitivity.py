"""How exactly must a predictor know the physics to land within 10 degrees? PyBullet itself at
the truth's step (1/960 s), on each mesh's own hull, restarted from the recorded step-0 state as
benchmarks/frontier.py's rows are, with one quantity changed by a small factor: the friction coefficient
(the scale of every friction force and torque: what a learned model's deceleration must get right), the
spin about the vertical at step 0, or the speed at step 0 (what an observation would give with that error).
Scored as the frontier scores (non-toppling medians; position as a fraction of Coulomb sliding's). The
unchanged row is the re-simulation floor, the frontier table's "PyBullet 1/960 s" row.

    python -m benchmarks.studies.rotation_sensitivity              # both frontier sets, ~6 minutes
    python -m benchmarks.studies.rotation_sensitivity --sets wheel --factors 1.01 0.99

Needs the frontier's truth stores (runs/frontier/{pybullet,wheel}/meshes_60_truth_x5.zarr, made by
benchmarks/frontier.py on first use). docs/research/friction-and-sensitivity.md.
"""

from __future__ import annotations

import argparse
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks import frontier as fr  # noqa: E402
from benchmarks.frontier_sets import collect_set, requests_from_store, truth_store  # noqa: E402

from physdyn.config import PhysicsConfig, config_from_dict  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402
from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.sim.world import PhysicsWorld  # noqa: E402

QUANTITIES = ("friction", "spin", "speed")


def perturbed(req: fr.Requests, quantity: str, factor: float) -> fr.Requests:
    """The requests with one quantity scaled by ``factor`` (the truth they are scored against unchanged)."""
    if quantity == "friction":
        return replace(req, friction=req.friction * factor)
    if quantity == "spin":
        w0 = req.w0.copy()
        w0[:, 2] *= factor
        return replace(req, w0=w0)
    return replace(req, v0=req.v0 * np.array([factor, factor, 1.0]))


def measure(set_name: str, work: Path, factors: list[float]) -> list[tuple[str, dict]]:
    meshes = collect_set(set_name, work, 60)
    store = truth_store(meshes, 5)
    req = requests_from_store(store)
    world = PhysicsWorld(config_from_dict(PhysicsConfig, store.attrs["physics"]))  # the truth's own step
    bodies = {}
    with warnings.catch_warnings():  # notes about a mesh (an open surface...) change nothing here
        warnings.simplefilter("ignore")
        for key in dict.fromkeys(map(str, store.source)):
            spec = prepare_body(load_mesh(key)).spec
            bodies[key] = (spec, world.collision_shape(spec))
    variants = [("unchanged (the re-simulation floor)", req)]
    variants += [(f"{q} x{f:g}", perturbed(req, q, f)) for q in QUANTITIES for f in factors]
    rows = []
    for name, changed in variants:
        out = fr.Outcome.empty(len(req))
        for r, key in enumerate(changed.mesh):
            spec, shape = bodies[key]
            fr.roll_out(world, spec, shape, changed, r, store.rate_hz, out)
        rows.append((name, fr.score(req, out)))  # scored against the unchanged truth
        s = rows[-1][1]
        print(f"  {set_name}: {name}: position / sliding {s['position_over_sliding']:.3f}, rotation "
              f"{s['rotation_deg']:.1f} deg, topple {s['topple_accuracy']:.3f}", flush=True)
    world.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", nargs="+", choices=("pybullet", "wheel"), default=["pybullet", "wheel"])
    ap.add_argument("--factors", nargs="+", type=float, default=[1.01, 0.99, 1.03, 0.97, 1.1, 0.9])
    ap.add_argument("--work", type=Path, default=Path("runs/frontier"))
    args = ap.parse_args()
    results = {s: measure(s, args.work, args.factors) for s in args.sets}
    print("\n| changed | " + " | ".join(f"{s}: position / sliding, rotation, topple" for s in args.sets) + " |")
    print("|---|" + "---|" * len(args.sets))
    for i, (name, _) in enumerate(results[args.sets[0]]):
        cells = [f"{r[i][1]['position_over_sliding']:.3f}, {r[i][1]['rotation_deg']:.1f}°, {r[i][1]['topple_accuracy']:.3f}"
                 for r in results.values()]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
