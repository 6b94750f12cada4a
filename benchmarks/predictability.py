"""How predictable is the simulated motion itself? The floor under any model's errors.

    python benchmarks/predictability.py                                   # the external meshes' store
    python benchmarks/predictability.py --store runs/external_val/external_60x10_from30_unnamed.zarr --eps 0.01

Each non-toppling push of a store made from mesh files (``benchmarks/external_meshes.py`` writes them) is
simulated again in PyBullet from its recorded step-0 state (``physdyn.predict.simulator``, as
``--compare-sim`` does), once as it is and once with v0 and w0 each turned by a random relative amount
``--eps``. Printed: how far the plain re-simulation ends from the store (the re-simulation's own error)
and how far the perturbed one ends from the plain one (what a change of eps in the inputs does), as
medians of the final rotation (deg) and position (cm), by the push's initial spin |w_z| since fast spins
carry the rotation error; then the rocking just after the push (vertical velocity and tilt spin changes
over the first 2 s at 15 and 30 Hz, as a share of the velocity changes' sum, Table 1's denominator) and
how much of it the perturbation changes: the part of it no model could predict.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from physdyn.data.store import load_store
from physdyn.eval.metrics import rotation_angle_deg
from physdyn.predict.body import prepare_body
from physdyn.predict.simulator import simulate_from_state

BANDS = ((0, 5), (5, 10), (10, 20), (20, np.inf))  # rad/s


def perturbed(x: np.ndarray, eps: float, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=3)
    return x + eps * np.linalg.norm(x) * d / np.linalg.norm(d)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", default="runs/external/external_30x10.zarr")
    parser.add_argument("--eps", type=float, default=1e-3, help="relative change of v0 and w0 (default 0.1 %%)")
    parser.add_argument("--rocking-pushes", type=int, default=150, help="pushes for the rocking part")
    args = parser.parse_args()
    store, rng, bodies = load_store(args.store), np.random.default_rng(0), {}
    rate = float(store.rate_hz)
    sims = np.flatnonzero(~store.toppled.astype(bool))
    t0 = time.perf_counter()

    def body(i: int):
        path = str(store.source[store.shape_id[i]])
        return bodies.setdefault(path, prepare_body(path)).spec

    def moved(sim: dict) -> np.ndarray:
        return sim["com_position"][-1] - sim["com_position"][0]

    rows = []
    for i in sims:
        f = store.frames(i)
        p, q = store.com_position[f], store.orientation_xyzw[f]
        v0, w0 = store.linear_velocity[f.start], store.angular_velocity[f.start]
        a = simulate_from_state(body(i), q[0], v0, w0, rate, len(p))
        b = simulate_from_state(body(i), q[0], perturbed(v0, args.eps, rng), perturbed(w0, args.eps, rng), rate, len(p))
        rows.append((abs(w0[2]), rotation_angle_deg(a["orientation_xyzw"][-1], q[-1]),
                     np.linalg.norm(moved(a) - (p[-1] - p[0])),
                     rotation_angle_deg(b["orientation_xyzw"][-1], a["orientation_xyzw"][-1]),
                     np.linalg.norm(moved(b) - moved(a))))
    r = np.array(rows)
    print(f"{args.store}: {len(r)} non-toppling pushes re-simulated twice in {time.perf_counter() - t0:.0f} s")
    print(f"{'|w_z| at step 0':<18} {'pushes':>6} {'re-sim vs store: rot (deg)':>27} {'pos (cm)':>9} "
          f"{f'perturbed {100 * args.eps:g} %: rot (deg)':>26} {'p90':>6} {'pos (cm)':>9}")
    for lo, hi in ((0, np.inf),) + BANDS:
        k = (r[:, 0] >= lo) & (r[:, 0] < hi)
        name = "all" if (lo, hi) == (0, np.inf) else (f"{lo:g}-{hi:g} rad/s" if np.isfinite(hi) else f"above {lo:g} rad/s")
        print(f"{name:<18} {int(k.sum()):6d} {np.median(r[k, 1]):27.1f} {100 * np.median(r[k, 2]):9.2f} "
              f"{np.median(r[k, 3]):26.1f} {np.percentile(r[k, 3], 90):6.1f} {100 * np.median(r[k, 4]):9.2f}")

    print(f"\nrocking over the first 2 s ({min(args.rocking_pushes, len(sims))} pushes), as a share of sum |dv| and sum |dw|:")
    for rate_hz in (15.0, 30.0):
        acc = np.zeros(6)
        for i in sims[: args.rocking_pushes]:
            f = store.frames(i)
            q0, v0, w0 = store.orientation_xyzw[f.start], store.linear_velocity[f.start], store.angular_velocity[f.start]
            n = int(2 * rate_hz)
            a = simulate_from_state(body(i), q0, v0, w0, rate_hz, n)
            b = simulate_from_state(body(i), q0, perturbed(v0, args.eps, rng), perturbed(w0, args.eps, rng), rate_hz, n)
            dva, dvb = np.diff(a["linear_velocity"], axis=0), np.diff(b["linear_velocity"], axis=0)
            dwa, dwb = np.diff(a["angular_velocity"], axis=0), np.diff(b["angular_velocity"], axis=0)
            acc += [np.abs(dva[:, 2]).sum(), np.abs(dva[:, 2] - dvb[:, 2]).sum(), np.linalg.norm(dva, axis=1).sum(),
                    np.linalg.norm(dwa[:, :2], axis=1).sum(), np.linalg.norm(dwa[:, :2] - dwb[:, :2], axis=1).sum(),
                    np.linalg.norm(dwa, axis=1).sum()]
        print(f"  {rate_hz:.0f} Hz: vertical dv {acc[0] / acc[2]:.3f} (changed by the perturbation {acc[1] / acc[2]:.3f}); "
              f"tilt dw {acc[3] / acc[5]:.3f} (changed {acc[4] / acc[5]:.3f})")


if __name__ == "__main__":
    main()
