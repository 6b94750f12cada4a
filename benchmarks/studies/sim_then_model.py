"""Study: simulate the first K steps from the cloud, then let the model continue.

The topple classifier already rolls the cloud's hull out in PyBullet for 1 s. Where does the rest of a
push's error come from — the first second, or what follows? For each push of a store's split: the
cloud_sim roll-out for K steps (the body's own inertia, 1/240 s), then the model rolled out with those K
steps' velocities as its warm start (its recurrent state follows the simulated motion), and the two
spliced: the simulated states up to step K, then the model's changes applied from the simulated state at
step K. Prints the final position and rotation (non-toppling medians) of the model alone, cloud_sim alone
and the splice for each K, and the seconds each takes.

    python -m benchmarks.studies.sim_then_model STORE [SPLIT] [--checkpoint CKPT] [--steps 8 15 30]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from physdyn.data.store import load_store
from physdyn.data.windows import store_spin_inertia, store_world_inertia
from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import gather_truth, select_sequences
from physdyn.eval.metrics import final_errors
from physdyn.eval.rollout import RolloutOptions, rollout
from physdyn.geometry.rotations import quat_conjugate, quat_multiply
from physdyn.predict.predictor import BUNDLED_CHECKPOINT
from physdyn.sim.cloud_body import CloudSimulator


def splice(sim: dict, model, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Simulated states to step K, then the model's motion since its own step K, from the simulated state."""
    p, q = model.com_position.copy(), model.orientation_xyzw.copy()
    p[:, : K + 1], q[:, : K + 1] = sim["com_position"], sim["orientation_xyzw"]
    turn = quat_multiply(model.orientation_xyzw[:, K + 1 :], quat_conjugate(model.orientation_xyzw[:, K : K + 1]))
    q[:, K + 1 :] = quat_multiply(turn, np.repeat(sim["orientation_xyzw"][:, K : K + 1], turn.shape[1], axis=1))
    p[:, K + 1 :] = sim["com_position"][:, K : K + 1] + model.com_position[:, K + 1 :] - model.com_position[:, K : K + 1]
    return p, q


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store")
    ap.add_argument("split", nargs="?", default="test")
    ap.add_argument("--checkpoint", default=str(BUNDLED_CHECKPOINT))
    ap.add_argument("--steps", type=int, nargs="+", default=[8, 15, 30])
    args = ap.parse_args()
    store = load_store(args.store)
    model = load_checkpoint(args.checkpoint)  # the network alone: the trajectories are the question here
    sims = select_sequences(store, args.split)
    truth = gather_truth(store, sims)
    S = truth["delta_position"].shape[1]
    p0, q0 = truth["com_position"][:, 0], truth["orientation_xyzw"][:, 0]
    v0, w0 = truth["linear_velocity"][:, 0], truth["angular_velocity"][:, 0]
    points = store.points[store.shape_id[sims]]
    subset = points[:, np.random.default_rng(0).permutation(points.shape[1])[: model.num_points or points.shape[1]]]
    standing = ~truth["toppled"]
    spin = store_spin_inertia(store, sims, q0)

    def report(name: str, p: np.ndarray, q: np.ndarray, seconds: float) -> None:
        e = final_errors(p, q, truth["com_position"], truth["orientation_xyzw"], truth["last"])
        print(f"  {name:<34} {100 * np.median(e['position_m'][standing]):6.2f} cm {np.median(e['rotation_deg'][standing]):6.1f} deg"
              f"   {1000 * seconds / len(sims):6.2f} ms/push", flush=True)

    print(f"{args.store} ({args.split}: {len(sims)} pushes, {int(standing.sum())} do not topple), {args.checkpoint}")
    t = time.perf_counter()
    alone = rollout(model, subset, q0, p0, v0, w0, S, RolloutOptions(spin_inertia=spin))
    report("model alone", alone.com_position, alone.orientation_xyzw, time.perf_counter() - t)
    inertia = store_world_inertia(store, sims, np.tile([0.0, 0.0, 0.0, 1.0], (len(sims), 1)))
    with CloudSimulator() as simulator:
        t = time.perf_counter()
        whole = simulator.trajectories(points, q0, p0, v0, w0, truth["friction"], S, store.rate_hz, inertia)
        report("cloud_sim alone", whole["com_position"], whole["orientation_xyzw"], time.perf_counter() - t)
        for K in args.steps:
            t = time.perf_counter()
            first = simulator.trajectories(points, q0, p0, v0, w0, truth["friction"], K, store.rate_hz, inertia)
            warm = (first["linear_velocity"][:, 1:], first["angular_velocity"][:, 1:])
            continued = rollout(model, subset, q0, p0, v0, w0, S, RolloutOptions(warm_start_velocities=warm, spin_inertia=spin))
            p, q = splice(first, continued, K)
            report(f"cloud_sim {K} steps, then the model", p, q, time.perf_counter() - t)


if __name__ == "__main__":
    main()
