"""Training-recipe ablations: every lever of docs/research/training-recipe.md on the same store, split and seed.

    python benchmarks/ablations.py                          # all levers, 2,000 steps each (~1 h on 2 cores)
    python benchmarks/ablations.py --only paper,prior-coulomb --steps 500
    python benchmarks/ablations.py --report-only            # rewrite the report from finished runs

Each lever is the quickstart experiment (configs/experiment/quickstart.yaml) with a few ``key=value``
overrides. A run trains under ``--out/<lever>`` (skipped when finished, so an interrupted sweep resumes),
then is rolled out on the validation and test splits beside the two baselines (staying put, Coulomb sliding
told the true friction). Levers are to be chosen on the validation split; the test split is reported too.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from physdyn.eval.evaluate import compare
from physdyn.models.run_directory import FINISHED
from physdyn.models.training import fit, load_experiment_config

REPO = Path(__file__).resolve().parents[1]
NOTES_MARK = "<!-- written by hand below this line; benchmarks/ablations.py keeps it -->"
PRESET = REPO / "configs/experiment/quickstart.yaml"

# The paper's recipe, spelled out so the levers stay what they are whatever the preset's defaults become.
PAPER_RECIPE = ["data.normalization=max", "data.first_window_fraction=0.0", "rollout.input_noise=0.0",
                "rollout.feedback=0.0", "loss.kind=relative", "model.orientation_input=false", "model.prior=none"]

# name -> (what it changes, overrides on top of PAPER_RECIPE). "paper" is the reference on the same data.
LEVERS: dict[str, tuple[str, list[str]]] = {
    "paper": ("the paper's recipe: max scaling, teacher forcing, relative loss, velocities only", []),
    "std-norm": ("per-channel mean/std normalisation", ["data.normalization=std"]),
    "input-noise": ("Gaussian noise 0.01 on fed velocities, targets corrected", ["rollout.input_noise=0.01"]),
    "feedback": ("training windows rolled out on the model's own velocities", ["rollout.feedback=1.0"]),
    "first-window": ("half the windows start at step 0", ["data.first_window_fraction=0.5"]),
    "huber": ("Huber loss (delta 0.05) instead of the relative loss", ["loss.kind=huber"]),
    "orientation": ("orientation since step 0 as an input (6D)", ["model.orientation_input=true"]),
    "prior-kinematic": ("residual on a kinematic prior (dp = v dt, dtheta = w dt)", ["model.prior=kinematic"]),
    "prior-coulomb": ("residual on Coulomb sliding", ["model.prior=coulomb"]),
    "combined": ("Coulomb prior + orientation + feedback + first windows",
                 ["model.prior=coulomb", "model.orientation_input=true", "rollout.feedback=1.0",
                  "data.first_window_fraction=0.5"]),
    "std-inputs": ("per-channel mean/std of the inputs only; changes max-scaled", ["data.normalization=std_inputs"]),
    "prior-planar": ("residual on planar Coulomb sliding: slide and spin stop together, tilt damped",
                     ["model.prior=planar"]),
    "combined-planar": ("planar prior + std inputs + orientation + feedback + first windows",
                        ["model.prior=planar", "data.normalization=std_inputs", "model.orientation_input=true",
                         "rollout.feedback=1.0", "data.first_window_fraction=0.5"]),
    "combined-planar-huber": ("combined-planar with the Huber loss",
                              ["model.prior=planar", "data.normalization=std_inputs", "model.orientation_input=true",
                               "rollout.feedback=1.0", "data.first_window_fraction=0.5", "loss.kind=huber"]),
    "more-data": ("combined-planar trained on 5x the pushes of the same shapes (configs/data/quickstart_large.yaml)",
                  ["model.prior=planar", "data.normalization=std_inputs", "model.orientation_input=true",
                   "rollout.feedback=1.0", "data.first_window_fraction=0.5", "data.store=data/quickstart_large.zarr"]),
    "prior-contact": ("residual on Coulomb friction over the footprint read from the point cloud (needs the orientation)",
                      ["model.prior=contact", "model.orientation_input=true"]),
    "combined-contact-huber": ("combined-planar-huber with the contact prior instead of the planar one",
                               ["model.prior=contact", "data.normalization=std_inputs", "model.orientation_input=true",
                                "rollout.feedback=1.0", "data.first_window_fraction=0.5", "loss.kind=huber"]),
    "std-coulomb": ("per-channel normalisation + Coulomb prior", ["data.normalization=std", "model.prior=coulomb"]),
    "combined-std": ("per-channel normalisation + Coulomb prior + orientation + feedback + first windows",
                     ["data.normalization=std", "model.prior=coulomb", "model.orientation_input=true",
                      "rollout.feedback=1.0", "data.first_window_fraction=0.5"]),
}


def train(name: str, overrides: list[str], args: argparse.Namespace) -> float:
    """Train one lever (or keep a finished run); returns its training wall time in seconds."""
    out = Path(args.out) / name
    timing = out / "ablation_time.json"
    if (out / FINISHED).is_file() and timing.is_file():
        return json.loads(timing.read_text())["seconds"]
    cfg = load_experiment_config(PRESET, [
        f"name={name}", f"out_dir={out}", f"data.store={args.store}", f"trainer.max_steps={args.steps}",
        f"seed={args.seed}", "progress_bar=false", *PAPER_RECIPE, *overrides])  # a lever may train on another store
    t0 = time.perf_counter()
    fit(cfg, overwrite=True)
    seconds = time.perf_counter() - t0
    timing.write_text(json.dumps({"seconds": seconds, "steps": args.steps}))
    return seconds


def evaluate_run(name: str, args: argparse.Namespace) -> dict:
    out = Path(args.out) / name
    path = out / "ablation_eval.json"
    if path.is_file():
        return json.loads(path.read_text())
    rows = {}
    for split in ("val", "test"):
        result = compare(out / "best.ckpt", args.store, split=split)
        table = {r["predictor"]: r for r in result["table"]}
        model = table.pop(result["model"])
        toppled = np.asarray(result["results"][result["model"]]["per_sequence"]["toppled"], dtype=bool)
        rows[split] = {"model": model, "baselines": table, "majority_topple_accuracy": float(max(toppled.mean(), 1 - toppled.mean()))}
    path.write_text(json.dumps(rows, indent=1))
    return rows


def cm(x: float) -> str:
    return f"{100 * x:.2f}"


def verdict(name: str, results: dict[str, dict], split: str) -> str:
    """How a lever moved the three headline figures against the paper's recipe (position and rotation:
    relative change of the median; topple: change of accuracy)."""
    if name == "paper" or "paper" not in results:
        return "reference" if name == "paper" else "-"
    m, ref = results[name][split]["model"], results["paper"][split]["model"]
    dp = m["final_position_m_median"] / ref["final_position_m_median"] - 1
    dr = m["final_rotation_deg_median"] / ref["final_rotation_deg_median"] - 1
    dt = m["topple_accuracy"] - ref["topple_accuracy"]
    return f"position {100 * dp:+.0f} %, rotation {100 * dr:+.0f} %, topple {dt:+.3f}"


def write_report(results: dict[str, dict], seconds: dict[str, float], args: argparse.Namespace) -> str:
    first = next(iter(results.values()))
    lines = [
        "# Ablations of the training recipe",
        "",
        "Generated by `python benchmarks/ablations.py` "
        f"(store `{args.store}`, {args.steps} training steps of batch 64 per lever, seed {args.seed}, "
        f"{datetime.now(timezone.utc):%Y-%m-%d}, {platform.machine()} with {os.cpu_count()} cores, "
        f"{torch.get_num_threads()} torch threads, no GPU). Every lever is the quickstart architecture "
        "(`configs/experiment/quickstart.yaml`: PointNet on 256 points, 3 x 128 LSTM, topple head) with the "
        "paper's recipe (`PAPER_RECIPE` in the script) and the overrides shown, evaluated on the same store, "
        "split and seed; one seed each, so differences of a few per cent are within run-to-run noise. "
        "Training times include whatever else ran on the machine.",
        "",
        "Columns (non-toppling sequences unless said): median final position error and its ratio to Coulomb "
        "sliding told the true friction (below 1: better than sliding), median final rotation error, the "
        "relative roll-out position error (supplement Table 1's P), and topple accuracy over all sequences.",
        "",
    ]
    for split, title in (("val", "Validation split (choose levers here)"), ("test", "Test split (unseen shapes)")):
        b = first[split]["baselines"]
        slide = b["coulomb_slide"]["final_position_m_median"]
        lines += [f"## {title}", "",
                  f"Baselines: Coulomb sliding {cm(slide)} cm, {b['coulomb_slide']['final_rotation_deg_median']:.1f} deg; "
                  f"staying put {cm(b['stay_put']['final_position_m_median'])} cm; always answering the majority "
                  f"topple class {first[split]['majority_topple_accuracy']:.3f}. "
                  f"{first[split]['model']['count']} non-toppling sequences.", "",
                  "| lever | overrides | train (min) | final position (cm) | / sliding | final rotation (deg) | relative P | topple acc. | vs paper recipe |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, r in results.items():
            m = r[split]["model"]
            overrides = " ".join(f"`{o}`" for o in LEVERS[name][1]) or "-"
            lines.append(f"| {name} | {overrides} | {seconds[name] / 60:.1f} | {cm(m['final_position_m_median'])} | "
                         f"{m['final_position_m_median'] / slide:.2f} | {m['final_rotation_deg_median']:.1f} | "
                         f"{100 * m['relative_position']:.1f} % | {m['topple_accuracy']:.3f} | {verdict(name, results, split)} |")
        lines.append("")
    lines += ["## The levers", ""]
    lines += [f"- **{name}**: {LEVERS[name][0]}." for name in results]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--store", default="data/quickstart.zarr")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/ablations")
    parser.add_argument("--doc", default="runs/ablations/report.md",
                        help="the Markdown report to write (docs/research/training-recipe.md quotes it)")
    parser.add_argument("--only", default="", help="comma-separated lever names (default: all)")
    parser.add_argument("--report-only", action="store_true", help="no training: report the finished runs")
    args = parser.parse_args()
    names = [n for n in args.only.split(",") if n] or list(LEVERS)
    unknown = [n for n in names if n not in LEVERS]
    if unknown:
        parser.error(f"unknown lever '{unknown[0]}'; known: {', '.join(LEVERS)}")
    results, seconds = {}, {}
    for name in names:
        if args.report_only and not (Path(args.out) / name / "ablation_eval.json").is_file():
            continue
        seconds[name] = train(name, LEVERS[name][1], args)
        results[name] = evaluate_run(name, args)
        m, slide = results[name]["val"]["model"], results[name]["val"]["baselines"]["coulomb_slide"]
        print(f"{name:<16} {seconds[name] / 60:5.1f} min  val final position {cm(m['final_position_m_median'])} cm "
              f"({m['final_position_m_median'] / slide['final_position_m_median']:.2f}x sliding), rotation "
              f"{m['final_rotation_deg_median']:.1f} deg, topple acc {m['topple_accuracy']:.3f}", flush=True)
    if results:
        doc = Path(args.doc)
        doc.parent.mkdir(parents=True, exist_ok=True)
        kept = ""
        if doc.is_file() and NOTES_MARK in doc.read_text():  # hand-written conclusions survive a rerun
            kept = doc.read_text().split(NOTES_MARK, 1)[1]
        doc.write_text(write_report(results, seconds, args) + "\n" + NOTES_MARK + kept)
        print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
