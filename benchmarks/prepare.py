"""What preparing a new mesh costs: the milliseconds before a prediction of a mesh physdyn has not seen.

    python benchmarks/prepare.py                    # 10k-face meshes and the pybullet_data meshes
    python benchmarks/prepare.py --repeats 30 --random 30

Each repeat hands ``prepare_body`` a fresh ``trimesh.Trimesh`` (already in memory: file parsing is timed on
its own), then takes the point cloud the next model reads (``points_body(1024, "hull_surface")``) and the
resting pose (``initial_pose``). The steps are also timed one by one: cleaning (``prepare_mesh``: checks, the
convex hull, repairs when needed), mass properties, the simulator's ``RigidBodySpec``, the points and the
pose. Meshes:

- (a) 10k-face meshes: a UV sphere (every vertex on the convex hull: qhull's worst case), a torus, and
  pybullet_data's teddy subdivided once (irregular, several bodies);
- (b) the pybullet_data meshes of benchmarks/external_meshes.py (``collect_meshes``: the named objects and
  ``--random`` random_urdfs objects, at their scales), read from the files it writes.

One thread (numpy, torch, open3d); figures are the minimum over repeats of wall time (``ms``) and of this
thread's CPU time (``cpu``): on a busy machine the CPU time shows what the work costs without the waiting.
The issue's target is 2 ms for a 10,000-face mesh; ``x target`` is the total's wall time over 2 ms.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy loads its BLAS: one thread, as the target is stated

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pybullet_data  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402

from external_meshes import collect_meshes  # noqa: E402

from physdyn.config import MassConfig  # noqa: E402
from physdyn.geometry.mass import solid_mass_properties  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh, prepare_mesh  # noqa: E402
from physdyn.predict.body import PreparedBody, initial_pose, prepare_body  # noqa: E402
from physdyn.sim.body import RigidBodySpec  # noqa: E402

TARGET_MS = 2.0
NUM_POINTS, METHOD = 1024, "hull_surface"
UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])
STEPS = ("clean", "mass", "spec", "points", "pose")


def ten_thousand_faces() -> dict[str, trimesh.Trimesh]:
    teddy = trimesh.load(Path(pybullet_data.getDataPath()) / "teddy2_VHACD_CHs.obj", force="mesh")
    teddy.apply_scale(0.3 / teddy.extents.max())
    return {
        "sphere 10k (UV, all on hull)": trimesh.creation.uv_sphere(radius=0.1, count=[51, 51]),
        "torus 10k": trimesh.creation.torus(0.1, 0.03, major_sections=100, minor_sections=50),
        "teddy x4 (subdivided)": teddy.subdivide(),
    }


def timed(run, repeats: int) -> tuple[float, float]:
    """Minimum wall and thread-CPU milliseconds of ``run()`` over ``repeats``."""
    wall, cpu = [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.thread_time()
        run()
        cpu.append(time.thread_time() - c)
        wall.append(time.perf_counter() - w)
    return 1e3 * min(wall), 1e3 * min(cpu)


def measure(mesh: trimesh.Trimesh, repeats: int) -> dict[str, tuple[float, float]]:
    """Step and total times for one mesh, each repeat on a fresh copy (nothing cached from the last)."""
    vertices, faces = np.array(mesh.vertices), np.array(mesh.faces)
    density = MassConfig().density

    def fresh() -> trimesh.Trimesh:
        return trimesh.Trimesh(vertices=vertices.copy(), faces=faces.copy(), process=False)

    def total() -> None:
        body = prepare_body(state["raw"])
        body.points_body(NUM_POINTS, METHOD)
        initial_pose(body.spec, UPRIGHT)

    # The steps, in the order prepare_body runs them, each on the outputs of the one before.
    state: dict = {}

    def clean() -> None:
        state["prepared"] = prepare_mesh(state["raw"], "bench")

    def mass() -> None:
        p = state["prepared"]
        state["props"] = solid_mass_properties(p.mesh, p.watertight, density, "bench")

    def spec() -> None:
        p = state["prepared"]
        state["spec"] = RigidBodySpec.from_mesh(p.mesh, state["props"], getattr(p, "hull_vertices", None))

    def points() -> None:
        PreparedBody(mesh=state["prepared"].mesh, spec=state["spec"], name="bench").points_body(NUM_POINTS, METHOD)

    def pose() -> None:
        initial_pose(state["spec"], UPRIGHT)

    steps = {"clean": clean, "mass": mass, "spec": spec, "points": points, "pose": pose}
    best = {name: (np.inf, np.inf) for name in (*STEPS, "total")}
    for _ in range(repeats):
        state["raw"] = fresh()
        for name, run in steps.items():
            best[name] = np.minimum(best[name], timed(run, 1))
        state["raw"] = fresh()
        best["total"] = np.minimum(best["total"], timed(total, 1))
    return {name: (float(wall), float(cpu)) for name, (wall, cpu) in best.items()}


def row(label: str, faces: int, hull: int, times: dict) -> str:
    steps = "  ".join(f"{times[s][0]:6.2f}" for s in STEPS)
    ms, cpu = times["total"]
    return f"{label:32s} {faces:6d} {hull:5d}  {steps}  {ms:7.2f} {cpu:7.2f}  {ms / TARGET_MS:6.1f}"


def header() -> str:
    steps = "  ".join(f"{s:>6s}" for s in STEPS)
    return f"{'mesh':32s} {'faces':>6s} {'hull':>5s}  {steps}  {'ms':>7s} {'cpu':>7s}  {'x target':>6s}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--random", type=int, default=30, help="random_urdfs objects besides the named ones")
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:
        import open3d

        open3d.utility.set_verbosity_level(open3d.utility.VerbosityLevel.Error)
    except ImportError:
        pass
    warnings.simplefilter("ignore")  # open meshes note their hull fallback: expected here

    print("(a) 10k-face meshes, in memory; steps and totals in ms (minimum over repeats)")
    print(header())
    for label, mesh in ten_thousand_faces().items():
        times = measure(mesh, args.repeats)
        hull = len(prepare_body(mesh).spec.hull_vertices)
        print(row(label, len(mesh.faces), hull, times))

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        collect_meshes(folder, args.random)
        files = sorted(folder.glob("*.obj"))
        parse, rows, faces = [], [], []
        for path in files:
            parse.append(timed(lambda: load_mesh(path), max(3, args.repeats // 4)))
            mesh = load_mesh(path)
            rows.append(measure(mesh, args.repeats))
            faces.append(len(mesh.faces))
    print(f"\n(b) {len(files)} pybullet_data meshes (external_meshes.collect_meshes, --random {args.random}), "
          f"median {int(np.median(faces))} faces (max {max(faces)}); ms per mesh")
    print(f"{'':32s} {'':6s} {'':5s}  " + "  ".join(f"{s:>6s}" for s in STEPS) + f"  {'ms':>7s} {'cpu':>7s}")
    for label, reduce in (("median over meshes", np.median), ("max over meshes", np.max), ("mean over meshes", np.mean)):
        steps = "  ".join(f"{reduce([r[s][0] for r in rows]):6.2f}" for s in STEPS)
        total = reduce([r["total"][0] for r in rows])
        cpu = reduce([r["total"][1] for r in rows])
        print(f"{label:32s} {'':6s} {'':5s}  {steps}  {total:7.2f} {cpu:7.2f}")
    print(f"file parsing (load_mesh), not in the totals: median {np.median([p[0] for p in parse]):.2f} ms, "
          f"max {max(p[0] for p in parse):.2f} ms")


if __name__ == "__main__":
    main()
