"""Study: how well does PyBullet predict a push when it only knows what the model knows?

The model sees the point cloud (body frame, centred on the centre of mass) and the velocities at step 0.
This study builds a rigid body from exactly that — the convex hull of the cloud's first ``--points`` points
as the collision shape, mass properties of that hull as a uniform solid taken about the known centre of
mass — and lets PyBullet roll it out from the store's step-0 state, at a coarse physics step. It reports the
#11 metrics (final position / rotation of non-toppling pushes, topple accuracy over all) against the store,
and the wall time per push against the store's own simulation cost at 1/960 s.

    python -m benchmarks.studies.cloud_sim STORE [--split 2|all] [--points 256] [--step 240] [--limit N]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np


from physdyn.config import PhysicsConfig  # noqa: E402
from physdyn.data.store import load_store  # noqa: E402
from physdyn.eval.metrics import rotation_angle_deg  # noqa: E402
from physdyn.predict.simulator import simulate_from_state  # noqa: E402
from physdyn.data.windows import store_world_inertia  # noqa: E402
from physdyn.sim.body import RigidBodySpec  # noqa: E402
from physdyn.sim.cloud_body import cloud_body_spec  # noqa: E402
from physdyn.sim.trajectory import tilt_angle  # noqa: E402

def cloud_spec(points: np.ndarray, inertia_kind: str = "hull") -> RigidBodySpec:
    """``cloud_body_spec`` (the package's body from a cloud: its hull, the hull's inertia about the cloud's
    origin), with the inertia variants this study compared: ``hullF`` F x the hull's, ``shell``/``shell08``
    the cloud's own second moments as a thin shell (x 0.8)."""
    spec = cloud_body_spec(points)
    if inertia_kind == "hull":
        return spec
    if inertia_kind.startswith("hull"):
        per_mass = float(inertia_kind[4:]) * (spec.principal_axes * spec.inertia_diag) @ spec.principal_axes.T / spec.mass
    else:
        c = np.asarray(points, np.float64)
        second = c.T @ c / len(c)
        per_mass = {"shell": 1.0, "shell08": 0.8}[inertia_kind] * (np.trace(second) * np.eye(3) - second)
    return cloud_body_spec(points, per_mass)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store")
    ap.add_argument("--split", default="2", help="0/1/2 or all")
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--step", type=float, default=240.0, help="physics rate in Hz (1/time step)")
    ap.add_argument("--limit", type=int, default=0, help="at most this many pushes (0: all)")
    ap.add_argument("--scale", type=float, default=1.0, help="scale the cloud about the centre of mass first")
    ap.add_argument("--seconds", type=float, default=0.0, help="simulate only this long (0: the whole sequence)")
    ap.add_argument("--inertia", default="hull", help="hull, hullF (F x the hull's), shell, shell08")
    ap.add_argument("--save", help="write per-push errors and the tilt curve (deg per step) to this .npz")
    ap.add_argument("--true-body", action="store_true",
                    help="the store's own mass properties and the cloud's hull (isolates the inertia estimate)")
    args = ap.parse_args()

    store = load_store(args.store)
    sims = np.arange(store.num_sims) if args.split == "all" else np.flatnonzero(store.split == int(args.split))
    if args.limit:
        sims = sims[:: max(1, len(sims) // args.limit)][: args.limit]
    base = PhysicsConfig()
    rate = store.rate_hz
    specs: dict[int, RigidBodySpec] = {}
    p_err, r_err, topple_pred, topple_true, seconds = [], [], [], [], 0.0
    tilts = []
    for m in sims:
        s = int(store.shape_id[m])
        if s not in specs:
            spec = cloud_spec(args.scale * store.points[s][: args.points], args.inertia)
            if args.true_body:  # the store's inertia, as physdyn test hands it to CloudSimulator
                inertia = store_world_inertia(store, np.flatnonzero(store.shape_id == s)[:1], np.array([[0.0, 0.0, 0.0, 1.0]]))
                spec = cloud_body_spec(args.scale * store.points[s][: args.points], inertia[0])
            specs[s] = spec
        fr = store.frames(int(m))
        T = fr.stop - fr.start
        if args.seconds:
            T = min(T, int(round(args.seconds * rate)) + 1)
        phys = replace(base, time_step=1.0 / args.step,
                       lateral_friction_object=float(store.friction[m]) / base.lateral_friction_ground)
        t0 = time.perf_counter()
        out = simulate_from_state(specs[s], store.orientation_xyzw[fr.start], store.linear_velocity[fr.start],
                                  store.angular_velocity[fr.start], rate, T, phys)
        seconds += time.perf_counter() - t0
        true_p = store.com_position[fr]
        pred_p = out["com_position"] - out["com_position"][0] + true_p[0]
        p_err.append(np.linalg.norm(pred_p[-1] - true_p[T - 1]))
        r_err.append(float(rotation_angle_deg(out["orientation_xyzw"][-1], store.orientation_xyzw[fr.start + T - 1])))
        topple_pred.append(bool(out["topple_label"].any()))
        tilts.append(np.degrees(tilt_angle(out["orientation_xyzw"][0], out["orientation_xyzw"])))
        topple_true.append(bool(store.toppled[m]))
    p_err, r_err = np.asarray(p_err), np.asarray(r_err)
    tp, tt = np.asarray(topple_pred), np.asarray(topple_true)
    keep = ~tt
    print(f"{args.store}: {len(sims)} pushes ({keep.sum()} do not topple), cloud of {args.points} points, "
          f"physics {args.step:g} Hz{' (true mass properties)' if args.true_body else ''}")
    print(f"  final position, median of non-toppling: {100 * np.median(p_err[keep]):.2f} cm")
    print(f"  final rotation, median of non-toppling: {np.median(r_err[keep]):.1f} deg")
    print(f"  topple accuracy {np.mean(tp == tt):.3f} (majority {max(tt.mean(), 1 - tt.mean()):.3f}); "
          f"caught {int((tp & tt).sum())}/{int(tt.sum())}, false alarms {int((tp & ~tt).sum())}")
    if args.save:
        curves = np.full((len(sims), max(len(t) for t in tilts)), np.nan)
        for i, t in enumerate(tilts):
            curves[i, : len(t)] = t
        np.savez(args.save, sims=sims, position_m=p_err, rotation_deg=r_err, toppled=tt, predicted=tp, tilt_deg=curves,
                 split=store.split[sims], rate_hz=rate)
    print(f"  wall time {1000 * seconds / len(sims):.1f} ms per push")


if __name__ == "__main__":
    main()
