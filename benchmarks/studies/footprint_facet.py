"""The contact prior's footprint read from the cloud's convex-hull facet under the centre of mass (the face
the simulator's convex-hull collision shape rests on): the points within TOL metres of that facet's plane,
instead of the points within 5 mm of the lowest one. Patches ``contact_geometry`` for this run only.

    python benchmarks/studies/footprint_facet.py 0.001 val       # the bundled model, quickstart validation split
    python benchmarks/studies/footprint_facet.py 0.001 prior-val # the contact prior alone
    python benchmarks/studies/footprint_facet.py 0.001 ext       # benchmarks/external_meshes.py's meshes
    python benchmarks/studies/footprint_facet.py 0.001 extval    # its validation set (--random 60 --random-from 30 --no-named)
"""
import sys, torch, numpy as np
from scipy.spatial import ConvexHull, QhullError
import physdyn.models.priors as pri
def touching_mask(P, TOL, PERIMETER=False):  # P (N, 3) numpy; PERIMETER: the outline's corners only
    z = P[:, 2]; band = z <= z.min() + pri.SUPPORT_DEPTH
    try:
        hull = ConvexHull(P)
    except QhullError:
        return band
    # The facet the downward vertical through the centre of mass (inside the hull) leaves it by: among the
    # facets facing down (n . (0, 0, -1) > 0), the nearest along the ray (the distance -c / that product).
    eq = hull.equations  # n . x + c <= 0 inside, n outward
    along = -eq[:, 2]
    if not (along > 1e-12).any():
        return band
    k = np.argmin(np.where(along > 1e-12, -eq[:, 3] / np.where(along > 1e-12, along, 1.0), np.inf))
    n, c = eq[k, :3], eq[k, 3]
    on = (P @ n + c) >= -TOL
    if PERIMETER and on.sum() >= 3:  # only the corners of the facet's outline (where Bullet keeps its contacts)
        idx = np.flatnonzero(on)
        try:
            corners = idx[ConvexHull(P[idx, :2]).vertices]
        except QhullError:
            return on
        on = np.zeros_like(on)
        on[corners] = True
    return on
def main():
    TOL = float(sys.argv[1].rstrip("p")); which = sys.argv[2]
    PERIMETER = sys.argv[1].endswith("p")  # e.g. 0.001p: the outline's corners only
    orig = pri.contact_geometry
    def patched(points):
        masks = np.stack([touching_mask(p, TOL, PERIMETER) for p in points.detach().cpu().numpy().astype(np.float64)])
        return orig(points, torch.from_numpy(masks).to(points.device))
    pri.contact_geometry = patched
    import physdyn.models.dynamics_network as dm
    dm.contact_geometry = patched
    if which in ("val", "test", "prior-val", "prior-test"):
        from physdyn.eval.evaluate import evaluate
        from physdyn.predict.predictor import BUNDLED_CHECKPOINT
        split = which.split("-")[-1]
        if which.startswith("prior"):
            sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1])); from priors import prior_only_model; from physdyn.data.store import load_store
            st = load_store("data/quickstart.zarr"); m = prior_only_model("contact", st)
        else:
            m = str(BUNDLED_CHECKPOINT); st = "data/quickstart.zarr"
        h = evaluate(m, st, split=split)["headline"]
        print(f"TOL={TOL} {which}: {100*h['final_position_m_median']:.2f} cm {h['final_rotation_deg_median']:.1f} deg")
    else:
        sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1])); import external_meshes as em
        sys.argv = ["x"] + (["--work", "runs/external_val", "--random", "60", "--random-from", "30", "--no-named"] if which == "extval" else []) + sys.argv[3:]
        print(f"TOL={TOL} {which}"); em.main()


if __name__ == "__main__":
    main()
