"""Which screen, and what the correction and the final check are worth: variants of `physdyn plan`'s screened
search on benchmarks/planning.py's goals (real pushes of external meshes, upright, met within 2 cm and 15 deg
by PyBullet at 1/960 s on the mesh). docs/plan.md, "Choosing the search", and docs/research/index.md quote it.

    python benchmarks/studies/plan_screen.py --goals 50 --budget 1
    python benchmarks/studies/plan_screen.py --goals 50 --variants prior16 prior16-nocorr hull8 --hull-checkpoint runs/quickstart_hull/best.ckpt

Variants (NAME: screen x factor + ranking step, all with the final check unless "-nocheck"):
prior16 (the default), prior16-nocorr (no nearest-neighbour correction), prior16-120 (PyBullet 1/120 s ranks),
prior32-120, net4 (the bundled networks without simulator screen 4x), bundled-alone (the bundled model as the
search's only model, no check), hull8 (a network trained on
hull_surface clouds, --hull-checkpoint, screens 8x), fast16 and fast8 (the shipped `fast` model, nothing
simulated: the contact prior, its outcome correction and topple PointNet, screens 16x or 8x), and PyBullet alone
at 1/240, 1/120 and 1/60 s.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from external_meshes import external_store  # noqa: E402
from planning import goals_from_store  # noqa: E402

import physdyn.predict.planner as planner  # noqa: E402
from physdyn.predict.planner import Goal, verify_push  # noqa: E402
from physdyn.predict.predictor import load_predictor  # noqa: E402


def variants(predictor, hull, fast) -> dict[str, dict]:
    """name -> (Predictor.plan settings, screen factor, whether the correction runs)."""
    out = {
        "prior16": ({}, 16, True),
        "prior16-nocorr": ({}, 16, False),
        "prior16-nocheck": ({"check": False}, 16, True),
        "prior16-120": ({"pybullet_step": 1 / 120}, 16, True),
        "prior32-120": ({"pybullet_step": 1 / 120}, 32, True),
        "net4": ({"screen": "model"}, 4, True),
        "fast16": ({"screen": fast}, 16, True),
        "fast8": ({"screen": fast}, 8, True),
        "bundled-alone": ({"search": "model", "check": False}, 16, True),
        "pybullet-240": ({"search": "pybullet"}, 16, True),
        "pybullet-120": ({"search": "pybullet", "pybullet_step": 1 / 120}, 16, True),
        "pybullet-60": ({"search": "pybullet", "pybullet_step": 1 / 60}, 16, True),
    }
    if hull is not None:
        out["hull8"] = ({"screen": hull}, 8, True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--goals", type=int, default=50)
    ap.add_argument("--budget", type=float, default=1.0)
    ap.add_argument("--work", default="runs/external")
    ap.add_argument("--variants", nargs="+", default=None)
    ap.add_argument("--hull-checkpoint", default=None, help="a network on hull_surface clouds, for the hull8 variant")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    goals = goals_from_store(external_store(Path(args.work), 30, 10), args.goals)
    predictor = load_predictor("bundled")
    table = variants(predictor, load_predictor(args.hull_checkpoint) if args.hull_checkpoint else None, load_predictor("fast"))
    names = args.variants or list(table)
    search, factor, correct = planner.cross_entropy_search, planner.SCREEN_FACTOR, True
    rows: dict[str, list] = {n: [] for n in names}
    for g in goals:
        goal = Goal(xy=g["xy"], yaw=math.radians(g["yaw_deg"]), upright=True)
        for name in names:
            settings, planner.SCREEN_FACTOR, correct = table[name]
            planner.cross_entropy_search = lambda *a, _c=correct, **k: search(*a, **{**k, "correct": _c})
            plan = predictor.plan(g["mesh"], g["xy"], goal_yaw=g["yaw_deg"], upright=True, budget_s=args.budget,
                                  orientation_xyzw=g["orientation_xyzw"], seed=g["sim"], **settings)
            body = predictor._bodies([g["mesh"]], [1.0])[0]
            check = verify_push(body, plan["orientation_xyzw"], plan["lin_vel"], plan["ang_vel"], goal, predictor.rate_hz)
            rows[name].append((check["met"], 100 * check["miss_m"], check["miss_yaw_deg"], plan["candidates"], plan["screened"]))
        print(g["sim"], " | ".join(f"{n} {'met' if rows[n][-1][0] else '-'}" for n in names), flush=True)
    planner.cross_entropy_search, planner.SCREEN_FACTOR = search, factor
    print(f"\n{len(goals)} goals, {args.budget:g} s each\n\n| variant | goals met | median miss (cm / deg) | ranked | screened |\n|---|---|---|---|---|")
    for name in names:
        a = np.array(rows[name], dtype=float)
        print(f"| {name} | {100 * a[:, 0].mean():.0f} % ({int(a[:, 0].sum())}/{len(a)}) | {np.median(a[:, 1]):.1f} / "
              f"{np.median(a[:, 2]):.1f} | {a[:, 3].mean():.0f} | {a[:, 4].mean():.0f} |")


if __name__ == "__main__":
    main()
