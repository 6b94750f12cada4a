"""Draw five instances of each procedural family (clusters included): `python docs/figures/make_families.py` -> families.png."""

from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from physdyn.registry import SHAPE_FAMILIES  # noqa: E402

FAMILIES = ["primitives", "bottles", "mugs", "trashcans", "speakers", "clusters"]


def main(out: Path = Path(__file__).with_name("families.png"), per_family: int = 5) -> None:
    fig = plt.figure(figsize=(3 * per_family, 2.4 * len(FAMILIES)))
    for row, name in enumerate(FAMILIES):
        family = SHAPE_FAMILIES.build(name)
        for col in range(per_family):
            mesh = family.make(col, np.random.default_rng(100 + col)).mesh
            ax = fig.add_subplot(len(FAMILIES), per_family, row * per_family + col + 1, projection="3d")
            ax.add_collection3d(Poly3DCollection(mesh.vertices[mesh.faces], facecolor="tab:blue", edgecolor="k", linewidths=0.05))
            lo, hi = mesh.bounds
            centre, half = (lo + hi) / 2, (hi - lo).max() / 2
            for axis, c in zip("xyz", centre):
                getattr(ax, f"set_{axis}lim")(c - half, c + half)
            ax.set_title(f"{name}, {100 * (hi - lo).max():.0f} cm", fontsize=9)
            ax.set_axis_off()
            ax.view_init(elev=20, azim=-60)
    fig.tight_layout()
    fig.savefig(out, dpi=60)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
