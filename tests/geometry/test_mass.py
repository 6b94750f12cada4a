import numpy as np
import pytest
import trimesh

from physdyn.geometry.mass import exact_mass_properties, voxel_mass_properties, voxel_pitch

DENSITY = 250.0


def box_inertia(m, a, b, c):
    return m / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def cylinder_inertia(m, r, h):
    side = m * (3 * r * r + h * h) / 12.0
    return np.array([side, side, m * r * r / 2.0])


@pytest.fixture
def box():
    return trimesh.creation.box((0.073, 0.060, 0.170))  # the paper's real-world box


@pytest.fixture
def cylinder():
    return trimesh.creation.cylinder(radius=0.05, height=0.2, sections=256)


def test_exact_box_matches_textbook(box):
    p = exact_mass_properties(box, DENSITY)
    m = DENSITY * 0.073 * 0.060 * 0.170
    assert p.mass == pytest.approx(m, rel=1e-9)
    np.testing.assert_allclose(np.diag(p.inertia), box_inertia(m, 0.073, 0.060, 0.170), rtol=1e-9)
    np.testing.assert_allclose(p.com, 0.0, atol=1e-12)


def test_exact_cylinder_matches_textbook(cylinder):
    p = exact_mass_properties(cylinder, DENSITY)
    m = DENSITY * np.pi * 0.05**2 * 0.2
    assert p.mass == pytest.approx(m, rel=1e-3)  # 256-gon vs circle: 1e-4 area error
    np.testing.assert_allclose(np.diag(p.inertia), cylinder_inertia(m, 0.05, 0.2), rtol=2e-3)


@pytest.mark.parametrize("name", ["box", "cylinder"])
def test_voxel_within_five_percent_of_exact(name, request):
    mesh = request.getfixturevalue(name)
    exact = exact_mass_properties(mesh, DENSITY)
    vox = voxel_mass_properties(mesh, DENSITY)
    assert abs(vox.mass - exact.mass) / exact.mass < 0.05
    np.testing.assert_allclose(np.diag(vox.inertia), np.diag(exact.inertia), rtol=0.05)
    np.testing.assert_allclose(vox.com, exact.com, atol=voxel_pitch(mesh))


def test_voxel_pitch_refines_for_small_objects(box):
    assert voxel_pitch(box) == pytest.approx(0.060 / 40)
    big = trimesh.creation.box((2.0, 2.0, 2.0))
    assert voxel_pitch(big) == pytest.approx(0.025)


def test_principal_axes_are_a_rotation_and_diagonalise():
    mesh = trimesh.creation.box((0.3, 0.1, 0.05))
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(rand=np.random.default_rng(3).random(3)))
    p = exact_mass_properties(mesh, DENSITY)
    moments, axes = p.principal()
    assert np.linalg.det(axes) == pytest.approx(1.0)
    np.testing.assert_allclose(axes.T @ p.inertia @ axes, np.diag(moments), atol=1e-12)
    m = DENSITY * 0.3 * 0.1 * 0.05
    np.testing.assert_allclose(np.sort(moments), np.sort(box_inertia(m, 0.3, 0.1, 0.05)), rtol=1e-9)


def test_vertical_inertia_is_the_turned_tensors_zz_per_mass(box):
    from scipy.spatial.transform import Rotation

    from physdyn.geometry.mass import vertical_inertia

    props = exact_mass_properties(box, DENSITY)
    moments, axes = props.principal()
    np.testing.assert_allclose(vertical_inertia(moments, axes, props.mass, np.array([0.0, 0.0, 0.0, 1.0])),
                               box_inertia(1.0, 0.073, 0.060, 0.170)[2], rtol=1e-9)  # upright: (a^2 + b^2) / 12
    q = Rotation.random(4, random_state=0).as_quat()
    R = Rotation.from_quat(q).as_matrix()
    tensor = axes @ np.diag(moments) @ axes.T
    expected = np.einsum("bi,ij,bj->b", R[:, 2, :], tensor, R[:, 2, :]) / props.mass
    got = vertical_inertia(np.tile(moments, (4, 1)), np.tile(axes, (4, 1, 1)), np.full(4, props.mass), q)
    np.testing.assert_allclose(got, expected, rtol=1e-9)
