"""Could thinning skip qhull? Does qhull's hull of a hull_surface cloud (merged as ``thin_hull_surface`` merges
it) pick exactly the cloud's first min(H, 256) points, the mesh hull's vertices it was built from? Prints the
meshes where it does not, and counts per folder (docs/ablations.md, "Reading the cloud where the push ends":
7-20 % differ, so no shortcut was built).

    python benchmarks/studies/hull_shortcut.py runs/frontier/pybullet/meshes_60 runs/external_val_100/meshes \
        runs/robosuite/meshes
"""
import sys, glob, numpy as np, warnings
warnings.filterwarnings("ignore")
from scipy.spatial import ConvexHull, QhullError
from physdyn.geometry.sampling import THIN_QHULL_OPTIONS
from physdyn.predict.body import prepare_body
for folder in sys.argv[1:]:
    files = sorted(glob.glob(folder + "/*.obj") + glob.glob(folder + "/*.stl") + glob.glob(folder + "/*/*.obj"))
    same = differ = failed = 0
    for f in files:
        try:
            body = prepare_body(f)
        except Exception:
            failed += 1
            continue
        cloud = body.points_body(256, "hull_surface")
        K = min(len(body.spec.body_vertices()), 256)
        on = np.zeros(256, bool)
        try:
            on[ConvexHull(cloud.astype(np.float64), qhull_options=THIN_QHULL_OPTIONS).vertices] = True
        except (QhullError, ValueError):
            on[:] = True
        first = np.zeros(256, bool); first[:K] = True
        if (on == first).all():
            same += 1
        else:
            differ += 1
            print("  differ", f, "K", K, "qhull", on.sum(), "extra", (on & ~first).sum(), "missing", (first & ~on).sum())
    print(folder, "same", same, "differ", differ, "failed", failed, flush=True)
