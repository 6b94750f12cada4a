"""How fast the contact prior takes the spin away, against the simulator, step by step from the true state.

    python -m benchmarks.studies.spin_decel data/quickstart.zarr
    python -m benchmarks.studies.spin_decel --all runs/external_val/external_60x10_from30_unnamed.zarr

For the non-toppling pushes that spin (|w_z| > 2 rad/s at step 0) of each store (its validation and test
splits, where the prior's constants were not fitted; with --all every push, for stores no model or prior
was fitted on, as the external meshes' are), the prior is fed the TRUE state of steps 0-3
(velocities, the rotation since step 0) and the spin it takes away over those four steps is summed, as is
the spin the simulator took away. Printed: the ratio of their medians (1: right; below 1 the prior lets
the body spin too long, above 1 it stops it too early), per category, for three footprints: the shipped
band (cloud points within 5 mm of the lowest) and the points within 1 or 3 mm of the cloud's convex-hull
facet under the centre of mass (``common.touching_mask``); then, for the band, by the tilt spin at step 0
(does rocking after the push explain the misses?). The prior uses the body's I_zz / m, as the bundled
model does. No patch, no file written.
"""
import sys

import numpy as np
import torch

from benchmarks.studies.common import touching_mask

from physdyn.data.store import load_store  # noqa: E402
from physdyn.data.windows import store_spin_inertia, world_oriented_points  # noqa: E402
from physdyn.geometry.rotations import quat_conjugate, quat_multiply  # noqa: E402
from physdyn.models.priors import contact_changes, contact_geometry  # noqa: E402

STEPS = 4
POINTS = 256  # the encoder's cloud, from which the bundled model reads its footprint


def spin_lost(store, sims, tol):
    """(prior, true) spin taken away over the first STEPS steps, rad/s, in the sense of the step-0 spin."""
    st = store.start[sims]
    pts = world_oriented_points(store.points[store.shape_id[sims]][:, :POINTS], store.orientation_xyzw[st])
    touching = None if tol is None else torch.from_numpy(np.stack([touching_mask(p.astype(np.float64), tol) for p in pts]))
    geometry = contact_geometry(torch.tensor(pts, dtype=torch.float32), touching)
    k = (geometry.shape[1] - 2) // 4
    geometry[:, 4 * k] = torch.tensor(store_spin_inertia(store, sims, store.orientation_xyzw[st]), dtype=torch.float32)
    sense = np.sign(store.angular_velocity[st, 2])
    prior, true = np.zeros(len(sims)), np.zeros(len(sims))
    f32 = lambda x: torch.tensor(x, dtype=torch.float32)[:, None]  # noqa: E731
    for t in range(STEPS):
        f = st + t
        turn = quat_multiply(store.orientation_xyzw[f], quat_conjugate(store.orientation_xyzw[st]))
        with torch.no_grad():
            c = contact_changes(f32(store.linear_velocity[f]), f32(store.angular_velocity[f]), f32(turn), geometry,
                                1 / store.rate_hz, float(np.median(store.friction)))[:, 0].numpy()
        prior -= c[:, 5] * sense
        true -= (store.angular_velocity[f + 1, 2] - store.angular_velocity[f, 2]) * sense
    return prior, true


def main() -> None:
    every = "--all" in sys.argv[1:]
    for path in [a for a in sys.argv[1:] if a != "--all"]:
        store = load_store(path)
        held_out = np.ones(len(store.split), bool) if every else store.split >= 1
        long_enough = np.diff(store.start) > STEPS + 1
        spins = np.abs(store.angular_velocity[store.start[:-1], 2]) > 2.0
        sims = np.flatnonzero(~store.toppled & held_out & long_enough & spins)
        category = store.category[store.shape_id[sims]]
        names = [store.category_names[c] if c < len(store.category_names) else str(c) for c in np.unique(category)]
        print(f"{path}: {len(sims)} spinning non-toppling pushes; prior / simulator, median spin taken away over {STEPS} steps")
        for label, tol in (("band 5 mm (shipped)", None), ("hull facet 1 mm", 0.001), ("hull facet 3 mm", 0.003)):
            prior, true = spin_lost(store, sims, tol)
            parts = [f"{n} {np.median(prior[category == c]) / np.median(true[category == c]):.2f}"
                     for n, c in zip(names, np.unique(category))]
            print(f"  {label:<22} all {np.median(prior) / np.median(true):.2f}; " + ", ".join(parts), flush=True)
            if tol is None:
                st = store.start[sims]
                tilt = np.hypot(store.angular_velocity[st, 0], store.angular_velocity[st, 1])
                bands = [(0, 2), (2, 8), (8, np.inf)]
                print("  " + " " * 22 + " by step-0 tilt spin: " + ", ".join(
                    f"{lo:g}-{hi:g} rad/s {np.median(prior[m]) / np.median(true[m]):.2f} (n {m.sum()})"
                    for lo, hi in bands for m in [(tilt >= lo) & (tilt < hi)]))


if __name__ == "__main__":
    main()
