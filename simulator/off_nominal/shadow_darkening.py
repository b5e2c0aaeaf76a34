"""The moving shadows' compiled pass: every shadow's covered fraction at every pixel of its window, and the darkening.

:meth:`simulator.off_nominal.moving_shadows.MovingShadows.darken` chooses the windows and calls
:func:`darken_windows`. Kept apart from :mod:`simulator.off_nominal.moving_shadows` so that declaring
``[scene.off_nominal]`` (which imports that module's configuration) loads no numba: ``darken`` imports this module
when it first darkens a field.

Float32 throughout, one operation at a time in this order (no fused multiply-add), as numpy evaluates
the same formulas on float32 arrays (``tests/simulator/off_nominal/test_moving_shadows.py`` holds the two bit for
bit).
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: Columns of the ``shadows`` table :func:`darken_windows` reads, one row per shadow (float32).
SHADOW_COLUMNS = ("east_offset", "north_offset", "anti_sun_east", "anti_sun_north", "length", "slope", "intercept",
                  "direct_change")


def shadow_table(start_m: np.ndarray, grid_origin_m, anti_sun: np.ndarray, length_m: np.ndarray,
                 radius_m: np.ndarray, edge_m: np.ndarray, core_factor: np.ndarray) -> np.ndarray:
    """The per-shadow float32 constants of :func:`darken_windows` (columns :data:`SHADOW_COLUMNS`).

    Parameters
    ----------
    start_m : ndarray, shape (n, 2)
        East, north of each shadow's axis start at the time (m).
    grid_origin_m : (float, float)
        East, north of the ground grid's (row 0, col 0) pixel centre (m).
    anti_sun : ndarray, shape (2,)
        Horizontal unit vector away from the sun.
    length_m, radius_m, edge_m : ndarray, shape (n,)
        Axis length, half width and edge width of each shadow (m).
    core_factor : ndarray, shape (n,)
        Direct-beam transmission in each core.

    Returns
    -------
    ndarray, shape (n, 8), float32
        Per shadow: ``origin - start`` east and north (m), the anti-sun vector, the axis length (m), the edge
        ramp's slope ``-1 / w`` (1/m) and intercept ``0.5 + r / w``, and ``-(1 - core_factor)``.
    """
    table = np.empty((len(start_m), len(SHADOW_COLUMNS)), dtype=np.float32)
    for index in range(len(start_m)):
        table[index] = (grid_origin_m[0] - start_m[index][0], grid_origin_m[1] - start_m[index][1], anti_sun[0],
                        anti_sun[1], length_m[index], -1.0 / edge_m[index], 0.5 + radius_m[index] / edge_m[index],
                        -(1.0 - core_factor[index]))
    return table


@njit(cache=True, nogil=True, boundscheck=False)
def darken_windows(radiance, col_map, row_map, sky, any_sky, metres_per_pixel, shadows, windows, diffuse_fraction):
    """Multiply ``radiance`` in place by ``f + (1 - f) D``, ``D`` the product of the shadows' direct-beam factors.

    Shadow ``k`` (row ``k`` of ``shadows``) covers the pixels of its window ``windows[k]`` (row0, row1, col0,
    col1; end exclusive) by the fraction ``c = clip(0.5 + r / w - d / w, 0, 1)``, ``d`` the ground distance from
    the pixel's ground point to the shadow's axis segment (a disc's centre when the length is 0), 0 on sky
    pixels; its factor on the direct beam is ``1 + c (T - 1)`` (``T`` the core's transmission). A pixel's ``D``
    multiplies its shadows' factors in their order, from 1. Every pixel of the windows' bounding box is
    multiplied (by ``f + (1 - f)``, rounded, where no shadow's window holds it); pixels outside it are left as they
    are.

    Parameters
    ----------
    radiance : ndarray, shape (H, W), float32
        Radiance (W m^-2 sr^-1 um^-1), changed in place.
    col_map, row_map : ndarray, shape (H, W), float32
        Ground grid coordinates of every pixel (east = origin + col x mpp, north = origin - row x mpp).
    sky : ndarray, shape (H, W), bool
        Sky pixels (read only with ``any_sky``).
    any_sky : bool
        Whether any pixel sees the sky.
    metres_per_pixel : float32
        Ground grid spacing (m).
    shadows : ndarray, shape (n, 8), float32
        :func:`shadow_table`.
    windows : ndarray, shape (n, 4), int64
        Each shadow's window (non-empty).
    diffuse_fraction : float32
        Fraction ``f`` of the irradiance that is sky light.
    """
    count = windows.shape[0]
    top, bottom = windows[0, 0], windows[0, 1]
    left, right = windows[0, 2], windows[0, 3]
    for index in range(1, count):
        top, bottom = min(top, windows[index, 0]), max(bottom, windows[index, 1])
        left, right = min(left, windows[index, 2]), max(right, windows[index, 3])
    direct = np.empty(right - left, dtype=np.float32)
    lit = np.float32(1.0) - diffuse_fraction
    one = np.float32(1.0)
    for row in range(top, bottom):
        for col in range(left, right):
            direct[col - left] = one
        for index in range(count):
            row0, row1, col0, col1 = windows[index, 0], windows[index, 1], windows[index, 2], windows[index, 3]
            if row < row0 or row >= row1:
                continue
            _multiply_shadow_row(direct[col0 - left:col1 - left], col_map[row, col0:col1], row_map[row, col0:col1],
                                 sky[row, col0:col1], any_sky, metres_per_pixel, shadows[index])
        values = radiance[row]
        for col in range(left, right):
            values[col] *= diffuse_fraction + lit * direct[col - left]


@njit(cache=True, nogil=True, boundscheck=False, inline="always")
def _multiply_shadow_row(direct, cols, rows, sky, any_sky, metres_per_pixel, shadow):
    """Multiply one window row of ``direct`` by one shadow's factor (:func:`darken_windows`)."""
    east_offset, north_offset, anti_east, anti_north = shadow[0], shadow[1], shadow[2], shadow[3]
    length, slope, intercept, change = shadow[4], shadow[5], shadow[6], shadow[7]
    zero, one = np.float32(0.0), np.float32(1.0)
    segment = length > zero
    for index in range(direct.shape[0]):
        east = cols[index] * metres_per_pixel + east_offset
        north = north_offset - rows[index] * metres_per_pixel
        if segment:         # distance to the segment: remove the clipped along-axis part
            along = min(max(east * anti_east + north * anti_north, zero), length)
            east -= along * anti_east
            north -= along * anti_north
        covered = np.sqrt(east * east + north * north) * slope + intercept
        covered = min(max(covered, zero), one)
        if any_sky and sky[index]:
            covered = zero
        direct[index] *= covered * change + one
