"""Simulation throughput of the quickstart preset: simulations per second per core.

    python benchmarks/simulate.py              # 1/3 of the quickstart shapes, 1 and 2 workers
    python benchmarks/simulate.py --full       # the whole quickstart preset (6,000 simulations)

The figure covers the whole pipeline (shape generation, mass properties, stable poses, point sampling,
simulation, store writes), as `physdyn simulate` runs it.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from physdyn.config import DataConfig, load_config
from physdyn.data.simulated_store import generate_dataset

REPO = Path(__file__).resolve().parents[1]
TARGET_PER_CORE = 60.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="the whole quickstart preset")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    overrides = [] if args.full else [f"families.{f}.shapes=20" for f in ("primitives", "bottles", "mugs", "trashcans", "speakers")]
    cfg = load_config(DataConfig, REPO / "configs/data/quickstart.yaml", overrides)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; preset quickstart"
          f"{'' if args.full else ' (20 shapes per category)'}")
    base = None
    for workers in args.workers:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            report = generate_dataset(cfg, f"{tmp}/bench.zarr", workers=workers, progress=False)
            seconds = time.perf_counter() - t0
        rate = report.num_sims / seconds
        per_core = rate / workers
        base = base or rate
        print(f"workers={workers}: {report.num_sims} sims, {report.num_frames} frames in {seconds:.1f} s -> "
              f"{rate:.1f} sims/s, {per_core:.1f} sims/s per core (target >= {TARGET_PER_CORE:.0f}: "
              f"{'ok' if per_core >= TARGET_PER_CORE else 'BELOW'}); speed-up vs first {rate / base:.2f}x")


if __name__ == "__main__":
    main()
