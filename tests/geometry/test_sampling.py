"""Point representations: the hull_surface cloud keeps every convex-hull vertex, so its hull is the mesh's."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from physdyn.errors import PhysdynError
from physdyn.geometry.sampling import farthest_point_sample, hull_surface_points, sample_surface_points, shape_points
from physdyn.predict.body import prepare_body


def _rows(a: np.ndarray) -> set:
    return {tuple(r) for r in np.round(np.asarray(a, np.float64), 5)}


def _irregular_mesh() -> trimesh.Trimesh:
    """A lumpy convex-ish blob: a sphere with vertices pushed in and out, so the hull has many vertices."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    rng = np.random.default_rng(3)
    mesh.vertices *= rng.uniform(0.8, 1.2, (len(mesh.vertices), 1))
    return mesh


def test_farthest_point_sampling_keeps_the_picked_points_in_their_input_order():
    """From points[0] it picks 10 (the farthest), then 5, and returns them in their order in the input: a
    hull_surface cloud's first point stays its lowest hull vertex, where sampling started."""
    points = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [10.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    np.testing.assert_array_equal(farthest_point_sample(points, 3), points[[0, 1, 2]])
    np.testing.assert_array_equal(farthest_point_sample(points, 2), points[[0, 2]])


def test_hull_surface_cloud_holds_every_hull_vertex_and_has_the_mesh_hull():
    mesh = _irregular_mesh()
    hull = mesh.convex_hull.vertices
    assert 30 < len(hull) < 256
    points = hull_surface_points(mesh, 256, seed=0)
    assert points.shape == (256, 3) and points.dtype == np.float32
    assert _rows(hull) <= _rows(points)  # every vertex of the hull is in the cloud
    cloud_hull = ConvexHull(points.astype(np.float64))
    np.testing.assert_allclose(cloud_hull.volume, mesh.convex_hull.volume, rtol=1e-5)
    # the rest are surface samples: on the mesh's surface
    _, distance, _ = trimesh.proximity.closest_point(mesh, points[len(hull):])
    assert distance.max() < 1e-6


def test_uniform_surface_samples_lose_the_hull_corners():
    """Why the representation exists: the paper's cloud of the same size misses hull vertices and shrinks the hull."""
    mesh = _irregular_mesh()
    points = sample_surface_points(mesh, 256, 3, seed=0)
    assert not _rows(mesh.convex_hull.vertices) <= _rows(points)
    assert ConvexHull(points.astype(np.float64)).volume < 0.99 * mesh.convex_hull.volume


def test_a_hull_larger_than_the_cloud_is_thinned_to_well_spread_hull_vertices():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.05)  # 2,562 hull vertices
    points = hull_surface_points(mesh, 256, seed=0)
    assert points.shape == (256, 3)
    assert _rows(points) <= _rows(mesh.convex_hull.vertices)
    # the lowest vertex is always kept: contact starts there
    assert np.isclose(points[:, 2].min(), mesh.vertices[:, 2].min())
    assert ConvexHull(points.astype(np.float64)).volume > 0.95 * mesh.convex_hull.volume


def test_prepared_body_points_are_in_the_body_frame_and_repeatable():
    body = prepare_body(_irregular_mesh())
    a = body.points_body(256, "hull_surface")
    b = prepare_body(_irregular_mesh()).points_body(256, "hull_surface")
    np.testing.assert_array_equal(a, b)
    hull_body = body.spec.body_vertices()  # the simulator's hull, body frame
    assert _rows(hull_body) <= _rows(a)
    with pytest.raises(PhysdynError, match="points method 'grid' is unknown"):
        shape_points(body.mesh, 64, "grid")


def test_a_thinned_hull_surface_cloud_keeps_its_hull_points_first_then_its_own_samples():
    from physdyn.geometry.hull import point_hull
    from physdyn.geometry.sampling import thin_hull_surface

    box = trimesh.creation.box((0.1, 0.2, 0.3))
    cloud = hull_surface_points(box, 64)
    thin = thin_hull_surface(cloud, 20)
    # the eight corners first (a box's samples lie exactly on its faces: none is a hull point), then the
    # cloud's own samples in their order
    assert {tuple(p) for p in thin[:8]} == {tuple(p) for p in box.vertices.astype(np.float32)}
    np.testing.assert_array_equal(thin[8:], cloud[8:20])
    assert thin.dtype == np.float32 and ConvexHull(thin).volume == pytest.approx(box.volume, rel=1e-6)
    # more hull points than the count: hull points only, spread from the lowest over the whole can
    can = trimesh.creation.cylinder(radius=0.05, height=0.2, sections=64)
    cloud = hull_surface_points(can, 256)
    thin = thin_hull_surface(cloud, 32)
    on_hull = {tuple(p) for p in cloud[point_hull(cloud.astype(np.float64)).vertex_index]}
    assert len(on_hull) > 32 and {tuple(p) for p in thin} <= on_hull
    assert thin[0, 2] == cloud[:, 2].min()
    np.testing.assert_allclose(np.ptp(thin, axis=0), np.ptp(cloud, axis=0), rtol=0.02)
    np.testing.assert_array_equal(thin_hull_surface(cloud, 256), cloud)  # nothing to thin
    # a turned box: float32 samples on its slanted faces are not taken for corners, so all eight stay
    turned = trimesh.creation.box((0.1, 0.2, 0.3))
    turned.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(3).random(3)))
    cloud = hull_surface_points(turned, 64)
    thin = thin_hull_surface(cloud, 16)
    assert ConvexHull(thin).volume == pytest.approx(turned.volume, rel=1e-6)
    np.testing.assert_array_equal(thin[8:], cloud[8:16])


def test_a_cloud_made_from_a_mesh_is_thinned_from_its_known_hull_without_qhull(monkeypatch):
    """Given how many of a ``hull_surface`` cloud's first points are its mesh's hull vertices (a prepared body
    knows), thinning it runs no qhull and takes those for its hull; where qhull marks just those (a box, an
    irregular mesh), both thin it alike. A cloud without it (a store's) still goes through qhull."""
    import scipy.spatial

    import physdyn.geometry.sampling as sampling

    box = trimesh.creation.box((0.1, 0.2, 0.3))
    box.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(5).random(3)))
    for mesh, count in ((box, 16), (_irregular_mesh(), 24)):
        body = prepare_body(mesh)
        cloud = body.points_body(64, "hull_surface")
        hull_size = len(body.spec.body_vertices())
        assert body.hull_count(64) == min(hull_size, 64)
        with monkeypatch.context() as patched:
            patched.setattr(scipy.spatial, "ConvexHull", None)  # any qhull run would fail
            known = sampling.thin_hull_surface(cloud, count, body.hull_count(64))
        qhull = sampling.thin_hull_surface(cloud, count)
        np.testing.assert_array_equal(known, qhull)
        kept = min(hull_size, count)
        assert {tuple(p) for p in known[:kept]} <= {tuple(p) for p in cloud[:hull_size]}
        np.testing.assert_array_equal(known[kept:], cloud[hull_size:hull_size + count - kept])
