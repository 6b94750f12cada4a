"""Per-face quantities, surface samples, mass integrals and the convex hull, computed by physdyn's faster
routes, give trimesh's numbers to the bit: the stores' bodies and clouds do not change with them."""

import numpy as np
import pytest
import trimesh

from physdyn.geometry.hull import point_hull
from physdyn.geometry.mass import exact_mass_properties
from physdyn.geometry.sampling import uniform_surface_samples
from physdyn.geometry.surface import face_areas, face_crosses


@pytest.fixture(scope="module")
def meshes():
    box = trimesh.creation.box((0.073, 0.060, 0.170))
    box.apply_translation([-0.2, 0.1, -0.05])  # negative coordinates: numpy cubes them on a slower path
    bumpy = trimesh.creation.icosphere(3, radius=0.1)
    bumpy.vertices *= 1.0 + 0.2 * np.random.default_rng(0).random((len(bumpy.vertices), 1))
    return {"box": box, "bumpy": bumpy, "torus": trimesh.creation.torus(0.1, 0.03),
            "cylinder": trimesh.creation.cylinder(radius=0.05, height=0.2, sections=64)}


def test_face_crosses_and_areas_are_trimeshs(meshes):
    for name, mesh in meshes.items():
        crosses = face_crosses(np.asarray(mesh.vertices), np.asarray(mesh.faces))
        np.testing.assert_array_equal(crosses, mesh.triangles_cross, err_msg=name)
        np.testing.assert_array_equal(face_areas(crosses), mesh.area_faces, err_msg=name)


def test_exact_mass_properties_are_trimeshs_to_the_bit(meshes):
    for name, mesh in meshes.items():
        props, ref = exact_mass_properties(mesh, 250.0), mesh.mass_properties
        assert props.volume == ref.volume and props.mass == ref.volume * 250.0, name
        np.testing.assert_array_equal(props.com, ref.center_mass, err_msg=name)
        np.testing.assert_array_equal(props.inertia, ref.inertia * 250.0, err_msg=name)


def test_uniform_surface_samples_are_trimeshs_draws(meshes):
    for name, mesh in meshes.items():
        for count, seed in ((1, 0), (100, 3), (1000, 0)):
            expected, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
            np.testing.assert_array_equal(uniform_surface_samples(mesh, count, seed), expected, err_msg=name)


def test_point_hull_is_trimeshs_convex_hull(meshes):
    for name, mesh in meshes.items():
        hull = point_hull(np.asarray(mesh.vertices))
        np.testing.assert_array_equal(mesh.vertices[hull.vertex_index], mesh.convex_hull.vertices, err_msg=name)
        assert hull.volume == pytest.approx(mesh.convex_hull.volume, rel=1e-12), name
    flat = np.c_[np.random.default_rng(0).random((20, 2)), np.zeros(20)]
    assert point_hull(flat) is None and point_hull(flat[:3]) is None
