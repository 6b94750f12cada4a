"""Point representations: the hull_surface cloud keeps every convex-hull vertex, so its hull is the mesh's."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from physdyn.errors import PhysdynError
from physdyn.geometry.sampling import hull_surface_points, sample_surface_points, shape_points
from physdyn.predict.body import prepare_body


def _rows(a: np.ndarray) -> set:
    return {tuple(r) for r in np.round(np.asarray(a, np.float64), 5)}


def _irregular_mesh() -> trimesh.Trimesh:
    """A lumpy convex-ish blob: a sphere with vertices pushed in and out, so the hull has many vertices."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    rng = np.random.default_rng(3)
    mesh.vertices *= rng.uniform(0.8, 1.2, (len(mesh.vertices), 1))
    return mesh


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
