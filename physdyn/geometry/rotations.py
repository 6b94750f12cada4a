"""Rotation maths on scalar-last (x, y, z, w) quaternions, as PyBullet and SciPy store them."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation


# Up to this many quaternions the two functions below gather their products in a few array operations (each
# operation's dispatch, microseconds, is most of the cost of a few quaternions); above it they write the
# arithmetic out per component, which passes over a large batch's memory fewer times (5x cheaper for 4,096).
# The two ways give the same bits (for a NaN, its sign apart).
GATHERED_AT_MOST = 256

# quat_to_matrix's entries, row by row, as 1 - 2 (a + b) on the diagonal and 2 (a +/- b) off it, a and b
# among the products xx yy zz xy xz yz xw yw zw (indices 0-8 of _PRODUCTS)
_PRODUCTS = (np.array([0, 1, 2, 0, 0, 1, 0, 1, 2]), np.array([0, 1, 2, 1, 2, 2, 3, 3, 3]))
_FIRST = np.array([1, 3, 4, 3, 0, 5, 4, 5, 0])
_SECOND = np.array([2, 8, 7, 8, 2, 6, 7, 6, 1])
_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_DIAGONAL = np.array([0, 4, 8])


def quat_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """q_xyzw: (..., 4), normalised here -> (..., 3, 3). Closed form: 1 - 2 (y y + z z), 2 (x y - z w), ...
    A prediction of one push calls it about ten times on a few numbers: gathered in a dozen array operations
    (``GATHERED_AT_MOST``) instead of written out, 31 against 83 us a call."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    if q.shape[-1:] != (4,):  # the gathered products would read the first four numbers of anything
        raise ValueError(f"quaternions (..., 4) expected, got shape {q.shape}")
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    if q.size > 4 * GATHERED_AT_MOST:  # written out: fewer passes over a large batch's memory
        x, y, z, w = np.moveaxis(q, -1, 0)
        return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                         2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                         2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1).reshape(q.shape[:-1] + (3, 3))
    products = q[..., _PRODUCTS[0]] * q[..., _PRODUCTS[1]]
    twice = 2 * (products[..., _FIRST] + _SIGN * products[..., _SECOND])  # a + (-b) is a - b, to the bit
    twice[..., _DIAGONAL] = 1 - twice[..., _DIAGONAL]
    return twice.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """m: (..., 3, 3) rotation matrices -> (..., 4) unit quaternions with w >= 0."""
    m = np.asarray(m, dtype=np.float64)
    q = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat().reshape(m.shape[:-2] + (4,))
    return canonical_quat(q)


def canonical_quat(q_xyzw: np.ndarray) -> np.ndarray:
    """The same rotation with w >= 0 (q and -q are one rotation)."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    return np.where(q[..., 3:4] < 0, -q, q)


# quat_multiply's terms, component by component: a's w, x, y, z times these of b's components, with these signs
_B_TERMS = np.array([[0, 3, 2, 1], [1, 2, 3, 0], [2, 1, 0, 3], [3, 0, 1, 2]])
_A_TERMS = np.array([3, 0, 1, 2])
_TERM_SIGNS = np.array([[1.0, 1.0, 1.0, -1.0], [1.0, -1.0, 1.0, 1.0], [1.0, 1.0, -1.0, 1.0], [1.0, -1.0, -1.0, -1.0]])


def quat_multiply(a_xyzw: np.ndarray, b_xyzw: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (apply b, then a): x = aw bx + ax bw + ay bz - az by, and so on, summed in that
    order. A prediction of one push makes a dozen of these small products: gathered in a few array operations
    (``GATHERED_AT_MOST``), 15 against 23 us for one pair, 24 against 55 us for a sequence."""
    a, b = np.asarray(a_xyzw, dtype=np.float64), np.asarray(b_xyzw, dtype=np.float64)
    # (the size by math.prod: numpy's prod of a shape cost 11 of a pair's 30 us)
    size = a.size if a.shape == b.shape else math.prod(np.broadcast_shapes(a.shape, b.shape))
    if size > 4 * GATHERED_AT_MOST:  # written out: fewer passes over a large batch's memory
        ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
        bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
        out = np.empty(np.broadcast_shapes(a.shape, b.shape))
        out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
        out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
        out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
        out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
        return out
    terms = a[..., _A_TERMS][..., None, :] * b[..., _B_TERMS] * _TERM_SIGNS  # (..., 4 components, 4 terms)
    return terms[..., 0] + terms[..., 1] + terms[..., 2] + terms[..., 3]  # t + (-u) is t - u, to the bit


def quat_conjugate(q_xyzw: np.ndarray) -> np.ndarray:
    q = np.asarray(q_xyzw, dtype=np.float64)
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


def rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """Exp: axis-angle (..., 3) -> quaternion (..., 4)."""
    r = np.asarray(rotvec, dtype=np.float64)
    return Rotation.from_rotvec(r.reshape(-1, 3)).as_quat().reshape(r.shape[:-1] + (4,))


def turn_about_vertical(angle: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """Exp(angle z) * q: each rotation (..., 4) turned by ``angle`` (...) radians about the world vertical.
    ``quat_multiply(rotvec_to_quat(angle * z), q)`` written out for that axis, without scipy's general
    Exp (the same to rounding; a third of its cost on one push's steps)."""
    half = 0.5 * np.asarray(angle, dtype=np.float64)
    c, s = np.cos(half), np.sin(half)
    q = np.asarray(q_xyzw, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([c * x - s * y, c * y + s * x, c * z + s * w, c * w - s * z], axis=-1)


def quat_to_rotvec(q_xyzw: np.ndarray) -> np.ndarray:
    """Log: quaternion (..., 4) -> axis-angle (..., 3), angle in [0, pi]."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4)).as_rotvec().reshape(q.shape[:-1] + (3,))


def world_delta_rotvec(q_prev_xyzw: np.ndarray, q_next_xyzw: np.ndarray) -> np.ndarray:
    """World-frame rotation between two orientations: Log(R_next R_prev^T), so R_next = Exp(d) R_prev."""
    return quat_to_rotvec(quat_multiply(q_next_xyzw, quat_conjugate(q_prev_xyzw)))


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Radians into (-pi, pi]."""
    wrapped = np.pi - np.mod(np.pi - np.asarray(angle, dtype=np.float64), 2.0 * np.pi)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def tilt_angle(q0_xyzw: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """Angle (rad) between world z and the object's initial up direction carried by its rotation since q0.

    The initial up direction is world z at q0; in the body it is R0^T z, and at q it points along
    R R0^T z. Shapes: q0 (4,) or (..., 4); q (..., 4) -> (...).
    """
    rel = quat_to_matrix(quat_multiply(q_xyzw, quat_conjugate(np.broadcast_to(q0_xyzw, np.shape(q_xyzw)))))
    up_z = np.clip(rel[..., 2, 2], -1.0, 1.0)
    return np.arccos(up_z)


def continuous_quat(q_xyzw: np.ndarray) -> np.ndarray:
    """(T, 4) -> a copy whose consecutive quaternions have a non-negative dot product (q and -q are the same
    rotation; trackers export them continuous, and averaging needs it)."""
    q = np.array(q_xyzw, dtype=np.float64)
    flips = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
    q[1:] *= flips[:, None]
    return q
