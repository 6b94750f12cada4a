"""The contact prior's footprint as the 4 touching points spanning the largest area (greedily, as Bullet's
contact manifold keeps its points) instead of farthest-point sampling, as the option
``model.contact_footprint=area`` does (docs/research/contact-prior.md). Patches ``contact_geometry`` for this run only, so that the bundled model's
weights and the prior alone use it (and, for ``facet`` and ``flat``, other candidate points).

    python benchmarks/studies/footprint_area.py val [band|facet|flat] # quickstart validation: the prior alone, the bundled model
    python benchmarks/studies/footprint_area.py extval [band|facet|flat]  # the bundled model on the external validation set
    python benchmarks/studies/footprint_area.py hull STORE           # the prior alone on a store of meshes, footprint
                                                                     # from the cloud or from the mesh's convex-hull face
    python benchmarks/studies/footprint_area.py spin STORE           # every 6th mesh spun in place: PyBullet and the prior
    python benchmarks/studies/footprint_area.py run SCRIPT [ARGS]    # another study under the patch (band), e.g.
                                                                     # spin_primitives.py or spin_decel.py
    python benchmarks/studies/footprint_area.py {val,extval} band CHECKPOINT  # another model under the patch

``band``: among the cloud points within 5 mm of the lowest (the shipped candidates); ``facet``: among those
within 1 mm of the cloud's convex-hull facet under the centre of mass (``footprint_facet.py``); ``flat``: the
band chosen for area where 3 or more cloud points lie within 1 mm of the lowest (a flat face), the shipped
footprint elsewhere. ``hull``
rolls the prior alone out (no network) from each non-toppling push's step-0 state and prints the median
final rotation error with the shipped footprint, with the 4 largest-area vertices of the mesh's own
convex-hull face the body rests on (what the simulator collides), and with that face only where it has 3
or more vertices.
"""
import sys
from pathlib import Path

import numpy as np
import torch
import trimesh

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
import physdyn.models.dynamics_network as dm  # noqa: E402
import physdyn.models.priors as pri  # noqa: E402
from footprint_facet import touching_mask  # noqa: E402
from spin_primitives import prior_rollout  # noqa: E402

SHIPPED = pri.contact_geometry


def area_geometry(points, touching=None):
    """``contact_geometry`` with the footprint chosen for area (``model.contact_footprint=area``, built from
    this study)."""
    return SHIPPED(points, touching, footprint="area")


def hull_face_geometry(store, shape: int, orientation_xyzw: np.ndarray, hulls: dict) -> tuple[torch.Tensor, int]:
    """(1, 18) footprint geometry from the 4 largest-area vertices of the mesh's convex-hull face the body
    rests on in this orientation (what the simulator collides), and how many vertices that face has.
    ``hulls``: a cache of hull vertices (body frame) per shape."""
    from physdyn.geometry.rotations import quat_to_matrix

    if shape not in hulls:
        hulls[shape] = np.asarray(trimesh.load(store.source[shape], force="mesh").convex_hull.vertices) - store.com_mesh[shape]
    V = hulls[shape] @ quat_to_matrix(orientation_xyzw).T
    touching = V[:, 2] <= V[:, 2].min() + 5e-4
    return area_geometry(torch.tensor(V[None], dtype=torch.float32), torch.tensor(touching[None])), int(touching.sum())


def patch(candidates: str) -> None:
    def geometry(points, touching=None, footprint=None):  # the patch decides the footprint
        if touching is None and candidates == "flat":
            z = points[..., 2]
            flat = (z <= z.min(dim=1, keepdim=True).values + 0.001).sum(dim=1) >= 3
            return torch.where(flat[:, None], area_geometry(points), SHIPPED(points))
        if touching is None and candidates == "facet":
            masks = np.stack([touching_mask(p, 0.001) for p in points.detach().cpu().numpy().astype(np.float64)])
            touching = torch.from_numpy(masks).to(points.device)
        return area_geometry(points, touching)
    pri.contact_geometry = geometry
    dm.contact_geometry = geometry


def hull_rollouts(path: str) -> None:
    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia, world_oriented_points
    from physdyn.geometry.rotations import quat_conjugate, quat_multiply
    from physdyn.models.rotations import quat_multiply as turn_by, rotvec_to_quat

    store = load_store(path)
    sims = np.flatnonzero(~store.toppled)
    start, end = store.start[sims], store.start[sims + 1]
    q0 = store.orientation_xyzw[start]
    cloud = torch.tensor(world_oriented_points(store.points[store.shape_id[sims]][:, :256], q0), dtype=torch.float32)
    shipped = SHIPPED(cloud)
    hulls, vertices, face = {}, np.zeros(len(sims), int), []
    for i, sim in enumerate(sims):
        geometry, vertices[i] = hull_face_geometry(store, store.shape_id[sim], q0[i], hulls)
        face.append(geometry[0])
    face = torch.stack(face)
    mixed = torch.where(torch.tensor(vertices >= 3)[:, None], face, shipped)
    true_turn = quat_multiply(store.orientation_xyzw[end - 1], quat_conjugate(q0))
    inertia = torch.tensor(store_spin_inertia(store, sims, q0), dtype=torch.float32)
    print(f"{path}: {len(sims)} non-toppling pushes, {int((vertices < 3).sum())} resting on a hull face of < 3 vertices; "
          "the prior alone, median final rotation error (deg)")
    for name, geometry in (("cloud band, farthest points (shipped)", shipped), ("mesh hull face, largest area", face),
                           ("hull face where >= 3 vertices, else shipped", mixed)):
        geometry = geometry.clone()
        geometry[:, -2] = inertia  # the body's own I_zz / m, as the bundled model
        v = torch.tensor(store.linear_velocity[start], dtype=torch.float32)[:, None]
        w = torch.tensor(store.angular_velocity[start], dtype=torch.float32)[:, None]
        turn = torch.zeros(len(sims), 1, 4)
        turn[..., 3] = 1.0
        turns = [turn[:, 0].numpy().astype(np.float64)]
        for _ in range(int((end - start).max()) - 1):
            with torch.no_grad():
                c = pri.contact_changes(v, w, turn, geometry, 1 / store.rate_hz, float(np.median(store.friction)))
            v, w = v + c[..., :3], w + c[..., 3:6]
            turn = turn_by(rotvec_to_quat(c[..., 9:12]), turn)
            turn = turn / turn.norm(dim=-1, keepdim=True)
            turns.append(turn[:, 0].numpy().astype(np.float64))
        final = np.stack(turns, 1)[np.arange(len(sims)), end - start - 1]
        miss = quat_multiply(final, quat_conjugate(true_turn))
        error = np.degrees(2 * np.arccos(np.clip(np.abs(miss[:, 3]), 0, 1)))
        print(f"  {name:<45} all {np.median(error):5.1f}; faces of < 3 vertices {np.median(error[vertices < 3]):5.1f}, "
              f">= 3 {np.median(error[vertices >= 3]):5.1f}", flush=True)


def spin_in_place(path: str, w0: float = 10.0) -> None:
    """Every 6th mesh of a store, in its first push's resting pose, given a spin w0 about the vertical and
    nothing else: w_z over 5 steps in PyBullet and by the prior with either footprint."""
    from physdyn.data.store import load_store
    from physdyn.data.windows import store_spin_inertia, world_oriented_points
    from physdyn.predict.body import prepare_body
    from physdyn.predict.simulator import simulate_from_state

    store = load_store(path)
    spins = lambda g: np.round(prior_rollout(g, 0.0, w0, store.rate_hz, float(np.median(store.friction)))[0], 2)  # noqa: E731

    for shape in range(0, store.num_shapes, 6):
        sim = int(np.flatnonzero(store.shape_id == shape)[0])
        q0 = store.orientation_xyzw[store.start[sim]]
        simulated = simulate_from_state(prepare_body(store.source[shape]).spec, q0, np.zeros(3), np.array([0.0, 0.0, w0]),
                                        store.rate_hz, 6)["angular_velocity"][:, 2]
        cloud = SHIPPED(torch.tensor(world_oriented_points(store.points[shape][:256], q0)[None], dtype=torch.float32))
        face, vertices = hull_face_geometry(store, shape, q0, {})
        for g in (cloud, face):
            g[0, -2] = float(store_spin_inertia(store, np.array([sim]), q0[None])[0])
        print(f"shape {shape:3d}: w_z PyBullet {np.round(simulated, 2)}; prior, cloud band {spins(cloud)}; "
              f"prior, hull face of {vertices} vertices {spins(face)}", flush=True)


def main() -> None:
    which = sys.argv[1]
    if which in ("hull", "spin"):
        (hull_rollouts if which == "hull" else spin_in_place)(sys.argv[2])
        return
    if which == "run":
        import runpy
        patch("band")
        sys.argv = sys.argv[2:]
        runpy.run_path(str(HERE / sys.argv[0]), run_name="__main__")
        return
    patch(sys.argv[2] if len(sys.argv) > 2 else "band")
    if which == "val":
        from priors import prior_only_model

        from physdyn.data.store import load_store
        from physdyn.eval.evaluate import evaluate
        from physdyn.predict.predictor import BUNDLED_CHECKPOINT
        store = load_store("data/quickstart.zarr")
        models = [("the prior alone", prior_only_model("contact", store)), ("the bundled model", str(BUNDLED_CHECKPOINT))]
        if len(sys.argv) > 3:
            models = [(sys.argv[3], sys.argv[3])]
        for name, model in models:
            h = evaluate(model, store, split="val")["headline"]
            print(f"{name}: {100 * h['final_position_m_median']:.2f} cm {h['final_rotation_deg_median']:.1f} deg "
                  f"{1000 * h['position']:.2f} mm per step")
    else:
        import external_meshes
        checkpoint = ["--checkpoint", sys.argv[3]] if len(sys.argv) > 3 else []
        sys.argv = ["external_meshes.py", "--work", "runs/external_val", "--random", "60", "--random-from", "30", "--no-named"] + checkpoint
        external_meshes.main()


if __name__ == "__main__":
    main()
