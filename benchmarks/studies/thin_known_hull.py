"""Thinning a cloud with its hull known: a ``hull_surface`` cloud is built with its mesh's hull vertices first,
so at prediction those can be taken as its hull instead of running qhull (physdyn/geometry/sampling.py,
``thin_hull_surface``). Does that thin as qhull's merged hull does, what does it save, and does it change
the ``fast`` model's accuracy? (docs/research/fast-cost.md.)

    python -m benchmarks.studies.thin_known_hull clouds [FOLDER ...] [--points 256] [--count 64]

``clouds``: for each mesh (default: pybullet_data's random_urdfs 000-999; the study sets' folders
are runs/frontier/pybullet/meshes_60 runs/external_val_100/meshes runs/robosuite/meshes), its prepared
body's ``hull_surface`` cloud: whether qhull (``THIN_QHULL_OPTIONS``, facets merged within 1e-7) marks exactly
its first min(H, N) points, whether the thinned clouds are equal, and the time of each thinning.
"""

from __future__ import annotations

import argparse
import glob
import time
import warnings

import numpy as np


def clouds(folders: list[str], points: int, count: int) -> None:
    from scipy.spatial import ConvexHull, QhullError

    import physdyn.geometry.sampling as sampling
    from physdyn.errors import PhysdynError
    from physdyn.predict.body import prepare_body

    if not folders:
        import pybullet_data

        folders = [f"{pybullet_data.getDataPath()}/random_urdfs"]
    sampling.farthest_point_sample(np.random.default_rng(0).random((8, 3)), 4)  # open3d's first import is no thinning's
    for folder in folders:
        files = sorted(glob.glob(f"{folder}/*.obj") + glob.glob(f"{folder}/*.stl") + glob.glob(f"{folder}/*/*.obj"))
        made, same_marks, same_thinned, spent = 0, 0, 0, np.zeros(2)
        for path in files:
            try:
                body = prepare_body(path)
            except PhysdynError:
                continue
            cloud = body.points_body(points, "hull_surface")
            first = min(len(body.spec.body_vertices()), points)
            t0 = time.perf_counter()
            known = sampling.thin_hull_surface(cloud, count, body.hull_count(points))
            t1 = time.perf_counter()
            qhull = sampling.thin_hull_surface(cloud, count)
            spent += (t1 - t0, time.perf_counter() - t1)
            on_hull = np.zeros(len(cloud), dtype=bool)
            try:
                on_hull[ConvexHull(cloud.astype(np.float64), qhull_options=sampling.THIN_QHULL_OPTIONS).vertices] = True
            except (QhullError, ValueError):
                on_hull[:] = True
            made += 1
            same_marks += bool(on_hull[:first].all() and not on_hull[first:].any())
            same_thinned += bool(np.array_equal(known, qhull))
            if not on_hull[:first].all() or on_hull[first:].any():
                print(f"  differ {path}: H {first}, qhull drops {int((~on_hull[:first]).sum())} of them "
                      f"and adds {int(on_hull[first:].sum())} samples")
        print(f"{folder}: {made} clouds of {points} points ({len(files) - made} meshes refused), thinned to {count}")
        print(f"  qhull marks exactly the first min(H, N) points: {same_marks} of {made}")
        print(f"  the thinned clouds are equal: {same_thinned} of {made}")
        print(f"  ms a cloud: known hull {1000 * spent[0] / max(made, 1):.3f}, qhull {1000 * spent[1] / max(made, 1):.3f}",
              flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("clouds")
    c.add_argument("folders", nargs="*")
    c.add_argument("--points", type=int, default=256, help="the cloud's size (the shipped models': 256)")
    c.add_argument("--count", type=int, default=64, help="thinned to (the fast model's PointNets: 64)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    clouds(args.folders, args.points, args.count)


if __name__ == "__main__":
    main()
