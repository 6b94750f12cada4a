"""Checks of a prediction request's inputs, where they enter: each bad value is a one-line ``PredictionError``
naming the input, the value and the fix. ``Predictor`` (``predictor.py``) and `physdyn predict` use them."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from physdyn.errors import PredictionError

MAX_LINEAR_SPEED = 50.0  # m/s; training pushes are 0.5-2 m/s
MAX_ANGULAR_SPEED = 500.0  # rad/s
MAX_SECONDS = 600.0  # a pushed object rests within seconds; far longer only allocates


def as_vector(value: Any, name: str, length: int = 3) -> np.ndarray:
    """``value`` as a finite float64 vector of ``length``; a one-line ``PredictionError`` naming ``name``."""
    try:
        vec = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise PredictionError(f"{name} must be {length} numbers, got {value!r}") from None
    if np.ndim(value) > 1 or vec.size != length:
        raise PredictionError(f"{name} must be {length} numbers, got {vec.size} ({_short(value)})")
    if not np.isfinite(vec).all():
        raise PredictionError(f"{name} must be finite, got {_short(value)}; pass {length} real numbers")
    return vec


def positive_number(value: Any, what: str, example: str, unit: str = "") -> float:
    """``value`` as a finite number above 0, or a one-line ``PredictionError`` naming ``what`` and the fix
    (``example``: a flag as a user would give it; ``unit``: e.g. " of seconds")."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise PredictionError(f"{what} must be a number{unit}, got {value!r}") from None
    if not math.isfinite(number) or number <= 0:
        raise PredictionError(f"{what} must be a positive number{unit}, got {value!r}; e.g. {example}")
    return number


def check_seconds(seconds: Any) -> float:
    s = positive_number(seconds, "seconds", "--seconds 3")
    if s > MAX_SECONDS:
        raise PredictionError(f"seconds must be at most {MAX_SECONDS:g} (objects come to rest within a few), got {seconds!r}")
    return s


ZERO_QUATERNION = "orientation (x, y, z, w) is the zero quaternion; pass a rotation, e.g. 0 0 0 1"


def check_orientation(orientation_xyzw: Any) -> np.ndarray:
    """Unit quaternion (x, y, z, w) from ``orientation_xyzw``; identity (the mesh frame as is) for None."""
    if orientation_xyzw is None:
        return np.array([0.0, 0.0, 0.0, 1.0])
    q = as_vector(orientation_xyzw, "orientation (x, y, z, w)", 4)
    norm = float(np.linalg.norm(q))
    if norm < 1e-9:
        raise PredictionError(ZERO_QUATERNION)
    return q / norm


def _per_request(value: Any, count: int, name: str, length: int = 3) -> np.ndarray:
    """(count, length) finite float64 from one vector for every request or one row per request."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PredictionError(f"{name}: expected {length} numbers or {count} rows of {length}, got {_short(value)}") from None
    if arr.shape == (length,):
        return np.tile(as_vector(arr, name, length), (count, 1))
    if arr.shape != (count, length):
        raise PredictionError(f"{name}: expected {length} numbers or {count} rows of {length}, got shape {arr.shape}")
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():  # the first bad row's own message (checking every row one by one costs 20 us a push)
        i = int(np.argmin(finite))
        as_vector(arr[i], f"{name} of request {i + 1}", length)
    return arr


def _orientations(orientation_xyzw: Any, count: int) -> np.ndarray:
    """(count, 4) unit quaternions: ``check_orientation`` of one value for every request or one row per
    request, all rows at once (each row's norm as ``np.linalg.norm`` of the row alone computes it: a batched
    dot product, so the same numbers to the bit)."""
    if orientation_xyzw is None:
        return np.tile(check_orientation(None), (count, 1))
    q = _per_request(orientation_xyzw, count, "orientation (x, y, z, w)", 4)
    norm = np.sqrt(np.matmul(q[:, None, :], q[:, :, None])[:, 0, 0])
    if (norm < 1e-9).any():
        raise PredictionError(ZERO_QUATERNION)
    return q / norm[:, None]


def _per_request_values(value: Any, count: int, name: str) -> list:
    """One scalar for all requests, or a sequence of ``count``."""
    if isinstance(value, (str, bytes)) or np.ndim(value) == 0:
        return [value] * count
    values = list(value)
    if len(values) != count:
        raise PredictionError(f"{name}: expected one value or {count}, got {len(values)}")
    return values


def _boolean(value: Any, name: str) -> bool:
    """A real boolean: the strings "no" or "false" are not read as true."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise PredictionError(f"{name} must be true or false, got {value!r}")


def _short(value: Any) -> str:
    text = " ".join(str(v) for v in np.ravel(value)) if np.ndim(value) else str(value)
    return text if len(text) <= 60 else text[:57] + "..."
