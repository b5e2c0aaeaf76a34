"""Rotations as unit quaternions, and the frames they connect.

Conventions (used everywhere in the project):

* Quaternions are ``(w, x, y, z)`` arrays, Hamilton product, *active* rotations:
  ``v_out = q * v_in * conj(q)``. ``quat_to_matrix(q) @ v_in`` gives the same ``v_out``.
* The world frame is the local level frame at the landing site: x east, y north, z up (m); the
  ground is the plane z = 0.
* The lander body frame has z along the lander's symmetry axis pointing up (towards the parachute),
  x and y level when the lander hangs straight. A lander's *attitude* is the body-to-world
  quaternion, so the identity attitude is a level lander with the camera looking at nadir.
* The camera frame is the CAHVOR frame: x along image columns (right), y along image rows (down),
  z along the boresight.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def quat_normalize(quaternion: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) with non-negative w (the same rotation).

    Parameters
    ----------
    quaternion : ndarray, shape (..., 4)
        Quaternion(s) (w, x, y, z), any non-zero finite norm.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion(s), ``w >= 0``.

    Raises
    ------
    ValueError
        A zero or non-finite quaternion (no rotation to normalise to).
    """
    quaternion = np.asarray(quaternion, dtype=float)
    norm = np.sqrt(np.add.reduce(quaternion * quaternion, axis=-1, keepdims=True))   # np.linalg.norm's sum, less overhead
    if not np.all((norm > 0) & np.isfinite(norm)):
        raise ValueError(f"quaternion (w, x, y, z) must be finite with a non-zero norm; got {quaternion!r}")
    quaternion = quaternion / norm
    return np.where(quaternion[..., :1] < 0, -quaternion, quaternion)


def quat_multiply(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Hamilton product ``left * right`` (apply ``right`` first), broadcasting over leading axes.

    Parameters
    ----------
    left, right : ndarray, shape (..., 4)
        Quaternions (w, x, y, z).

    Returns
    -------
    ndarray, shape (..., 4)
        The product.
    """
    left, right = np.asarray(left, dtype=float), np.asarray(right, dtype=float)
    lw, lx, ly, lz = left[..., 0], left[..., 1], left[..., 2], left[..., 3]
    rw, rx, ry, rz = right[..., 0], right[..., 1], right[..., 2], right[..., 3]
    product = np.empty(np.broadcast_shapes(left.shape, right.shape))
    product[..., 0] = lw * rw - lx * rx - ly * ry - lz * rz
    product[..., 1] = lw * rx + lx * rw + ly * rz - lz * ry
    product[..., 2] = lw * ry - lx * rz + ly * rw + lz * rx
    product[..., 3] = lw * rz + lx * ry - ly * rx + lz * rw
    return product


def quat_conjugate(quaternion: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion.

    Parameters
    ----------
    quaternion : ndarray, shape (..., 4)
        Unit quaternion(s) (w, x, y, z).

    Returns
    -------
    ndarray, shape (..., 4)
        The conjugate(s) ``(w, -x, -y, -z)``.
    """
    return np.asarray(quaternion, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_from_axis_angle(axis: np.ndarray | Sequence[float], angle_rad: float | np.ndarray) -> np.ndarray:
    """Quaternion rotating by ``angle_rad`` (right-handed) about ``axis``.

    Parameters
    ----------
    axis : array_like, shape (3,)
        Rotation axis, finite and non-zero (any length).
    angle_rad : float or ndarray, shape (...)
        Rotation angle(s) (rad).

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion(s) (w, x, y, z).
    """
    axis = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    if not np.all((norm > 0) & np.isfinite(norm)) or not np.all(np.isfinite(angle_rad)):
        raise ValueError(f"rotation axis must be a finite non-zero 3-vector and the angle finite; "
                         f"got axis {axis!r}, angle {angle_rad!r}")
    axis = axis / norm
    half = 0.5 * np.asarray(angle_rad, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_from_rotation_vector(rotation_vector_rad: np.ndarray) -> np.ndarray:
    """Quaternion of the rotation ``exp([v]x)``: axis ``v/|v|``, angle ``|v|``.

    Parameters
    ----------
    rotation_vector_rad : ndarray, shape (..., 3)
        Rotation vector(s) v (rad).

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion(s) (w, x, y, z).
    """
    rotation_vector_rad = np.asarray(rotation_vector_rad, dtype=float)
    angle = np.linalg.norm(rotation_vector_rad, axis=-1, keepdims=True)
    if not np.all(np.isfinite(angle)):
        raise ValueError(f"rotation vector (rad) must be finite; got {rotation_vector_rad!r}")
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0 (series keeps full precision for tiny angles)
    scale = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 1e-8, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), scale * rotation_vector_rad], axis=-1)


def quat_to_rotation_vector(quaternion: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quat_from_rotation_vector` (angle in [0, pi]).

    Parameters
    ----------
    quaternion : ndarray, shape (..., 4)
        Unit quaternion(s) (w, x, y, z).

    Returns
    -------
    ndarray, shape (..., 3)
        Rotation vector(s) (rad).
    """
    quaternion = quat_normalize(quaternion)
    vector = quaternion[..., 1:]
    sin_half = np.linalg.norm(vector, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, quaternion[..., :1])
    scale = np.where(sin_half > 1e-12, angle / np.where(sin_half > 1e-12, sin_half, 1.0), 2.0)
    return scale * vector


def quat_to_matrix(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrix/matrices of unit quaternion(s).

    Parameters
    ----------
    quaternion : ndarray, shape (..., 4)
        Unit quaternion(s) (w, x, y, z).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    values = np.asarray(quaternion, dtype=float)
    if values.shape == (4,):
        return _quat_to_matrix_one(values)
    unit = quat_normalize(values)
    w, x, y, z = unit[..., 0], unit[..., 1], unit[..., 2], unit[..., 3]
    matrix = np.empty(unit.shape[:-1] + (3, 3))
    matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    matrix[..., 1, 0], matrix[..., 1, 1], matrix[..., 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    matrix[..., 2, 0], matrix[..., 2, 1], matrix[..., 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return matrix


def _quat_to_matrix_one(quaternion: np.ndarray) -> np.ndarray:
    """:func:`quat_to_matrix` of one quaternion (shape (4,)) in Python floats, ~10x fewer calls.

    The same IEEE operations in the same order: the squared norm summed left to right (numpy's reduction of four
    values), each component divided by the norm, the sign of w made non-negative, the same matrix expressions.
    """
    w, x, y, z = quaternion.tolist()
    norm = math.sqrt(((w * w + x * x) + y * y) + z * z)
    if not (norm > 0 and math.isfinite(norm)):
        raise ValueError(f"quaternion (w, x, y, z) must be finite with a non-zero norm; got {quaternion!r}")
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def matrix_to_quat(matrix: np.ndarray) -> np.ndarray:
    """Unit quaternion of a 3x3 rotation matrix (Shepperd's method, numerically stable).

    Parameters
    ----------
    matrix : ndarray, shape (3, 3)
        Rotation matrix.

    Returns
    -------
    ndarray, shape (4,)
        Unit quaternion (w, x, y, z).
    """
    m = np.asarray(matrix, dtype=float)
    trace = np.trace(m)
    candidates = np.array([trace, m[0, 0], m[1, 1], m[2, 2]])
    index = int(np.argmax(candidates))
    if index == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif index == 1:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif index == 2:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return quat_normalize(np.array(q))


def rotate(quaternion: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Rotate vectors by unit quaternion(s), broadcasting over leading axes.

    Parameters
    ----------
    quaternion : ndarray, shape (..., 4)
        Unit quaternion(s) (w, x, y, z).
    vectors : ndarray, shape (..., 3)
        Vectors to rotate.

    Returns
    -------
    ndarray, shape (..., 3)
        Rotated vectors.
    """
    return np.einsum("...ij,...j->...i", quat_to_matrix(quaternion), np.asarray(vectors, dtype=float))


def slerp(q0: np.ndarray, q1: np.ndarray, fraction: float | np.ndarray) -> np.ndarray:
    """Spherical linear interpolation from ``q0`` (fraction 0) to ``q1`` (fraction 1), shortest arc.

    Parameters
    ----------
    q0, q1 : ndarray, shape (..., 4)
        Unit quaternions (w, x, y, z) at the ends.
    fraction : float or ndarray, shape (...)
        Where between them, 0 .. 1.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion(s).
    """
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    fraction = np.asarray(fraction, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    safe = np.where(small, 1.0, sin_theta)
    w0 = np.where(small, 1.0 - fraction, np.sin((1.0 - fraction) * theta) / safe)
    w1 = np.where(small, fraction, np.sin(fraction * theta) / safe)
    return quat_normalize(w0 * q0 + w1 * q1)


def off_nadir_angle_rad(attitude: np.ndarray) -> np.ndarray:
    """Angle between the lander's -z axis (camera side) and world nadir.

    Parameters
    ----------
    attitude : ndarray, shape (..., 4)
        Lander-to-world unit quaternion(s) (w, x, y, z).

    Returns
    -------
    ndarray, shape (...)
        Off-nadir angle(s) (rad).
    """
    down_in_world = rotate(attitude, np.array([0.0, 0.0, -1.0]))
    return np.arccos(np.clip(-down_in_world[..., 2], -1.0, 1.0))
