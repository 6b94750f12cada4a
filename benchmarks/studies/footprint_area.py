"""The contact prior's footprint from the mesh's own convex-hull face the body rests on (what the simulator
collides) against the one read from the cloud (docs/research/contact-prior.md); the footprint's 4 points are
chosen to span the largest area, as Bullet's contact manifold keeps its points and as the option
``model.contact_footprint=area`` does.

    python -m benchmarks.studies.footprint_area hull STORE    # the prior alone on a store of meshes, footprint
                                                              # from the cloud or from the mesh's convex-hull face
    python -m benchmarks.studies.footprint_area spin STORE    # every 6th mesh spun in place: PyBullet and the prior

``hull`` rolls the prior alone out (no network) from each non-toppling push's step-0 state and prints the
median final rotation error with the shipped footprint, with the 4 largest-area vertices of the mesh's own
convex-hull face the body rests on, and with that face only where it has 3 or more vertices.
"""
import sys

import numpy as np
import torch
import trimesh

import physdyn.models.priors as pri
from benchmarks.studies.common import prior_rollout

SHIPPED = pri.contact_geometry


def area_geometry(points, touching=None):
    """``contact_geometry`` with the footprint chosen for area (``model.contact_footprint=area``)."""
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
    if len(sys.argv) != 3 or sys.argv[1] not in ("hull", "spin"):
        sys.exit(__doc__)
    (hull_rollouts if sys.argv[1] == "hull" else spin_in_place)(sys.argv[2])


if __name__ == "__main__":
    main()
