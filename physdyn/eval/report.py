"""Write a comparison (``physdyn.eval.evaluate.compare``) to a folder: metrics.json, report.md, plots.

- ``metrics.json``: the whole comparison (NaN written as null)
- ``report.md``: the headline table (non-toppling roll-outs, as in the paper) and the verdict
- ``rollout_error_vs_time.png``: median accumulated position and rotation error per step with the
  interquartile band, model beside the baselines, cut where fewer than a quarter of the sequences still run
- ``errors_per_category.png``: mean roll-out errors per category (supplement Fig. 6)
- on an ensemble store, with the comparison's ``distribution`` (``physdyn.eval.distribution_eval``): its table
  in ``report.md`` and ``topple_reliability.png``, the reliability diagram of the forecast's topple probability
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from physdyn.errors import PhysdynError
from physdyn.files import atomic_output, check_writable, jsonable, save_figure_atomic, write_text_atomic

from physdyn.eval.metrics import ERROR_KEYS

UNITS = {"linear_velocity": "m/s", "angular_velocity": "rad/s", "position": "m", "angle_deg": "deg", "axis": "1 - cos"}


def fmt_number(x: Any, digits: int = 4) -> str:
    """A number to 4 significant digits for a table; None, NaN and inf read 'n/a'."""
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}g}"


def markdown(comparison: dict) -> str:
    first = next(iter(comparison["results"].values()))
    lines = [
        f"# Evaluation on {first['store']} ({first['split']} split, warm start {first['warm_start']})", "",
        "Roll-out errors per step on non-toppling sequences (mean over steps, then sequences); relative errors "
        "are sum |error| / sum |true change| per sequence; final errors are medians at the last step.", "",
    ]
    head = ["predictor", "n"] + [f"{k} ({UNITS[k]})" for k in ERROR_KEYS] + ["rel. v", "rel. w", "rel. p", "rel. angle",
                                                                             "final p (m)", "final rot (deg)", "topple acc."]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in comparison["table"]:
        cells = [row["predictor"], str(row["count"])] + [fmt_number(row[k]) for k in ERROR_KEYS]
        cells += [fmt_number(100 * row[f"relative_{k}"], 3) + " %" for k in ("linear_velocity", "angular_velocity", "position", "angle")]
        cells += [fmt_number(row["final_position_m_median"]), fmt_number(row["final_rotation_deg_median"]), fmt_number(row["topple_accuracy"], 3)]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", comparison["verdict"], ""]
    if comparison.get("distribution"):
        lines += distribution_markdown(comparison["distribution"], comparison["model"])
    return "\n".join(lines)


def distribution_markdown(block: dict, model: str) -> list[str]:
    """The lines of report.md's distribution section: the sampled and the deterministic forecast beside the
    floors (``physdyn.eval.distribution_eval.evaluate_distribution``'s block)."""
    spread = ", ".join(f"{k}={v:g}" for k, v in block["uncertainty"].items())
    source = "the store's ensemble's" if block["uncertainty_source"] == "store" else "given"
    lines = ["## Distribution scores", "",
             f"Final outcomes after {block['seconds']:.2f} s of {block['pushes']} pushes, each against its "
             f"{block['members']} reference members; {block['samples']} samples each from the "
             f"{block['distribution']} distribution stage (uncertainty {source}: {spread}; friction "
             f"{'varied' if block['friction_varied'] else 'not varied: the model predicts at its own'}). Lower is "
             "better, except coverage: the share of members inside the "
             "forecast's 50 % and 90 % regions. Floor: a perfect forecast's expected score. Definitions: "
             "docs/evaluation.md.", ""]
    head = ["forecast", "position ES (cm)", "orientation ES (deg)", "Brier", "ECE", "coverage 50 %", "coverage 90 %"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    rows = [(f"{model}, {block['samples']} samples", block["forecast"]), (f"{model}, deterministic", block["deterministic"])]
    for name, s in rows:
        cells = [fmt_number(s[k]) for k in ("position_es_cm", "orientation_es_deg", "brier", "ece")]
        cells += ["n/a" if s[k] is None else fmt_number(100 * s[k], 3) + " %" for k in ("coverage_50", "coverage_90")]
        lines.append("| " + " | ".join([name, *cells]) + " |")
    floor = block["forecast"]
    lines.append("| " + " | ".join(["floor (perfect forecast)", fmt_number(floor["position_floor_cm"]),
                                    fmt_number(floor["orientation_floor_deg"]), fmt_number(floor["brier_floor"]), "0",
                                    "50 %", "90 %"]) + " |")
    return lines + ["", f"![topple reliability]({RELIABILITY_FILE})", ""]


CURVE_MIN_SHARE = 0.25  # error-vs-time plots stop where fewer than this share of the sequences still run...
CURVE_MIN_SEQUENCES = 10  # ...or fewer than this many (a smaller set is plotted while all of it runs)


def curve_end(count: Any, min_share: float = CURVE_MIN_SHARE, min_sequences: int = CURVE_MIN_SEQUENCES) -> int:
    """Steps to plot of an error curve with ``count`` sequences running at each step: up to the first step
    where fewer than max(min_share x count[0], min_sequences) still run, beyond which a mean or median
    describes which few long sequences remain rather than how errors grow."""
    count = np.asarray(count, dtype=float)
    if not len(count) or count[0] <= 0:
        return len(count)
    short = np.flatnonzero(count < min(max(min_share * count[0], min_sequences), count[0]))
    return int(short[0]) if len(short) else len(count)


def draw_error_curves(axes: Any, label: str, curves: dict, rate_hz: float, end: int) -> list[float]:
    """Position and rotation error of one predictor on two axes: the median with the interquartile band
    (the mean for results written before the quartiles). Returns each panel's highest upper quartile."""
    t = np.arange(end) / rate_hz
    tops = []
    for ax, key in zip(axes, ("position_m", "rotation_deg")):
        if f"{key}_median" in curves:
            line, = ax.plot(t, np.array(curves[f"{key}_median"][:end], dtype=float), label=label)
            upper = np.array(curves[f"{key}_q75"][:end], dtype=float)
            ax.fill_between(t, np.array(curves[f"{key}_q25"][:end], dtype=float), upper, color=line.get_color(),
                            alpha=0.15, lw=0)
            tops.append(float(np.nanmax(upper)) if np.isfinite(upper).any() else 0.0)
        else:
            values = np.array(curves[key][:end], dtype=float)
            ax.plot(t, values, label=f"{label} (mean)")
            tops.append(float(np.nanmax(values)) if np.isfinite(values).any() else 0.0)
    return tops


def fit_error_axes(axes: Any, tops: list[list[float]]) -> bool:
    """When one predictor (usually staying put) is more than twice as far off as the next, scale each axis
    to the others so they stay readable. ``tops``: per predictor, its two panels' highest values."""
    clipped = False
    for i, ax in enumerate(axes):
        highest = sorted(t[i] for t in tops)
        if len(highest) >= 3 and highest[-1] > 2 * highest[-2] > 0:
            ax.set_ylim(0, 1.3 * highest[-2])
            clipped = True
    return clipped


def plot_error_vs_time(comparison: dict, path: Path, group: str = "non_toppling") -> None:
    """Median accumulated position and rotation error per step (interquartile band) of the model and the
    baselines, cut by ``curve_end`` (the cut is stated on the plot)."""
    import matplotlib  # heavy (~0.4 s): loaded when a plot is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    notes, tops = set(), []
    for name, result in comparison["results"].items():
        curves = result["curves"].get(group) or result["curves"]["all"]
        count = curves["count"]
        end = curve_end(count)
        if end < len(count):
            notes.add(f"cut at {(end - 1) / result['rate_hz']:.2f} s: beyond it fewer than "
                      f"{min(max(CURVE_MIN_SHARE * count[0], CURVE_MIN_SEQUENCES), count[0]):.0f} of the "
                      f"{int(count[0])} sequences still run")
        tops.append(draw_error_curves(axes, name, curves, result["rate_hz"], end))
    if fit_error_axes(axes, tops):
        notes.add("the worst predictor's curve leaves the axis")
    axes[0].set(xlabel="time (s)", ylabel="position error (m)", title=f"Roll-out position error ({group})")
    axes[1].set(xlabel="time (s)", ylabel="rotation error (deg)", title=f"Roll-out rotation error ({group})")
    axes[0].legend(fontsize=8)
    caption = "median over sequences, band: interquartile range"
    if notes:
        caption += "; " + "; ".join(sorted(notes))
    fig.text(0.5, 0.01, caption, ha="center", fontsize=8, color="#444")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure_atomic(fig, path, dpi=100)
    plt.close(fig)


def plot_errors_per_category(comparison: dict, path: Path) -> None:
    import matplotlib  # heavy (~0.4 s): loaded when a plot is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("linear_velocity", "angular_velocity", "position", "angle_deg")
    names = list(comparison["results"])
    cats = list(next(iter(comparison["results"].values()))["per_category"])
    fig, axes = plt.subplots(1, len(keys), figsize=(4 * len(keys), 3.5))
    width = 0.8 / max(len(names), 1)
    for i, name in enumerate(names):
        per_cat = comparison["results"][name]["per_category"]
        for ax, key in zip(axes, keys):
            values = [per_cat[c]["non_toppling"]["rollout"][key] for c in cats]
            ax.bar(np.arange(len(cats)) + i * width, values, width, label=name)
    for ax, key in zip(axes, keys):
        ax.set_xticks(np.arange(len(cats)) + 0.4 - width / 2, cats, rotation=30)
        ax.set_title(f"{key} ({UNITS[key]})")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=100)
    plt.close(fig)


REPORT_FILES = {"metrics": "metrics.json", "report": "report.md",
                "error_vs_time": "rollout_error_vs_time.png", "per_category": "errors_per_category.png"}
VIEWER_FILE = "viewer.html"  # written beside the report by `physdyn test` (physdyn.viz.store_scenes)
RELIABILITY_FILE = "topple_reliability.png"  # with a distribution block only


def check_report_target(out_dir: str | Path, overwrite: bool = False) -> None:
    """Refuse to replace an earlier report unless asked, or a place that cannot be written: call before
    spending time on an evaluation."""

    if Path(out_dir).is_file():
        raise PhysdynError(f"--out {out_dir} is a file; pass a folder for the report")
    check_writable(out_dir, "--out")
    existing = [name for name in (*REPORT_FILES.values(), VIEWER_FILE, RELIABILITY_FILE) if (Path(out_dir) / name).exists()]
    if existing and not overwrite:
        raise PhysdynError(f"{out_dir} already holds a report ({existing[0]}); pass --overwrite to replace it or choose another --out")


def write_report(comparison: dict, out_dir: str | Path, overwrite: bool = False) -> dict[str, Path]:
    """Write the files listed in the module docstring into ``out_dir``; returns name -> path."""
    check_report_target(out_dir, overwrite)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {key: out / name for key, name in REPORT_FILES.items()}
    # Each file whole or not at all; metrics.json last, so a folder that has it has the whole report.
    plot_error_vs_time(comparison, paths["error_vs_time"])
    plot_errors_per_category(comparison, paths["per_category"])
    if comparison.get("distribution"):
        paths["reliability"] = plot_topple_reliability(comparison["distribution"], out / RELIABILITY_FILE)
    else:  # a replaced report's diagram would describe another evaluation
        (out / RELIABILITY_FILE).unlink(missing_ok=True)
    write_text_atomic(paths["report"], markdown(comparison))
    write_text_atomic(paths["metrics"], json.dumps(jsonable(comparison, nan_as_null=True), indent=1))
    return paths


def plot_topple_reliability(block: dict, path: Path) -> Path:
    """The sampled forecast's reliability diagram (``block["reliability"]["forecast"]``) as a PNG, whole or not at all."""
    from physdyn.eval.scores import ReliabilityDiagram, plot_reliability_diagram

    diagram = ReliabilityDiagram(**{k: np.asarray(v, dtype=float) for k, v in block["reliability"]["forecast"].items()})
    with atomic_output(path, suffix=".png") as tmp:
        plot_reliability_diagram(diagram, tmp, title=f"topple probability, {block['samples']} samples "
                                                      f"(ECE {diagram.expected_calibration_error:.3f})")
    return path
