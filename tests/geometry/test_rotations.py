"""The quaternion maths every roll-out and training batch uses, against SciPy's rotations, for the shapes the
callers pass: one quaternion, a batch, a batch of sequences, and one broadcast against many; a few
quaternions and many take two ways through the code (``GATHERED_AT_MOST``), which give the same bits."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physdyn.geometry.rotations import quat_conjugate, quat_multiply, quat_to_matrix, rotvec_to_quat, turn_about_vertical


@pytest.mark.parametrize("shape", [(4,), (1, 4), (6, 4), (2, 5, 4), (0, 4), (300, 4), (3, 100, 4)])  # both ways
def test_quat_to_matrix_is_scipys_rotation_matrix_of_the_normalised_quaternion(shape):
    q = np.random.default_rng(0).normal(size=shape) * 3.0  # not unit: it normalises
    m = quat_to_matrix(q)
    assert m.shape == shape[:-1] + (3, 3)
    expected = Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(shape[:-1] + (3, 3)) if q.size else m
    np.testing.assert_allclose(m, expected, atol=1e-12)


@pytest.mark.parametrize("shapes", [((4,), (4,)), ((7, 4), (7, 4)), ((1, 4), (9, 4)), ((3, 1, 4), (3, 5, 4)), ((4,), (2, 3, 4)), ((300, 4), (300, 4)), ((1, 4), (3, 100, 4))])
def test_quat_multiply_composes_rotations_as_scipy_does(shapes):
    rng = np.random.default_rng(1)
    a, b = (q / np.linalg.norm(q, axis=-1, keepdims=True) for q in (rng.normal(size=s) for s in shapes))
    product = quat_multiply(a, b)
    A, B = np.broadcast_arrays(a, b)
    expected = (Rotation.from_quat(A.reshape(-1, 4)) * Rotation.from_quat(B.reshape(-1, 4))).as_quat().reshape(A.shape)
    assert product.shape == A.shape
    # q and -q are one rotation: compare the matrices
    np.testing.assert_allclose(quat_to_matrix(product), quat_to_matrix(expected), atol=1e-12)
    # a rotation and its inverse compose to the identity
    np.testing.assert_allclose(quat_multiply(a, quat_conjugate(a)), np.broadcast_to([0.0, 0.0, 0.0, 1.0], a.shape), atol=1e-15)


def test_a_few_quaternions_and_many_give_the_same_bits():
    from physdyn.geometry.rotations import GATHERED_AT_MOST

    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2 * GATHERED_AT_MOST, 4)), rng.normal(size=(2 * GATHERED_AT_MOST, 4))
    b[:5] = 0.0  # zeros, whose signs the products keep
    many, few = quat_multiply(a, b), np.concatenate([quat_multiply(a[i : i + 7], b[i : i + 7]) for i in range(0, len(a), 7)])
    assert np.array_equal(many, few) and np.array_equal(np.signbit(many), np.signbit(few))
    many, few = quat_to_matrix(a), np.concatenate([quat_to_matrix(a[i : i + 7]) for i in range(0, len(a), 7)])
    assert np.array_equal(many, few)


def test_a_quaternion_of_another_length_is_refused():
    for shape in ((5,), (2, 5), (3,)):
        with pytest.raises(ValueError, match="quaternions"):
            quat_to_matrix(np.ones(shape))


def test_a_turn_about_the_vertical_is_the_general_product_with_its_rotation():
    rng = np.random.default_rng(4)
    q = rng.normal(size=(3, 7, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    angle = rng.uniform(-7.0, 7.0, (3, 7))
    angle[0, :3] = [0.0, 1e-9, -3e-5]  # scipy's Exp takes a series there
    general = quat_multiply(rotvec_to_quat(angle[..., None] * np.array([0.0, 0.0, 1.0])), q)
    np.testing.assert_allclose(turn_about_vertical(angle, q), general, atol=1e-15)
    turned = Rotation.from_quat(turn_about_vertical(angle, q).reshape(-1, 4))
    yaw = Rotation.from_rotvec(angle.reshape(-1, 1) * np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(turned.as_matrix(), (yaw * Rotation.from_quat(q.reshape(-1, 4))).as_matrix(), atol=1e-12)
