"""Could thinning run qhull on the mesh hull's vertices alone? Does qhull (thin_hull_surface's options) on a hull_surface
cloud's first min(H, N) points, the mesh hull's vertices it was built from, mark the same vertices as on the whole
cloud, and how much cheaper is it? (docs/performance.md, nineteenth session: 2 of 228 clouds differ, 0.43 against
0.53-0.56 ms, so it was not built.)

    D=$(python -c "import pybullet_data; print(pybullet_data.getDataPath())")
    python benchmarks/studies/hull_subset.py "runs/frontier/pybullet/meshes_60/*.obj" "$D/random_urdfs/1[0-5]?/*.obj"
"""
import glob
import sys
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")
from scipy.spatial import ConvexHull, QhullError
from physdyn.geometry.sampling import THIN_QHULL_OPTIONS
from physdyn.predict.body import prepare_body
def mask(points):
    on = np.zeros(len(points), bool)
    try:
        on[ConvexHull(points.astype(np.float64), qhull_options=THIN_QHULL_OPTIONS).vertices] = True
    except (QhullError, ValueError):
        on[:] = True
    return on
for spec in sys.argv[1:]:
    files = sorted(glob.glob(spec))
    same = differ = failed = 0; tf = ts = 0.0
    for f in files:
        try:
            body = prepare_body(f)
        except Exception:
            failed += 1; continue
        for n in (256, 64):
            cloud = body.points_body(n, "hull_surface")
            K = min(len(body.spec.hull_vertices), n)
            t0 = time.perf_counter(); full = mask(cloud); t1 = time.perf_counter()
            sub = np.zeros(n, bool); sub[:K] = mask(cloud[:K]) if K >= 4 else True; t2 = time.perf_counter()
            tf += t1 - t0; ts += t2 - t1
            if (full == sub).all(): same += 1
            else:
                differ += 1; print("  differ", f, n, "K", K, "full", full.sum(), "sub", sub.sum(), "extra in full", (full & ~sub).sum())
    print(spec, "same", same, "differ", differ, "failed", failed, f"ms full {1e3*tf/max(same+differ,1):.3f} sub {1e3*ts/max(same+differ,1):.3f}", flush=True)
