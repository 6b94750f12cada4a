"""One prediction from a cold process: what a user pays who runs `physdyn predict` once, against a
PyBullet script that does the same for the same mesh.

    python benchmarks/cold_start.py [--mesh MESH] [--repeats 5]

Each row is a fresh Python process, timed from the shell's side (wall clock, the median and the fastest of
``--repeats``):
- ``physdyn predict MESH``: the default model (`fast`), 3 s of a push, a summary printed;
- ``import physdyn; load_predictor()``: the start-up alone;
- a PyBullet script: trimesh loads the mesh and gives its hull and mass properties (as physdyn's
  preparation does), PyBullet builds the body on a plane and runs the same 3 s at 1/120 s;
- ``import torch``: the floor under any predictor in torch.
The in-process costs of one prediction (milliseconds; the frontier) are in docs/performance.md: from a
cold process they are a rounding error beside the imports.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pybullet_data

PUSH = ("--lin-vel", "0.8", "0", "0", "--ang-vel", "0", "0", "3")

PYBULLET_SCRIPT = """
import sys
import pybullet as p
import trimesh

mesh = trimesh.load(sys.argv[1], force="mesh")
hull = mesh.convex_hull
mass = 1.0
com = hull.center_mass
# the principal moments per unit mass, about axes turned into the body frame as PyBullet's inertial frame
principal = hull.principal_inertia_components * (mass / hull.volume)
w, x, y, z = trimesh.transformations.quaternion_from_matrix(hull.principal_inertia_transform.T)
p.connect(p.DIRECT)
p.setGravity(0, 0, -9.81)
p.setTimeStep(1 / 120)
p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE))
shape = p.createCollisionShape(p.GEOM_MESH, vertices=(hull.vertices - com).tolist())
body = p.createMultiBody(mass, shape, basePosition=[0, 0, float(com[2] - hull.bounds[0, 2])],
                         baseInertialFrameOrientation=[x, y, z, w])
p.changeDynamics(body, -1, localInertiaDiagonal=principal.tolist(), lateralFriction=0.5)
p.resetBaseVelocity(body, [0.8, 0, 0], [0, 0, 3])
for _ in range(360):
    p.stepSimulation()
print(p.getBasePositionAndOrientation(body)[0])
"""


def timed(command: list[str], repeats: int) -> list[float]:
    """Wall seconds of ``command`` in a fresh process, ``repeats`` times (one untimed run first: the disk cache)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    subprocess.run(command, capture_output=True, check=True, env=env)
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(command, capture_output=True, check=True, env=env)
        seconds.append(time.perf_counter() - t0)
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", default=str(Path(pybullet_data.getDataPath()) / "duck.obj"))
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rows = {
        "physdyn predict MESH (fast)": [sys.executable, "-m", "physdyn.cli", "predict", args.mesh, *PUSH],
        "import physdyn; load_predictor()": [sys.executable, "-c", "import physdyn; physdyn.load_predictor()"],
        "PyBullet 1/120 s script (trimesh hull and mass)": [sys.executable, "-c", PYBULLET_SCRIPT, args.mesh],
        "import torch": [sys.executable, "-c", "import torch"],
    }
    print(f"mesh {args.mesh}; wall seconds of a fresh process, median and fastest of {args.repeats}")
    medians = {}
    for name, command in rows.items():
        seconds = timed(command, args.repeats)
        medians[name] = statistics.median(seconds)
        print(f"  {name:<50} {medians[name]:6.2f} s  (fastest {min(seconds):.2f})", flush=True)
    pybullet = medians["PyBullet 1/120 s script (trimesh hull and mass)"]
    print(f"physdyn predict / PyBullet script: {medians['physdyn predict MESH (fast)'] / pybullet:.1f}x; "
          f"start-up alone / PyBullet script: {medians['import physdyn; load_predictor()'] / pybullet:.1f}x")


if __name__ == "__main__":
    main()
