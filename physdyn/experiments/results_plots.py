"""The results page's plots, drawn from numbers the page has chosen: error curves over time, and bars of
each category's roll-out errors. Nothing here reads a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from physdyn.eval.report import CURVE_MIN_SEQUENCES, draw_error_curves
from physdyn.files import save_figure_atomic


def _pyplot():
    import matplotlib  # heavy (~0.4 s): loaded when a plot is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_error_curve_plot(series: Sequence[tuple[str, dict, float, int]], path: Path, title: str) -> None:
    """Position and rotation error over time, side by side: one curve per (label, curves, rate_hz, steps)
    of ``series`` (``curves``: an evaluation's error curves, drawn up to ``steps`` steps)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for label, curves, rate_hz, steps in series:
        draw_error_curves(axes, label, curves, rate_hz, steps)
    axes[0].set(xlabel="time (s)", ylabel="position error (m)", title=f"{title}: position")
    axes[1].set(xlabel="time (s)", ylabel="rotation error (deg)", title=f"{title}: rotation")
    axes[0].legend(fontsize=7)
    fig.text(0.5, 0.01, f"median over the sequences still moving at each time (band: interquartile range); a "
             f"curve ends where fewer than a quarter of them, or {CURVE_MIN_SEQUENCES}, remain", ha="center",
             fontsize=8, color="0.35")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure_atomic(fig, path, dpi=100)
    plt.close(fig)


Bars = Sequence[tuple[str, list[float], "str | None"]]  # (label, one value per category, colour or None)


def draw_category_bars(categories: Sequence[str], panels: Sequence[tuple[str, Bars]], path: Path) -> None:
    """One panel per (title, bars) of ``panels``, side by side; each bar group is (label, one value per
    category, colour or None for the next default colour)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(11, 4))
    width = 0.2
    x = np.arange(len(categories))
    for ax, (title, bars) in zip(axes, panels):
        for i, (label, values, colour) in enumerate(bars):
            if colour is None:
                ax.bar(x + i * width, values, width, label=label)
            else:
                ax.bar(x + i * width, values, width, label=label, color=colour)
        ax.set_xticks(x + (len(bars) - 1) / 2 * width, categories, rotation=20)
        ax.set_title(title)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=100)
    plt.close(fig)
