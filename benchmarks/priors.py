"""The analytic priors alone, with no learning: how much of the job does each do before a network corrects it?

    python benchmarks/priors.py [--store data/quickstart.zarr] [--splits val test]

A model of the quickstart preset whose head outputs zeros rolls out its prior exactly (``model.prior``:
coulomb, planar, contact), through the same evaluation as a trained model (``physdyn.eval.evaluate``).
Printed per split: median final position error of the non-toppling sequences, its ratio to Coulomb
sliding told the true friction, and the median final rotation error.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from physdyn.data.normalization import compute_normalization
from physdyn.data.store import load_store
from physdyn.eval.evaluate import evaluate
from physdyn.models.dynamics_module import DynamicsModel
from physdyn.models.training import load_experiment_config

PRESET = Path(__file__).resolve().parents[1] / "configs" / "experiment" / "quickstart.yaml"


def prior_only_model(prior: str, store) -> DynamicsModel:
    cfg = load_experiment_config(PRESET, [f"model.prior={prior}", "model.orientation_input=true"])
    train = np.flatnonzero(store.split == 0)
    friction = float(np.median(store.friction[train]))
    model = DynamicsModel(cfg, compute_normalization(store, train, mode=cfg.data.normalization),
                          {"rate_hz": float(store.rate_hz), "friction": friction})
    with torch.no_grad():  # the network's residual is zero: the roll-out is the prior's
        model.head.linear.weight.zero_()
        model.head.linear.bias.zero_()
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--store", default="data/quickstart.zarr")
    parser.add_argument("--splits", nargs="+", default=["val", "test"])
    parser.add_argument("--priors", nargs="+", default=["coulomb", "planar", "contact"])
    args = parser.parse_args()
    store = load_store(args.store)
    print(f"store {args.store}; non-toppling sequences; medians")
    print(f"{'split':<6} {'prior':<16} {'final position (cm)':>20} {'/ sliding':>10} {'final rotation (deg)':>21} {'s':>6}")
    for split in args.splits:
        slide = evaluate("coulomb_slide", store, split=split)["headline"]
        print(f"{split:<6} {'(Coulomb sliding)':<16} {100 * slide['final_position_m_median']:20.2f} {1.0:10.2f} "
              f"{slide['final_rotation_deg_median']:21.1f}")
        for prior in args.priors:
            t0 = time.perf_counter()
            h = evaluate(prior_only_model(prior, store), store, split=split)["headline"]
            print(f"{split:<6} {prior:<16} {100 * h['final_position_m_median']:20.2f} "
                  f"{h['final_position_m_median'] / slide['final_position_m_median']:10.2f} "
                  f"{h['final_rotation_deg_median']:21.1f} {time.perf_counter() - t0:6.1f}", flush=True)


if __name__ == "__main__":
    main()
