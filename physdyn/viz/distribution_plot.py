"""The plot people look at for a distribution: where the sampled pushes leave the object (top view), with the
central 50 % and 90 % regions of the final position (``physdyn.eval.scores.position_region``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from physdyn.eval.scores import position_region
from physdyn.files import atomic_output
from physdyn.pipeline.distribution import MIN_REGION_SAMPLES
from physdyn.predict.prediction_files import check_output_path

CM_PER_M = 100.0


def plot_distribution(result: dict[str, Any], path: str | Path, overwrite: bool = False) -> Path:
    """A PNG of a ``Predictor.predict_distribution`` dict: each sample's final centre of mass seen from above
    (cm; red where the sample toppled), its path faint, the start, the mean and the 50 % and 90 % ellipses."""
    import matplotlib  # heavy (~0.4 s): loaded when a plot is drawn

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    path = check_output_path(path, overwrite, (".png",), "plot")
    path.parent.mkdir(parents=True, exist_ok=True)
    p = np.asarray(result["com_position"], dtype=np.float64) * CM_PER_M  # (N, T, 3)
    final = p[:, -1, :2]
    toppled = np.asarray(result.get("toppled", np.zeros(len(p), bool)), dtype=bool)
    fig, ax = plt.subplots(figsize=(6.0, 5.0))
    for path_xy in p[:, :, :2]:
        ax.plot(path_xy[:, 0], path_xy[:, 1], color="#4682b4", alpha=0.12, lw=0.8)
    ax.scatter(final[~toppled, 0], final[~toppled, 1], s=14, color="#4682b4", label="final position, stays up")
    if toppled.any():
        ax.scatter(final[toppled, 0], final[toppled, 1], s=14, color="#b22222", label="final position, toppled")
    ax.plot(*p[0, 0, :2], marker="x", color="k", ms=8, ls="none", label="start")
    ax.plot(*final.mean(axis=0), marker="+", color="k", ms=12, ls="none", label="mean")
    if len(final) >= MIN_REGION_SAMPLES:
        for level, style in ((0.5, "-"), (0.9, "--")):
            outline = position_region(final / CM_PER_M, level).boundary(128) * CM_PER_M
            ax.plot(outline[:, 0], outline[:, 1], color="#333", ls=style, lw=1.2, label=f"{round(100 * level)} % region")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (cm)")
    ax.set_ylabel("y (cm)")
    ax.set_title(f"{Path(str(result.get('mesh', ''))).name}: {len(p)} sampled pushes, "
                 f"topple probability {float(result['topple_probability'][-1]):.2f}", fontsize=10)
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    try:
        with atomic_output(path, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", dpi=120)
    finally:
        plt.close(fig)
    return path
