"""Study: is the cloud_sim baseline biased, or only scattered? (docs/ablations.md, "The simulator on the cloud")

For the non-toppling pushes of a store's split: its final displacement projected on the true one, as a
fraction of the true one, and its final yaw as a fraction of the true yaw (pushes turning more than
0.3 rad); medians and quartiles. A ratio near 1 with a wide spread is scatter a residual cannot remove.

    python benchmarks/studies/cloud_sim_bias.py STORE [SPLIT]      # SPLIT: train, val or test (default)
"""

import sys

import numpy as np

from physdyn.eval.baselines import CloudSim
from physdyn.eval.evaluate import evaluate
from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_rotvec


def yaw_since_start(q: np.ndarray, last: np.ndarray) -> np.ndarray:
    rows = np.arange(len(last))
    return quat_to_rotvec(quat_multiply(q[rows, last], quat_conjugate(q[:, 0])))[:, 2]


def main() -> None:
    path, split = sys.argv[1], (sys.argv[2] if len(sys.argv) > 2 else "test")
    kept = evaluate(CloudSim(), path, split=split, keep_trajectories=True)["trajectories"]
    pred, truth = kept["predicted"], kept["truth"]
    last, rows, standing = truth["last"], np.arange(len(truth["last"])), ~truth["toppled"]
    moved_pred = pred.com_position[rows, last] - pred.com_position[:, 0]
    moved_true = truth["com_position"][rows, last] - truth["com_position"][:, 0]
    along = (moved_pred[:, :2] * moved_true[:, :2]).sum(1) / np.maximum((moved_true[:, :2] ** 2).sum(1), 1e-9)
    yaw_pred, yaw_true = yaw_since_start(pred.orientation_xyzw, last), yaw_since_start(truth["orientation_xyzw"], last)
    turned = standing & (np.abs(yaw_true) > 0.3)
    yaw = yaw_pred[turned] / yaw_true[turned]
    print(f"{path} ({split}, {int(standing.sum())} non-toppling pushes)")
    print(f"  displacement along the true one: median {np.median(along[standing]):.3f}, "
          f"quartiles {np.percentile(along[standing], 25):.3f}-{np.percentile(along[standing], 75):.3f}")
    print(f"  final yaw / true yaw ({int(turned.sum())} pushes turning > 0.3 rad): median {np.median(yaw):.3f}, "
          f"quartiles {np.percentile(yaw, 25):.3f}-{np.percentile(yaw, 75):.3f}")


if __name__ == "__main__":
    main()
