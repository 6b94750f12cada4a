"""`physdyn plan` on meshes training never saw: goals met at equal wall-clock budgets, physdyn's planner (its
fast model screening candidates for PyBullet) against the same planner with PyBullet at 1/240, 1/120 and
1/60 s alone, each with and without the final check at the conventions' step.

    python benchmarks/planning.py --goals 50 --budgets 1 --json plan.json         # docs/plan.md's table (~15 min)
    python benchmarks/planning.py --goals 50 --budgets 0.2 1 5                    # every budget (about 1.5 h)

1. Goals: real pushes of the external meshes (benchmarks/external_meshes.py: pybullet_data's named objects and
   random_urdfs, simulated per the conventions at 1/960 s), one push per mesh in turn, only pushes that do
   not topple. A goal is the push's displacement of the centre of mass on the plane and its turn about the
   vertical between the rest poses (the store's step 0, one physics step after the push, stands for the
   rest pose: ~1 mm off), upright: so every goal is reachable.
2. Each planner gets the mesh placed in the push's resting orientation, the goal and the budget, one torch
   thread (one core). The learned model's one-time set-up in the process is done before the first goal.
3. A goal is met when PyBullet at 1/960 s on the mesh, from the returned lin_vel / ang_vel and the placed
   mesh, ends within 2 cm and 15 deg of it, upright (``physdyn.plan.verify_push``, run by ``plan_push`` with ``verify``).
Reports, per budget and planner: goals met, the median miss (cm, deg) of that check, the goals the planner's
own model said it met (the search's failures apart from the model's errors), candidates per second.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from external_meshes import external_store  # python benchmarks/planning.py: Python puts this folder on the path

from physdyn.plan import PlanOptions, plan_push
from physdyn.plan.goal import turn_about_vertical
from physdyn.predict.predictor import load_predictor

# name -> the plan's options (physdyn.plan.PlanOptions). The same planner throughout (cross-entropy rounds, the budget's clock);
# what differs is what rolls out the candidates, and whether the last fifth of the budget re-checks the
# best 8 at the conventions' step.
PLANNERS = {
    "physdyn (default: contact-prior screen, PyBullet 1/240 s ranks, check)": PlanOptions(),
    "physdyn (networks screen, PyBullet 1/240 s ranks, check)": PlanOptions(screen="model"),
    "physdyn (bundled model alone)": PlanOptions(search="model", check=False),
    "pybullet 1/240 s, check": PlanOptions(search="pybullet", pybullet_step=1 / 240),
    "pybullet 1/120 s, check": PlanOptions(search="pybullet", pybullet_step=1 / 120),
    "pybullet 1/60 s, check": PlanOptions(search="pybullet", pybullet_step=1 / 60),
    "pybullet 1/240 s": PlanOptions(search="pybullet", pybullet_step=1 / 240, check=False),
    "pybullet 1/120 s": PlanOptions(search="pybullet", pybullet_step=1 / 120, check=False),
    "pybullet 1/60 s": PlanOptions(search="pybullet", pybullet_step=1 / 60, check=False),
}
DEFAULT_PLANNERS = [name for name in PLANNERS if "bundled" not in name]  # the bundled model alone: --planners


def goals_from_store(store, count: int) -> list[dict]:
    """Up to ``count`` non-toppling pushes, one per mesh in turn (the first of each, then the second...)."""
    by_shape: dict[int, list[int]] = {}
    for i in range(store.num_sims):
        if not store.toppled[i]:
            by_shape.setdefault(int(store.shape_id[i]), []).append(i)
    order = [sims[k] for k in range(max(map(len, by_shape.values()))) for sims in by_shape.values() if k < len(sims)]
    goals = []
    for i in order[:count]:
        f = store.frames(i)
        p, q = store.com_position[f], store.orientation_xyzw[f]
        goals.append({"sim": int(i), "mesh": str(store.source[store.shape_id[i]]), "orientation_xyzw": q[0],
                      "xy": p[-1, :2] - p[0, :2], "yaw_deg": math.degrees(float(turn_about_vertical(q[0], q[-1])))})
    return goals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default="bundled", help="default: the bundled model")
    parser.add_argument("--work", default="runs/external", help="where benchmarks/external_meshes.py keeps its store")
    parser.add_argument("--random", type=int, default=30)
    parser.add_argument("--pushes", type=int, default=10)
    parser.add_argument("--goals", type=int, default=50)
    parser.add_argument("--budgets", type=float, nargs="+", default=[0.2, 1.0, 5.0])
    parser.add_argument("--planners", nargs="+", default=DEFAULT_PLANNERS, choices=list(PLANNERS), metavar="NAME",
                        help="which planners (default: all but the bundled model alone): " + "; ".join(PLANNERS))
    parser.add_argument("--json", default=None, help="also write every plan's figures here")
    parser.add_argument("--screen-checkpoint", action="append", default=[], metavar="CKPT",
                        help="also the default planner with this checkpoint's model as its screen (repeatable), "
                             "e.g. the contact prior with its outcome correction (physdyn fit-outcome)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    store = external_store(Path(args.work), args.random, args.pushes)
    goals = goals_from_store(store, args.goals)
    predictor = load_predictor(args.checkpoint)
    for path in args.screen_checkpoint:  # the same search, another screen (handed the body the planner prepared)
        name = f"physdyn ({Path(path).stem} screen, PyBullet 1/240 s ranks, check)"
        PLANNERS[name] = PlanOptions(screen=load_predictor(path))
        args.planners.append(name)
    rows = []
    started = time.perf_counter()
    for g in goals:
        for budget in args.budgets:
            for name in args.planners:
                # verified after the search's clock stops: PyBullet at the conventions' step on the mesh
                options = replace(PLANNERS[name], seed=g["sim"], verify=True)
                plan = plan_push(predictor, g["mesh"], g["xy"], g["yaw_deg"], True, budget, g["orientation_xyzw"], options)
                check = plan["verified"]
                rows.append({"sim": g["sim"], "mesh": Path(g["mesh"]).stem, "budget_s": budget, "planner": name,
                             "met": check["met"], "miss_cm": 100 * check["miss_m"], "miss_deg": check["miss_yaw_deg"],
                             "toppled": check["toppled"], "predicted_miss_cm": 100 * plan["predicted"]["miss_m"],
                             "predicted_miss_deg": plan["predicted"]["miss_yaw_deg"], "predicted_met": plan["predicted"]["met"],
                             "candidates": plan["candidates"], "screened": plan["screened"], "elapsed_s": plan["elapsed_s"],
                             "goal_cm": 100 * float(np.linalg.norm(g["xy"])), "goal_deg": g["yaw_deg"]})
        done = rows[-len(args.budgets) * len(args.planners):]
        print(f"sim {g['sim']} ({Path(g['mesh']).stem}): " + ", ".join(
            f"{r['planner']}@{r['budget_s']:g}s {'met' if r['met'] else 'no'} {r['miss_cm']:.1f}cm/{r['miss_deg']:.0f}deg"
            for r in done), flush=True)
    seconds = time.perf_counter() - started
    print(f"\n{len(goals)} goals from real pushes of {len({g['mesh'] for g in goals})} external meshes, "
          f"{seconds:.0f} s; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores\n")
    print("| budget per goal | planner | goals met | median miss (cm) | median miss (deg) | met as predicted | "
          "candidates per second (screened) |")
    print("|---|---|---|---|---|---|---|")
    table = []
    for budget in args.budgets:
        for name in args.planners:
            rs = [r for r in rows if r["budget_s"] == budget and r["planner"] == name]
            met = np.mean([r["met"] for r in rs])
            rate = sum(r["candidates"] for r in rs) / sum(r["elapsed_s"] for r in rs)
            screened = sum(r["screened"] for r in rs) / sum(r["elapsed_s"] for r in rs)
            predicted = np.mean([r["predicted_met"] for r in rs])  # the search's own verdict: model error apart
            line = {"budget_s": budget, "planner": name, "met": float(met), "predicted_met": float(predicted), "median_miss_cm": float(np.median([r["miss_cm"] for r in rs])),
                    "median_miss_deg": float(np.median([r["miss_deg"] for r in rs])), "candidates_per_s": float(rate),
                    "screened_per_s": float(screened)}
            table.append(line)
            print(f"| {budget:g} s | {name} | {100 * met:.0f} % ({sum(r['met'] for r in rs)}/{len(rs)}) | "
                  f"{line['median_miss_cm']:.1f} | {line['median_miss_deg']:.1f} | {100 * predicted:.0f} % | {rate:.0f}"
                  + (f" ({screened:.0f})" if screened else "") + " |")
    if args.json:
        Path(args.json).write_text(json.dumps({"table": table, "plans": rows, "seconds": seconds}, indent=1))


if __name__ == "__main__":
    main()
