"""Variants of the shipped `fast` model judged where a choice may be made, and where its time goes
(docs/research/fast-cost.md, docs/research/topple-from-cloud.md, docs/research/outcome-correction.md).

    python benchmarks/studies/fast_variants.py sets CKPT ...     # the study sets and the frontier's pybullet set, every push
    python benchmarks/studies/fast_variants.py topple CKPT ... [--thresholds 0.4 0.5 0.6]   # topple accuracy by threshold
    python benchmarks/studies/fast_variants.py stages CKPT [--set pybullet]   # one new mesh's prediction, by stage

``sets``: final position over Coulomb sliding's (non-toppling medians), rotation (non-toppling) and topple
accuracy on the two study sets (``outcome_inputs.py robosuite`` makes the robosuite store;
``impact_pointnet.py``'s docstring makes the random_urdfs 100-159 store; a set whose store is
absent is left out, said so) and on the frontier's pybullet set, a new mesh per push (a) and 512 pushes of
each of two meshes (b) (the frontier's stores; ``benchmarks/frontier.py`` makes them), each push predicted
from its step-0 state with ``predict_many`` per mesh. ``topple``: the topple accuracy of the same
predictions on the pybullet set's (a) and (b) and random_urdfs 100-159, a push toppling where its highest
probability reaches each of ``--thresholds``. The frontier's wheel set is not read: nothing is chosen on it.
``stages``: the frontier's regime (a) on one set, a fresh mesh a request and the predictor's caches emptied,
each stage timed by wrapping the functions that run it (wall clock; run it on a quiet machine).
CKPT: a checkpoint path or a shipped name (fast, bundled).
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import sys
import time
import warnings
from pathlib import Path

for _threads in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_threads] = "1"

import numpy as np  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))

from frontier_sets import collect_set, requests_from_store, truth_store  # noqa: E402

from physdyn import load_predictor  # noqa: E402
from physdyn.data.store import load_store  # noqa: E402
from physdyn.eval.metrics import rotation_angle_deg  # noqa: E402
from physdyn.geometry.mesh_io import load_mesh  # noqa: E402

STUDY_SETS = {"random_urdfs 100-159": "runs/external_val_100/urdf_100_159_hull256.zarr",
              "robosuite": "runs/robosuite/robosuite_60_hull256.zarr"}
FRONTIER = Path("runs/frontier")


def predict_all(predictor, req) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every request, one ``predict_many`` per mesh: final displacements (R, 3), orientations (R, 4), toppled (R,)
    and the highest topple probability of each push (R,)."""
    meshes = {key: load_mesh(key) for key in dict.fromkeys(req.mesh)}
    disp, q, toppled, highest = np.zeros((len(req), 3)), np.zeros((len(req), 4)), np.zeros(len(req), bool), np.zeros(len(req))
    for key, idx in req.by_mesh().items():
        results = predictor.predict_many([meshes[key]] * len(idx), req.v0[idx], req.w0[idx],
                                         seconds=list(req.steps[idx] / predictor.rate_hz), orientation_xyzw=req.q0[idx])
        for r, res in zip(idx, results):
            disp[r], q[r], toppled[r] = res["com_position"][-1] - res["com_position"][0], res["orientation_xyzw"][-1], res["toppled"]
            highest[r] = np.max(res["topple_probability"])
    return disp, q, toppled, highest


def pybullet_set_requests() -> dict:
    """The frontier's pybullet set (benchmarks/frontier.py makes its stores): a new mesh per push (a), and 512
    pushes of each of two meshes (b)."""
    return {"pybullet (a)": requests_from_store(truth_store(collect_set("pybullet", FRONTIER, 60), 5)),
            "pybullet (b)": requests_from_store(load_store(str(FRONTIER / "pybullet" / "meshes_60_one_mesh_2_truth_x512.zarr")),
                                                horizon=30)}


def sets(checkpoints: list[str]) -> None:
    reqs = {}
    for name, path in STUDY_SETS.items():
        if Path(path).exists():
            reqs[name] = requests_from_store(load_store(path))
        else:
            print(f"{name}: no {path} here (this docstring says how it is made); left out")
    reqs.update(pybullet_set_requests())
    print("| checkpoint | " + " | ".join(f"{n}: position / sliding, rotation, topple" for n in reqs) + " |")
    print("|---|" + "---|" * len(reqs))
    for checkpoint in checkpoints:
        predictor, cells = load_predictor(checkpoint), []
        for req in reqs.values():
            disp, q, toppled, _ = predict_all(predictor, req)
            still = ~req.toppled
            position = np.linalg.norm(disp - req.true_disp, axis=1)
            sliding = np.linalg.norm(req.slide_disp - req.true_disp, axis=1)
            rotation = rotation_angle_deg(q, req.true_q)
            cells.append(f"{np.median(position[still]) / np.median(sliding[still]):.3f}, {np.median(rotation[still]):.1f}°, "
                         f"{np.mean(toppled == req.toppled):.3f}")
        print(f"| {checkpoint} | " + " | ".join(cells) + " |", flush=True)


def topple(checkpoints: list[str], thresholds: list[float]) -> None:
    """Topple accuracy on the pybullet set's two regimes and random_urdfs 100-159, a push called toppling when
    its probability reaches each threshold (the conventions' metrics use 0.5, ``TOPPLE_THRESHOLD``)."""
    reqs = pybullet_set_requests()
    reqs["random_urdfs 100-159"] = requests_from_store(load_store(STUDY_SETS["random_urdfs 100-159"]))
    for checkpoint in checkpoints:
        predictor = load_predictor(checkpoint)
        for name, req in reqs.items():
            highest = predict_all(predictor, req)[3]
            cells = [f"{t:g}: {np.mean((highest >= t) == req.toppled):.3f}" for t in thresholds]
            print(f"{checkpoint}, {name} ({len(req)} pushes, majority {max(req.toppled.mean(), 1 - req.toppled.mean()):.3f}): "
                  + ", ".join(cells), flush=True)


def stages(checkpoint: str, set_name: str) -> None:
    import physdyn.geometry.mesh_io as mesh_io
    import physdyn.models.dynamics_network as dynamics_network
    import physdyn.models.outcome_correction as outcome_correction
    import physdyn.models.single_rollout as single_rollout
    import physdyn.models.topple_pointnet as topple_pointnet
    import physdyn.predict.body as body
    import physdyn.predict.predictor as predictor_module
    import physdyn.eval.rollout as rollout_module
    import physdyn.sim.body as sim_body

    spent: collections.Counter = collections.Counter()

    def timed(owner, name: str, label: str) -> None:
        inner = getattr(owner, name)

        @functools.wraps(inner)
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[label] += time.perf_counter() - t0
        setattr(owner, name, wrapper)

    for owner, name, label in ((predictor_module.Predictor, "predict_many", "the whole prediction"),
                               (predictor_module, "prepare_body", "preparing the mesh"),
                               (sim_body, "prepare_mesh", "  cleaning and checks"), (mesh_io, "point_hull", "    its hull"),
                               (sim_body, "solid_mass_properties", "  mass properties"),
                               (body.PreparedBody, "points_body", "the hull_surface cloud"),
                               (predictor_module, "rollout", "the roll-out"),
                               (single_rollout.SingleRollout, "run", "  the contact prior's steps"),
                               (topple_pointnet, "thinned_clouds", "  thinning the cloud (qhull, FPS)"),
                               (topple_pointnet.PointNetToppleClassifier, "predict", "  the topple PointNet"),
                               (dynamics_network.DynamicsNetwork, "encode", "  the shape code (footprint)"),
                               (outcome_correction, "correct_rollout", "  the outcome correction"),
                               (outcome_correction.OutcomeCorrection, "correction", "    its networks"),
                               (predictor_module, "_posed", "posing the body (resting height, inertia)"),
                               (rollout_module, "_oriented", "  turning clouds to step 0"),
                               (rollout_module, "integrate", "  integrating the changes"),
                               (single_rollout.SingleRollout, "of", "  the roll-out's weights on numpy")):
        timed(owner, name, label)
    req = requests_from_store(truth_store(collect_set(set_name, FRONTIER, 60), 5))
    meshes = {key: load_mesh(key) for key in dict.fromkeys(req.mesh)}
    predictor = load_predictor(checkpoint)
    import open3d  # noqa: F401  (its first import is not a prediction's)

    predictor.predict(next(iter(meshes.values())).copy(), [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], seconds=0.5)
    spent.clear()
    for r, key in enumerate(req.mesh):
        predictor.forget_meshes()
        predictor.predict(meshes[key].copy(), req.v0[r], req.w0[r], seconds=req.steps[r] / predictor.rate_hz,
                          orientation_xyzw=req.q0[r])
    print(f"{checkpoint} on the {set_name} set, {len(req)} requests, each a new mesh: ms a request")
    for label, seconds in spent.items():
        print(f"  {label:32s} {1000 * seconds / len(req):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=("sets", "topple", "stages"))
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.5],
                        help="topple: the probabilities at which a push counts as toppling")
    parser.add_argument("--set", default="pybullet", choices=("pybullet",),
                        help="stages: the frontier set to time on (the wheel set is for measuring only)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the meshes' notes (open surfaces, repaired faces), once per mesh
    torch.set_num_threads(1)
    if args.what == "sets":
        sets(args.checkpoints)
    elif args.what == "topple":
        topple(args.checkpoints, args.thresholds)
    else:
        for checkpoint in args.checkpoints:
            stages(checkpoint, args.set)


if __name__ == "__main__":
    main()
