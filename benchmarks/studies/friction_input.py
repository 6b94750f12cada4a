"""How much does giving `fast` the ground's friction help? (docs/predict.md, "Friction")

    physdyn simulate --config configs/data/friction_hull.yaml --out data/friction_hull.zarr --workers 2
    python -m benchmarks.studies.friction_input data/friction_hull.zarr

On a store simulated at a random effective friction per push (0.1-0.5), `fast` rolled out at each push's
friction (what `physdyn test` does on such a store) and at its own (0.25, what it was trained at), beside
Coulomb sliding at the push's friction. Median final position error and rotation error of the pushes that do
not topple, overall and by friction.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from physdyn.data.store import load_store
from physdyn.eval.evaluate import evaluate
from physdyn.pipeline.presets import load_pipeline

BINS = ((0.1, 0.2), (0.2, 0.3), (0.3, 0.4), (0.4, 0.5))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("store")
    ap.add_argument("--split", default="test")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    store = load_store(args.store)
    given = load_pipeline("fast")
    own = load_pipeline("fast")
    own.motion.takes_friction = False  # the same model at the friction it was trained at
    runs = {"fast at each push's friction": evaluate(given, store, args.split),
            "fast at its own (0.25)": evaluate(own, store, args.split),
            "Coulomb sliding at each push's friction": evaluate("coulomb_slide", store, args.split)}
    first = next(iter(runs.values()))["per_sequence"]
    upright = ~np.asarray(first["toppled"], dtype=bool)
    mu = np.asarray(store.friction, dtype=np.float64)[np.asarray(first["sim"])]
    print(f"{upright.sum()} pushes that do not topple of {len(upright)} ({args.store}, {args.split} split)\n")
    head = "| forecast | position (cm) | rotation (deg) | " + " | ".join(f"mu {a}-{b}: position (cm)" for a, b in BINS) + " |"
    print(head + "\n|" + "---|" * (3 + len(BINS)))
    for name, result in runs.items():
        per = result["per_sequence"]
        pos = 100 * np.asarray(per["final.position_m"])
        rot = np.asarray(per["final.rotation_deg"])
        cells = [f"{np.median(pos[upright]):.2f}", f"{np.median(rot[upright]):.1f}"]
        for a, b in BINS:
            keep = upright & (mu >= a) & (mu < b)
            cells.append(f"{np.median(pos[keep]):.2f} ({keep.sum()})" if keep.any() else "-")
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
