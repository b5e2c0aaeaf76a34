"""Gennery's CAHVOR camera model: 3D -> 2D projection with radial distortion and its inverse.

A model is six 3-vectors (Gennery 2001; Yakimovsky & Cunningham's CAHV plus distortion):

C  camera centre (m), A  unit pointing axis, H and V  horizontal and vertical image-plane vectors
(pixels, they fold in focal length, pixel size and principal point: ``H = hs*H' + hc*A``),
O  unit optical axis (axis of radial distortion), R = (R0, R1, R2) radial distortion coefficients.

Projection of a point ``P``::

    p = P - C,  zeta = p.O,  lambda = p - zeta*O,  tau = |lambda|^2 / zeta^2
    mu = R0 + R1*tau + R2*tau^2,  p' = p + mu*lambda
    x = p'.H / p'.A   (column, pixel centres at integers, (0, 0) the first pixel's centre)
    y = p'.V / p'.A   (row)

The inverse (2D -> 3D ray) takes the CAHV ray ``(V - y A) x (H - x A)`` (the distorted direction)
and removes the distortion by Newton iteration on ``u' = u (1 + mu(u^2))``, where ``u`` and
``u'`` are the tangents of the angle to O before and after distortion (converges to < 1e-12 rad).
With negative R1 or R2 the distortion ``u -> u'`` stops increasing at a turning point ``u*``
(:func:`distortion_turning_point`); pixels beyond ``u'(u*)`` are seen by no ray, and
:func:`unproject` returns the ray at ``u*`` for them (the model's outermost ray, on the pixel's side).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cahvor:
    """A CAHVOR model; vectors are float arrays of shape (3,), lengths in m, H and V in pixels.

    Parameters
    ----------
    c : ndarray, shape (3,)
        Centre of projection (m).
    a : ndarray, shape (3,)
        Pointing axis, unit vector.
    h : ndarray, shape (3,)
        Horizontal vector (px): ``hs`` times the image x axis plus ``hc`` times A.
    v : ndarray, shape (3,)
        Vertical vector (px): ``vs`` times the image y axis plus ``vc`` times A.
    o : ndarray, shape (3,)
        Optical axis of the radial distortion, unit vector.
    r : ndarray, shape (3,)
        Radial distortion coefficients R0, R1, R2 (dimensionless).
    """

    c: np.ndarray
    a: np.ndarray
    h: np.ndarray
    v: np.ndarray
    o: np.ndarray
    r: np.ndarray

    @property
    def hc(self) -> float:
        """Column of the pointing axis (pixels)."""
        return float(self.h @ self.a)

    @property
    def vc(self) -> float:
        """Row of the pointing axis (pixels)."""
        return float(self.v @ self.a)

    @property
    def hs(self) -> float:
        """Horizontal focal length in pixels."""
        return float(np.linalg.norm(np.cross(self.a, self.h)))

    @property
    def vs(self) -> float:
        """Vertical focal length in pixels."""
        return float(np.linalg.norm(np.cross(self.a, self.v)))

    def transformed(self, rotation_matrix: np.ndarray, translation_m: np.ndarray) -> Cahvor:
        """The same camera expressed in another frame: ``X_new = R @ X_old + t``.

        Parameters
        ----------
        rotation_matrix : ndarray, shape (3, 3)
            Rotation R from the model's frame to the new frame.
        translation_m : ndarray, shape (3,)
            Translation t (m), in the new frame.

        Returns
        -------
        Cahvor
            The model in the new frame (R unchanged).
        """
        rotation_matrix = np.asarray(rotation_matrix, dtype=float)
        return Cahvor(
            c=rotation_matrix @ self.c + np.asarray(translation_m, dtype=float),
            a=rotation_matrix @ self.a,
            h=rotation_matrix @ self.h,
            v=rotation_matrix @ self.v,
            o=rotation_matrix @ self.o,
            r=self.r.copy(),
        )


def cahvor_from_intrinsics(focal_length_m: float, pixel_pitch_m: float, principal_point_px: tuple[float, float],
                           radial_distortion: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Cahvor:
    """A CAHVOR model in the camera frame (C at the origin, A = O = +z, H along +x, V along +y).

    Parameters
    ----------
    focal_length_m : float
        Focal length (m).
    pixel_pitch_m : float
        Pixel pitch (m).
    principal_point_px : tuple of float
        ``(column, row)`` of the principal point (px, pixel centres at integers).
    radial_distortion : tuple of float, optional
        R0, R1, R2 (dimensionless); default none.

    Returns
    -------
    Cahvor
        The model, focal lengths ``hs = vs = focal_length_m / pixel_pitch_m`` (px).
    """
    focal_px = focal_length_m / pixel_pitch_m
    axis = np.array([0.0, 0.0, 1.0])
    hc, vc = principal_point_px
    return Cahvor(
        c=np.zeros(3),
        a=axis,
        h=focal_px * np.array([1.0, 0.0, 0.0]) + hc * axis,
        v=focal_px * np.array([0.0, 1.0, 0.0]) + vc * axis,
        o=axis.copy(),
        r=np.asarray(radial_distortion, dtype=float),
    )


def project(model: Cahvor, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project 3D points into the image.

    Parameters
    ----------
    model : Cahvor
    points_m : ndarray, shape (..., 3)
        Points in the model's frame (m).

    Returns
    -------
    pixels : ndarray, shape (..., 2)
        ``(column, row)``; 0 for points that are not imaged.
    in_front : ndarray of bool, shape (...)
        True where the point is imaged: in front of the camera (``zeta > 0`` and ``p'.A > 0``) and
        inside the field the distortion model covers (undistorted tangent ``sqrt(tau)`` below the
        turning point :func:`distortion_turning_point`; beyond it the polynomial folds back and
        would put far off-axis points inside the frame).
    """
    relative = np.asarray(points_m, dtype=float) - model.c
    zeta = relative @ model.o
    lam = relative - zeta[..., None] * model.o
    turning = distortion_turning_point(model.r)
    with np.errstate(all="ignore"):   # points at or beside the centre give inf/NaN here; masked below
        tangent = lam / zeta[..., None]
        tau = np.einsum("...i,...i->...", tangent, tangent)
        imaged = (zeta > 0) & np.isfinite(tau) & (tau <= turning * turning)
    tau = np.where(imaged, tau, 0.0)
    mu = model.r[0] + model.r[1] * tau + model.r[2] * tau**2
    distorted = relative + mu[..., None] * lam
    alpha = distorted @ model.a
    in_front = imaged & (alpha > 0)
    safe_alpha = np.where(in_front, alpha, 1.0)
    with np.errstate(all="ignore"):
        pixels = np.stack([distorted @ model.h / safe_alpha, distorted @ model.v / safe_alpha], axis=-1)
    return np.where(in_front[..., None], pixels, 0.0), in_front


def unproject(model: Cahvor, pixels: np.ndarray, tolerance_rad: float = 1e-12,
              max_iterations: int = 50) -> np.ndarray:
    """Unit ray directions (model frame) through image points; rays start at ``model.c``.

    Parameters
    ----------
    model : Cahvor
        The camera model.
    pixels : ndarray, shape (..., 2)
        ``(column, row)`` image coordinates (px).
    tolerance_rad : float, optional
        Convergence tolerance of the distortion inversion (tangent of the field angle).
    max_iterations : int, optional
        Largest number of Newton steps of the distortion inversion.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit directions, pointing in front of the camera.
    """
    pixels = np.asarray(pixels, dtype=float)
    column = pixels[..., 0]
    row = pixels[..., 1]
    # (V - y A) x (H - x A) = V x H - x (V x A) - y (A x H)   (A x A = 0): three constant vectors, one
    # component at a time (no (..., 3) temporaries: a full frame is 10^6 rays)
    # (np.cross's products and differences in scalar arithmetic: the same bits without its per-call cost)
    base = _cross(model.v, model.h)
    per_column = [-value for value in _cross(model.v, model.a)]
    per_row = [-value for value in _cross(model.a, model.h)]
    ray = [base[k] + column * per_column[k] + row * per_row[k] for k in range(3)]
    # unit length, pointing in front of the camera (+A)
    sign = np.where(_dot(ray, model.a) < 0, -1.0, 1.0) / np.sqrt(_dot(ray, ray))
    ray = [component * sign for component in ray]
    if np.any(model.r):
        omega = _dot(ray, model.o)
        lam_distorted = [ray[k] - omega * model.o[k] for k in range(3)]
        u_distorted = np.sqrt(_dot(lam_distorted, lam_distorted)) / omega
        u = _undistort_tangent(u_distorted, model.r, tolerance_rad, max_iterations)
        scale = np.where(u_distorted > 0, u / np.where(u_distorted > 0, u_distorted, 1.0), 1.0)
        ray = [omega * model.o[k] + scale * lam_distorted[k] for k in range(3)]
        length = np.sqrt(_dot(ray, ray))
        ray = [component / length for component in ray]
    return np.stack(ray, axis=-1)


def _cross(first, second) -> tuple[float, float, float]:
    """:func:`numpy.cross` of two 3-vectors in scalar arithmetic: the same products and differences, same bits."""
    a0, a1, a2 = (float(value) for value in first)
    b0, b1, b2 = (float(value) for value in second)
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def _dot(components, vector) -> np.ndarray:
    """Dot product, component by component, of a vector field with ``vector``.

    The field is given as its three component arrays; ``vector`` has 3 components (a constant vector or
    another field).
    """
    return components[0] * vector[0] + components[1] * vector[1] + components[2] * vector[2]


def distortion_turning_point(r: np.ndarray) -> float:
    """Smallest undistorted tangent where the distorted tangent stops increasing.

    That is ``u* > 0`` where ``d/du [u (1 + R0 + R1 u^2 + R2 u^4)] = 0``. Memoised per R.

    Parameters
    ----------
    r : ndarray, shape (3,)
        Radial distortion coefficients R0, R1, R2.

    Returns
    -------
    float
        ``u*`` (tangent of the field angle); ``inf`` when the distortion increases for every ``u``
        (e.g. R1, R2 >= 0).
    """
    return _turning_point(*(float(value) for value in r))


@functools.lru_cache(maxsize=64)
def _turning_point(r0: float, r1: float, r2: float) -> float:
    # slope = (1 + R0) + 3 R1 s + 5 R2 s^2 with s = u^2
    roots = np.roots([5.0 * r2, 3.0 * r1, 1.0 + r0]) if (r1 or r2) else np.zeros(0)
    positive = [root.real for root in np.atleast_1d(roots) if abs(root.imag) < 1e-12 and root.real > 0]
    return float(np.sqrt(min(positive))) if positive else float("inf")


def _undistort_tangent(u_distorted: np.ndarray, r: np.ndarray, tolerance: float, max_iterations: int) -> np.ndarray:
    """Solve ``u (1 + R0 + R1 u^2 + R2 u^4) = u_distorted`` for u by Newton's method.

    Iterates stay in ``[0, u*]`` (:func:`distortion_turning_point`), where the map increases; a
    ``u_distorted`` beyond the largest distorted value returns ``u*``.
    """
    # Python floats for the coefficients and their constant products (left-to-right evaluation forms
    # 1 + R0, 3 R1 and 5 R2 first anyway): the same operations as numpy scalars, at less per-call cost
    r0, r1, r2 = (float(value) for value in r)
    one_plus_r0, three_r1, five_r2 = 1.0 + r0, 3.0 * r1, 5.0 * r2
    turning = distortion_turning_point(r)
    u = np.minimum(u_distorted / one_plus_r0, turning)
    if np.isfinite(turning):
        beyond = u_distorted >= turning * (one_plus_r0 + r1 * turning**2 + r2 * turning**4)
        u = np.where(beyond, turning, u)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(max_iterations):
            u2 = u * u
            residual = u * (one_plus_r0 + r1 * u2 + r2 * u2 * u2) - u_distorted
            slope = one_plus_r0 + three_r1 * u2 + five_r2 * u2 * u2
            positive = slope > 0
            step = np.where(positive, residual / np.where(positive, slope, 1.0), 0.0)
            updated = np.clip(u - step, 0.0, turning)
            change = np.abs(updated - u)
            u = updated
            if (change < tolerance).all():
                break
    return u


def field_angle_rad(model: Cahvor, pixels: np.ndarray) -> np.ndarray:
    """Angle between the (undistorted) ray through each image point and the optical axis O.

    Parameters
    ----------
    model : Cahvor
        The camera model.
    pixels : ndarray, shape (..., 2)
        ``(column, row)`` image coordinates (px).

    Returns
    -------
    ndarray, shape (...)
        Field angle (rad).
    """
    rays = unproject(model, pixels)
    return np.arccos(np.clip(rays @ model.o, -1.0, 1.0))


def pixel_grid(width: int, height: int) -> np.ndarray:
    """Pixel-centre coordinates ``(column, row)`` of a width x height frame.

    Parameters
    ----------
    width, height : int
        Columns and rows of the frame (px).

    Returns
    -------
    ndarray, shape (height, width, 2)
        ``(column, row)`` of every pixel centre (px), float64.
    """
    columns, rows = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    return np.stack([columns, rows], axis=-1)


def field_of_view_deg(model: Cahvor, width: int, height: int) -> tuple[float, float]:
    """Full horizontal and vertical field of view between the outer pixel edges.

    Parameters
    ----------
    model : Cahvor
        The camera model.
    width, height : int
        Columns and rows of the frame (px).

    Returns
    -------
    tuple of float
        Horizontal and vertical field of view (deg), through the principal point.
    """
    half_w, half_h = width / 2.0, height / 2.0
    centre = np.array([model.hc, model.vc])
    edges = np.array([[centre[0] - half_w, centre[1]], [centre[0] + half_w, centre[1]],
                      [centre[0], centre[1] - half_h], [centre[0], centre[1] + half_h]])
    rays = unproject(model, edges)
    horizontal = np.degrees(np.arccos(np.clip(rays[0] @ rays[1], -1, 1)))
    vertical = np.degrees(np.arccos(np.clip(rays[2] @ rays[3], -1, 1)))
    return float(horizontal), float(vertical)
