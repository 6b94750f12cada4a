"""The frontier's tables and plot (benchmarks/frontier.py): figures formatted, each cost as a ratio to
PyBullet's at 1/240 s and 1/120 s, one markdown table per regime, and the accuracy-cost plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

if __package__:  # imported as benchmarks.frontier_report by a study (python -m benchmarks.studies.NAME)
    from .frontier_sets import Requests
else:  # imported by benchmarks/frontier.py, whose folder Python puts on the path
    from frontier_sets import Requests

COST_REFERENCES_HZ = (240, 120)  # the steps every cost is compared with


def median(x: np.ndarray) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def fmt(value: float | None, digits: int) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def fmt_ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}" if value >= 10 else f"{value:.2f}"


def add_cost_ratios(rows: list[dict]) -> list[dict]:
    """Each timed row's ``cost_over_pybullet``: hz -> its costs ("one", "batched") over PyBullet's at 1/hz s."""
    references = {row["hz"]: row["ms"]["one"] for row in rows if row["kind"] == "pybullet"}
    for row in rows:
        costs = {key: row["ms"][key] for key in ("one", "batched") if key in row["ms"]}
        if costs:
            row["cost_over_pybullet"] = {hz: {key: cost / ref for key, cost in costs.items()} for hz, ref in references.items()}
    return rows


def cost_cell(row: dict, hz: int) -> str:
    ratios = row.get("cost_over_pybullet", {}).get(hz, {})
    return " / ".join(f"{ratios[key]:.2f}" for key in ("one", "batched") if key in ratios) or "-"


def table(rows: list[dict]) -> str:
    """A markdown table of a regime's rows."""
    head = ["predictor", "position (cm)", "position / sliding", "rotation (deg)", "rotation, all (deg)", "topple acc.",
            "ms one at a time", "ms batched", "PyBullet build (ms / mesh)"]
    head += [f"cost / PyBullet 1/{hz} s" for hz in COST_REFERENCES_HZ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        ms = row["ms"]
        cells = [row["name"], fmt(row["position_cm"], 2), fmt(row["position_over_sliding"], 3),
                 fmt(row["rotation_deg"], 1), fmt(row["rotation_all_deg"], 1), fmt(row["topple_accuracy"], 3),
                 fmt_ms(ms.get("one")), fmt_ms(ms.get("batched")), fmt_ms(ms.get("build"))]
        cells += [cost_cell(row, hz) for hz in COST_REFERENCES_HZ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def regime_header(title: str, req: Requests, meshes: int) -> str:
    toppled = float(np.mean(req.toppled))
    return (f"{title}: {meshes} meshes, {len(req)} pushes ({int((~req.toppled).sum())} do not topple; the majority "
            f"answer's topple accuracy {max(toppled, 1 - toppled):.3f})")


TABLE_NOTES = """Position: median final displacement error of the non-toppling pushes (ratio: over Coulomb sliding's
median). Rotation: median final rotation error, non-toppling pushes (and all). Costs: CPU ms per trajectory on
one core; "cost / PyBullet" gives one at a time / batched over PyBullet's cost at that step. Regime (a) treats
every request as a new mesh: physdyn prepares each (a fresh copy; its content-keyed caches emptied, outside the
timing) and batches one push of every mesh a call; PyBullet's cost is the build of the body (prepare_body +
collision shape, the "build" column: per mesh the median of its timings at the five steps, and the same price
for a step schedule) plus one roll-out. A schedule row steps at a fine step for a push's first frames, while
its contact settles, then at a coarse one (its name gives both).
Regime (b): one mesh object per mesh for physdyn, one body per mesh for PyBullet, both spread over the pushes.
Ceilings: PyBullet at 1/960 s on the hull of the points (the body's own inertia), not timed."""


def ceiling_labels(rows: list[dict], key: str) -> list[tuple[float, str]]:
    """(y, label) of the ceiling rows, those within 5 % of each other under one label."""
    found = sorted((max(row[key], 1e-3), row["name"].removeprefix("ceiling ")) for row in rows if row["kind"] == "ceiling")
    merged: list[tuple[float, str]] = []
    for y, name in found:
        if merged and y < merged[-1][0] * 1.05:
            merged[-1] = (merged[-1][0], f"{merged[-1][1]}; {name}")
        else:
            merged.append((y, name))
    return [(y, f"ceiling: {names}") for y, names in merged]


def plot(results: dict[str, dict], path: Path) -> None:
    """Per mesh set (columns): position ratio to sliding (top) and rotation error (bottom) against ms per
    trajectory; PyBullet's steps as lines, physdyn's predictors as points, the ceilings as dotted lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator
    from matplotlib.transforms import blended_transform_factory

    panels = (("position_over_sliding", "final position error / Coulomb sliding's"),
              ("rotation_deg", "final rotation error (deg), non-toppling"))
    fig, axes = plt.subplots(2, len(results), figsize=(6.5 * len(results), 9), squeeze=False)
    colours = ["tab:orange", "tab:green", "tab:red", "tab:brown", "tab:pink", "tab:olive"]
    for col, (set_name, result) in enumerate(results.items()):
        names = [row["name"] for row in result["new_meshes"]["rows"] if row["kind"] == "physdyn"]
        for line, (key, label) in enumerate(panels):
            ax = axes[line, col]
            for regime, style, colour_pb, what in (("new_meshes", "-", "tab:blue", "new meshes"),
                                                   ("one_mesh", "--", "tab:purple", "pushes of one mesh")):
                rows = result[regime]["rows"]
                bullet = [row for row in rows if row["kind"] == "pybullet"]
                xs, ys = [row["ms"]["one"] for row in bullet], [max(row[key], 1e-3) for row in bullet]
                ax.plot(xs, ys, style, marker=".", color=colour_pb, label=f"PyBullet on the mesh's hull, {what}")
                for row, x, y in zip(bullet, xs, ys):
                    ax.annotate(f"1/{row['hz']}", (x, y), textcoords="offset points", xytext=(3, 3), fontsize=7,
                                color=colour_pb)
                for row in (r for r in rows if r["kind"] == "pybullet_schedule"):
                    ax.scatter(row["ms"]["one"], max(row[key], 1e-3), marker="*", color=colour_pb, s=70, zorder=3,
                               label=f"{row['name']}, {what}")
                for row in (r for r in rows if r["kind"] == "physdyn"):
                    colour = colours[names.index(row["name"]) % len(colours)]
                    y = max(row[key], 1e-3)
                    if regime == "one_mesh":
                        ax.scatter(row["ms"]["batched"], y, marker="^", color=colour, s=50, zorder=3,
                                   label=f"{row['name']}: {result['one_mesh']['pushes_per_mesh']} pushes of one mesh")
                        continue
                    ax.scatter(row["ms"]["one"], y, marker="o", color=colour, s=50, zorder=3,
                               label=f"{row['name']}: one new mesh at a time")
                    batched_y = max(row["batched"][key], 1e-3)
                    ax.scatter(row["ms"]["batched"], batched_y, marker="s", facecolors="none", edgecolors=colour, s=50,
                               zorder=3, label=f"{row['name']}: new meshes batched")
            to_axes = blended_transform_factory(ax.transAxes, ax.transData)
            for y, text in ceiling_labels(result["new_meshes"]["rows"], key):
                ax.axhline(y, color="0.45", ls=":", lw=0.8)
                ax.text(0.99, y, text, transform=to_axes, fontsize=6, color="0.35", ha="right", va="bottom")
            ax.set_xscale("log")
            ax.set_yscale("log")
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
                axis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
            ax.grid(True, which="both", alpha=0.3)
            ax.set_ylabel(label)
            if line == 0:
                ax.set_title(f"{set_name}: {result['new_meshes']['meshes']} meshes new to the model")
            else:
                ax.set_xlabel("ms per trajectory (one core; log)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    unique = dict(zip(labels, handles))
    fig.legend(unique.values(), unique.keys(), loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
