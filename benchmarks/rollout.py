"""Prediction cost beside the simulator's: one trajectory at a time and in batches, same objects, same states.

    python benchmarks/rollout.py                      # the bundled model, on this machine's CPU
    python benchmarks/rollout.py --checkpoint runs/X/best.ckpt --device cuda --batches 64 1024 4096

Objects: the named meshes of pybullet_data (benchmarks/external_meshes.py), prepared once (``prepare_body``;
its time is reported on its own). States: pushes like the training data's (horizontal speed 0.5-2 m/s in a
random direction, spin about z up to 4 rad/s), from each object's resting pose in its mesh frame.

- PyBullet: ``simulate_from_state`` for ``--seconds`` at the conventions' 1/960 s step, recorded at the
  model's rate (a world per trajectory: collision shape, placing at rest, stepping).
- physdyn, one at a time: ``Predictor.predict`` through the public API, per trajectory.
- physdyn, in batches: ``Predictor.predict_many`` with B requests over the same meshes, per trajectory.

Figures are medians over repeats; ratios are physdyn's time over PyBullet's (below 1: cheaper). Times
depend on the machine and on what else runs on it: run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from external_meshes import NAMED, collect_meshes  # noqa: E402

from physdyn.predict.body import prepare_body  # noqa: E402
from physdyn.predict.predictor import load_predictor  # noqa: E402
from physdyn.predict.simulator import simulate_from_state  # noqa: E402


def pushes(count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0, 2 * np.pi, count)
    speed = rng.uniform(0.5, 2.0, count)
    lin = np.stack([speed * np.cos(heading), speed * np.sin(heading), np.zeros(count)], axis=1)
    ang = np.stack([np.zeros(count), np.zeros(count), rng.uniform(-4.0, 4.0, count)], axis=1)
    return lin, ang


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default="bundled", help="a .ckpt of `physdyn fit`, or fast / bundled (default: the bundled model)")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--device", default="cpu", help="cpu, cuda or auto")
    parser.add_argument("--batches", type=int, nargs="+", default=[64, 256, 1024, 4096])
    parser.add_argument("--singles", type=int, default=16, help="trajectories timed one at a time (each side)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore")
    predictor = load_predictor(args.checkpoint, device=args.device)
    with tempfile.TemporaryDirectory() as tmp:
        collect_meshes(Path(tmp), random_count=0)
        files = sorted(str(p) for p in Path(tmp).iterdir() if p.suffix == ".obj")
        t0 = time.perf_counter()
        bodies = [prepare_body(f) for f in files]
        prepare_ms = (time.perf_counter() - t0) / len(bodies) * 1e3
    rate = predictor.rate_hz
    steps = predictor.num_steps(args.seconds)
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__} "
          f"({torch.get_num_threads()} threads), device {args.device}"
          + (f" ({torch.cuda.get_device_name()})" if args.device != "cpu" and torch.cuda.is_available() else ""))
    print(f"model: {predictor.name}; {len(bodies)} pybullet_data meshes ({', '.join(Path(n).stem for n in NAMED)}), "
          f"{args.seconds:g} s = {steps} steps at {rate:g} Hz; mesh preparation {prepare_ms:.1f} ms per mesh (once)")

    n = args.singles
    lin, ang = pushes(max(n, max(args.batches)))
    pick = [bodies[i % len(bodies)] for i in range(len(lin))]
    for i in range(2):  # warm-up: imports, first allocations
        simulate_from_state(pick[i].spec, identity, lin[i], ang[i], rate, steps)
        predictor.predict(pick[i], lin[i], ang[i], args.seconds)
    sim_ms = np.median([median_time(lambda i=i: simulate_from_state(pick[i].spec, identity, lin[i], ang[i], rate, steps), 1)
                        for i in range(n)]) * 1e3
    one_ms = np.median([median_time(lambda i=i: predictor.predict(pick[i], lin[i], ang[i], args.seconds), 3)
                        for i in range(n)]) * 1e3
    rows = [("PyBullet, one at a time", sim_ms, 1.0), ("physdyn predict, one at a time", one_ms, one_ms / sim_ms)]
    for B in args.batches:
        repeats = 3 if B <= 1024 else 1
        predictor.predict_many(pick[: min(B, 8)], lin[: min(B, 8)], ang[: min(B, 8)], args.seconds)
        total = median_time(lambda B=B: predictor.predict_many(pick[:B], lin[:B], ang[:B], args.seconds), repeats)
        per = total / B * 1e3
        rows.append((f"physdyn predict_many, batch {B}", per, per / sim_ms))
    print(f"\n{'per trajectory':<34} {'ms':>9}  {'x PyBullet':>10}")
    for name, ms, ratio in rows:
        print(f"{name:<34} {ms:9.3f}  {ratio:10.4f}")


if __name__ == "__main__":
    main()
