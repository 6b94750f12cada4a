"""The simulator's spin friction against the contact prior's, on three simple solids pushed from rest.

    python -m benchmarks.studies.spin_primitives

A disk (r 5 cm, h 2 cm), an upright cylinder (r 4 cm, h 10 cm) and a box (10 x 6 x 4 cm), made with trimesh,
prepared as `physdyn predict` prepares a mesh, given a spin (and a slide) directly, simulated per the
conventions (PyBullet, 1/960 s) and rolled out by the contact prior alone (its footprint read from the
body's 256-point cloud, the body's own I_zz / m). Printed at 15 Hz: the spin w_z and the horizontal speed
of both, and the prior's footprint (radii of its 4 points from the vertical through the centre of mass).
Checks whether Bullet's spin friction is Coulomb's over 4 contact points at the edge of the face (the
disk's: 98 rad/s^2 expected, uniform pressure over the disk would give 65) and whether the footprint
read from the cloud finds the face's corners. No patch, no file kept.
"""
import os
import tempfile
import warnings

import numpy as np
import torch
import trimesh

from benchmarks.studies.common import RATE, STEPS, prior_rollout
from physdyn.models.priors import contact_geometry
from physdyn.predict.body import prepare_body
from physdyn.predict.simulator import simulate_from_state

def main() -> None:
    warnings.simplefilter("ignore")
    solids = [("disk r5 h2", trimesh.creation.cylinder(radius=0.05, height=0.02, sections=64)),
              ("cylinder r4 h10", trimesh.creation.cylinder(radius=0.04, height=0.10, sections=64)),
              ("box 10x6x4", trimesh.creation.box(extents=[0.1, 0.06, 0.04]))]
    with tempfile.TemporaryDirectory() as tmp:
        for name, mesh in solids:
            path = os.path.join(tmp, name.split()[0] + ".obj")
            mesh.export(path)
            body = prepare_body(path)
            geometry = contact_geometry(torch.tensor(body.points_body(256), dtype=torch.float32)[None])
            k = (geometry.shape[1] - 2) // 4
            geometry[0, 4 * k] = float(mesh.moment_inertia[2, 2] / mesh.mass)
            radii = geometry[0, : 3 * k].reshape(k, 3)[:, :2].norm(dim=1).numpy()
            print(f"{name}: footprint radii {np.round(radii, 3)} m (the face's edge: {np.round(np.abs(mesh.vertices[:, :2]).max(0), 3)})")
            for v0, w0 in [(0.0, 10.0), (1.0, 10.0), (1.5, 5.0)]:
                sim = simulate_from_state(body.spec, np.array([0, 0, 0, 1.0]), np.array([v0, 0, 0]), np.array([0, 0, w0]), RATE, STEPS + 1)
                spins, speeds = prior_rollout(geometry, v0, w0)
                print(f"  v0 {v0} m/s, w0 {w0} rad/s: w_z simulator {np.round(sim['angular_velocity'][:, 2], 2)} prior {np.round(spins, 2)}")
                print(f"  {'':23} |v| simulator {np.round(np.linalg.norm(sim['linear_velocity'][:, :2], axis=1), 2)} prior {np.round(speeds, 2)}")


if __name__ == "__main__":
    main()
