"""Variants of the shipped `fast` model judged where a choice may be made (docs/research/fast-cost.md,
docs/research/topple-from-cloud.md, docs/research/outcome-correction.md).

    python -m benchmarks.studies.fast_variants sets CKPT ...     # the study sets and the frontier's pybullet set, every push
    python -m benchmarks.studies.fast_variants topple CKPT ... [--thresholds 0.4 0.5 0.6]   # topple accuracy by threshold

``sets``: final position over Coulomb sliding's (non-toppling medians), rotation (non-toppling) and topple
accuracy on the two study sets (``outcome_inputs.py robosuite`` makes the robosuite store;
``impact_pointnet.py``'s docstring makes the random_urdfs 100-159 store; a set whose store is
absent is left out, said so) and on the frontier's pybullet set, a new mesh per push (a) and 512 pushes of
each of two meshes (b) (the frontier's stores; ``benchmarks/frontier.py`` makes them), each push predicted
from its step-0 state with ``predict_many`` per mesh. ``topple``: the topple accuracy of the same
predictions on the pybullet set's (a) and (b) and random_urdfs 100-159, a push toppling where its highest
probability reaches each of ``--thresholds``. The frontier's wheel set is not read: nothing is chosen on it.
CKPT: a checkpoint path or a shipped name (fast, bundled).
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

for _threads in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_threads] = "1"

import numpy as np  # noqa: E402
import torch  # noqa: E402

from benchmarks.frontier_sets import collect_set, requests_from_store, truth_store  # noqa: E402
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=("sets", "topple"))
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.5],
                        help="topple: the probabilities at which a push counts as toppling")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the meshes' notes (open surfaces, repaired faces), once per mesh
    torch.set_num_threads(1)
    if args.what == "sets":
        sets(args.checkpoints)
    else:
        topple(args.checkpoints, args.thresholds)


if __name__ == "__main__":
    main()
