"""Table 1's relative roll-out errors (non-toppling test sequences) of the contact prior alone, or of a model,
and where the velocity, spin and position errors sit: horizontal / vertical parts of the summed error as a
share of the summed true change, by 0.25 s of the roll-out (the last column: 1 s and later).

    python -m benchmarks.studies.table1_parts runs/t1/speakers.zarr [runs/t1/std15/best.ckpt]
"""
import sys

import numpy as np

from benchmarks.priors import prior_only_model

from physdyn.data.store import load_store
from physdyn.eval.baselines import load_checkpoint
from physdyn.eval.evaluate import evaluate


def main() -> None:
    path = sys.argv[1]
    store = load_store(path)
    rate = float(store.rate_hz)
    model = prior_only_model("contact", store) if len(sys.argv) < 3 else load_checkpoint(sys.argv[2])
    r = evaluate(model, store, split="test", keep_trajectories=True)
    tr = r["trajectories"]
    pred, truth = tr["predicted"].deltas(), tr["truth"]
    ok = truth["valid"] & ~truth["toppled"][:, None]
    print(path, "relative (%)", {k: round(100 * v, 2) for k, v in r["rollout"]["non_toppling"]["relative"].items()})
    for key in ["delta_linear_velocity", "delta_angular_velocity", "delta_position"]:
        e = np.asarray(pred[key]) - np.asarray(truth[key])
        t = np.asarray(truth[key])
        den = np.linalg.norm(t, axis=-1)[ok].sum()
        tb = np.minimum((np.arange(e.shape[1]) / rate / 0.25).astype(int), 4)
        parts = []
        for b in range(5):
            m = ok & (tb[None, :] == b)
            parts.append(f"{np.linalg.norm(e[..., :2], axis=-1)[m].sum() / den:.3f}/{np.abs(e[..., 2])[m].sum() / den:.3f}")
        print(f"  {key}: error (xy/z) / sum |true| by 0.25 s: " + "  ".join(parts))


if __name__ == "__main__":
    main()
