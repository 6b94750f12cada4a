"""The bundled model against the baselines on a store's test split (default: the quickstart data).

    python benchmarks/bundled_model.py [STORE] [--checkpoint CKPT] [--split test]

Prints the median final-position error of non-toppling sequences for the model, Coulomb sliding and
staying put, and the model-to-sliding ratio (below 1: the model is better).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from physdyn.eval.evaluate import compare
from physdyn.predict.predictor import load_predictor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("store", nargs="?", default="data/quickstart.zarr")
    parser.add_argument("--checkpoint", default="bundled", help="default: the bundled model")
    parser.add_argument("--split", default="test")
    args = parser.parse_args()
    model = load_predictor(args.checkpoint).model
    t0 = time.perf_counter()
    result = compare(model, args.store, split=args.split)
    seconds = time.perf_counter() - t0
    rows = {row["predictor"]: row for row in result["table"]}
    model_name = result["model"]
    print(f"store {args.store}, {args.split} split, {rows[model_name]['count']} non-toppling sequences ({seconds:.0f} s)")
    for name, row in rows.items():
        print(f"  {name:<16} final position median {100 * row['final_position_m_median']:6.2f} cm   "
              f"position {1000 * row['position']:6.2f} mm/step   final rotation median {row['final_rotation_deg_median']:6.1f} deg")
    ratio = rows[model_name]["final_position_m_median"] / rows["coulomb_slide"]["final_position_m_median"]
    print(f"model / Coulomb sliding, median final position error: {ratio:.2f} ({'better' if ratio < 1 else 'worse'})")
    toppled = np.asarray(result["results"][model_name]["per_sequence"]["toppled"], dtype=bool)
    majority = max(toppled.mean(), 1 - toppled.mean())
    print(f"topple accuracy over all {len(toppled)} sequences: {rows[model_name]['topple_accuracy']:.3f} "
          f"(always answering the majority class: {majority:.3f})")
    print(result["verdict"])


if __name__ == "__main__":
    main()
