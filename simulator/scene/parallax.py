"""Relief at near-nominal cost: fixed-point parallax iterations and shading baked on the terrain grid.

The ``parallax`` method of ``[scene.relief]`` (the default; :mod:`simulator.scene.relief` keeps the ray
march, ``method = "march"``, as the reference). Per pose:

**Parallax.** A pixel whose ray meets the level ground z = 0 at grid point ``P0`` (the level map the
scene already has) meets height z at ``P(z) = P0 + (z / O_z) (O - P0)`` (horizontal grid coordinates,
``O`` the ray origin): a straight line through the origin, whatever the lens. The visible height solves
``f(z) = z - H(P(z)) = 0``. Along the ray ``f'(z) = 1 - q`` with ``q`` the slope of the terrain along the
ray's horizontal direction times ``tan(view angle)``; where the terrain's slope bound over the ray's
whole segment between the window's height extremes keeps ``|q| < UNIQUE_SLOPE_BOUND`` (0.9, a dilated map
of the bilinear surface's per-cell gradient bound), ``f`` is increasing, the ray crosses the surface once
(no occlusion is possible) and the secant iteration from the fixed-point start ``z1 = H(P0)`` converges
(at 1.5-2 km over the Gusev classes ``|q|`` is mostly 0.01-0.05: one secant step leaves 0.01-0.8 % of the
rays off 1 mm). One secant step runs on a half-resolution pixel grid (block means of the level map), its
heights are upsampled, then every pixel takes one fixed-point step ``z <- H(P(z))`` at full resolution
(contracting the upsampling error by ``q``) and is checked: where ``|z - H(P(z))| > height_tolerance_m``
(0.1-0.9 % of the pixels on the bench's poses) the pixel iterates on its own. Rays where the
bound does not hold (steep knobs, mesa walls: where a nearer bump may hide the crossing) and the few
that do not converge in ``MAX_PIXEL_ITERATIONS`` take the reference ray march
(:func:`simulator.scene.relief.march_heights`): occlusion stays exact.

**The rendered point is on the surface.** Heights are read with OpenCV's bilinear remap (OpenCV 5 interpolates
at the float coordinate; 4.x snapped it to 1/32 px); the reflectance is read with the same maps, so each pixel
shows the surface point ``(P_q, H(P_q))`` of its ray as read (``q``) at height z, exactly on the bilinear surface and within
``height_tolerance_m`` (vertically) of the pixel's ray: an image displacement of
``tolerance x tan(view angle) / ground pixel`` (3e-4 px at 1 mm and 1.5 m pixels).

**Shading, baked on the grid.** Per pose, on the terrain window, every grid node gets four values,
read at the hit point with one 4-channel bilinear remap: ``H``; ``H - S`` (``S`` the sun-ray horizon
height of :func:`simulator.scene.relief.horizon_height`, built once per terrain and sun and cached);
``(1 - d) LS(n, v) / LS(flat, v)`` and ``d (1 + n_z) / 2``, with ``n`` the node's normal from central
differences and ``v`` the unit vector from the node to the camera. The radiance factor is
``d (1 + n_z)/2 + (1 - d) LS(n)/LS(flat) lit``, ``lit = clip((H - S) / shadow_edge_m + 1/2, 0, 1)``:
the reference's formula, with the normal of the node grid interpolated across a cell instead of the
bilinear surface's own within-cell gradient; where the two can differ by more than
``NORMAL_DEVIATION_LIMIT`` (a per-cell bound, flagged in the sky term's channel) the pixel is shaded at its
own normal as the reference does (measured difference: docs/simulator.md, "Terrain relief"). The
pose-independent values are cached per terrain and sun (:func:`static_nodes`); per pose only the view term
is computed on the window (:func:`shading_nodes`).

**Compiled passes.** The elementwise work is fused into numba passes (``cache=True``; ~1.5 s of CPU to
compile once per machine): the level map in window coordinates, the coarse secant step with its next ray
points, the ray points (the rays' slopes formed on the way, never stored), the hit points with their grid
coordinates, the view term (the half-precision normals' bits read through a table of their exact values),
and one pass for the off-tolerance pixels and the radiance factor; OpenCV's remap keeps the bilinear reads
(a scalar compiled read measured 2x slower here: 3.3 against 1.7 ms for 1 Mpx, OpenCV 5.0's bits reproduced;
the check holds whatever the remap read to the tolerance).
They compute the same float32 operations as the numpy passes they replace: the same bits.
The per-pose floor is the reads: two full-resolution remaps (the fixed-point step and the 4-channel check
and shading read) and two half-resolution ones; the rest is memory-bound passes over 1 Mpx frames.
"""
from __future__ import annotations

import dataclasses
import threading
import weakref
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from simulator.derived_cache import DERIVED
from simulator.scene import ground_mapping, height_field, photometry
from simulator.scene.resample import Crop
from simulator.scene.terrain import Terrain

UNIQUE_SLOPE_BOUND = 0.9       # |q| below this over the whole ray segment: one crossing, secant converges
COARSE_SECANT_STEPS = 1          # half-resolution secant steps before the full-resolution step and check
MAX_PIXEL_ITERATIONS = 8
SECANT_SLOPE_RANGE = (0.1, 2.0)   # f' = 1 - q lies in (0.1, 1.9) where the bound holds
REMAP_ROW = 1024                 # a flat list of points is remapped as rows of this many (OpenCV maps < 32767)
NEVER_SHADOWED = 1.0e6           # H - S where cast shadows are off: lit everywhere
STATIC_TERRAINS_KEPT = 2         # terrains whose static node values stay cached (~100 MB each)
ROUGH_OFFSET = 1.0e4              # added to a rough node's sky term: any bilinear weight above 1e-7 shows
ROUGH_MARGIN = 1.0e-3             # a read above d + this (the sky term d (1 + n_z)/2 <= d) is rough
NORMAL_DEVIATION_LIMIT = 0.2     # node-gradient error (m/m) above which a pixel is shaded at its own normal


_work_pool = threading.local()


def _work_array(name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """A reusable array of this thread for one of a pose's full-frame intermediates (no page faults per pose)."""
    arrays = getattr(_work_pool, "arrays", None)
    if arrays is None:
        arrays = _work_pool.arrays = {}
    key = (name, shape, np.dtype(dtype).str)
    if key not in arrays:
        arrays[key] = np.empty(shape, dtype=dtype)
    return arrays[key]


def remap_points(source: np.ndarray, col: np.ndarray, row: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear remap of a grid (1 or 4 channels) at any shape of points, edges replicated.

    Parameters
    ----------
    source : ndarray, shape (rows, cols) or (rows, cols, channels), float32
        The grid.
    col, row : ndarray, float32, equal shapes
        Fractional grid coordinates.
    out : ndarray, optional
        Array for the result (2-D points only).

    Returns
    -------
    ndarray, float32, shape ``col.shape`` (+ channels)
        The values (OpenCV's bilinear interpolation: at the float coordinates in OpenCV 5, snapped to 1/32 px
        in 4.x).
    """
    if col.ndim == 2:
        return cv2.remap(source, col, row, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_REPLICATE)
    count = col.size
    rows = max(-(-count // REMAP_ROW), 1)
    padded = rows * REMAP_ROW

    def as_rows(values):
        out = np.zeros(padded, dtype=np.float32)
        out[:count] = values
        return out.reshape(rows, REMAP_ROW)
    result = cv2.remap(source, as_rows(col), as_rows(row), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    channels = source.shape[2:] if source.ndim == 3 else ()
    return result.reshape((padded,) + channels)[:count]


def slope_bound(heights: np.ndarray, metres_per_pixel: float) -> np.ndarray:
    """Per grid node, an upper bound of the bilinear surface's gradient magnitude in the cell it opens.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols), float32
        Heights (m).
    metres_per_pixel : float
        Grid spacing (m).

    Returns
    -------
    ndarray, shape (rows, cols), float32
        ``sqrt(max|dH/dcol|^2 + max|dH/drow|^2) / mpp`` over the cell's edges (m per m); the last row and
        column repeat their neighbours.
    """
    along_cols = np.abs(np.diff(heights, axis=1))                  # (rows, cols - 1)
    along_rows = np.abs(np.diff(heights, axis=0))                  # (rows - 1, cols)
    cell_cols = np.maximum(along_cols[:-1], along_cols[1:])        # (rows - 1, cols - 1)
    cell_rows = np.maximum(along_rows[:, :-1], along_rows[:, 1:])
    bound = np.sqrt(cell_cols * cell_cols + cell_rows * cell_rows) * np.float32(1.0 / metres_per_pixel)
    return np.pad(bound, ((0, 1), (0, 1)), mode="edge") if bound.size else np.zeros_like(heights)


def terrain_slope_bound(terrain: Terrain) -> np.ndarray:
    """:func:`slope_bound` of a relief terrain's heights, cached per terrain.

    Parameters
    ----------
    terrain : Terrain
        A terrain with ``height_m``.

    Returns
    -------
    ndarray, shape (rows, cols), float16
        The bound (m per m), raised by 2^-9 before rounding to half precision (half the memory of float32).
    """
    cache = DERIVED.of(terrain, "relief")
    if "slope_bound" not in cache:
        heights = np.asarray(terrain.height_m, dtype=np.float32)  # type: ignore[attr-defined]
        bound = slope_bound(heights, terrain.metres_per_pixel) * np.float32(1.0 + 2.0 ** -9)
        cache["slope_bound"] = bound.astype(np.float16)       # rounded up by the margin: still a bound
    return cache["slope_bound"]


def normal_deviation(heights: np.ndarray) -> np.ndarray:
    """Per node, a bound of |bilinear-surface gradient - interpolated node gradient| in the cells it touches.

    Within a cell the bilinear surface's ``dH/dcol`` runs between the cell's two column differences, and the
    interpolated node gradient (central differences) between its four corners' values: their difference is
    at most the larger of ``max(edges) - min(corners)`` and ``max(corners) - min(edges)`` (likewise for
    rows). A node takes the largest bound of the cells it is a corner of.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols), rows and cols >= 3
        Heights (m).

    Returns
    -------
    ndarray, shape (rows, cols), float32
        The bound (m per grid px).
    """
    heights = np.asarray(heights, dtype=np.float32)
    d_row, d_col = np.gradient(heights)

    def cell_bound(edge_a, edge_b, node_values):
        corner_max = np.maximum(np.maximum(node_values[:-1, :-1], node_values[:-1, 1:]),
                                np.maximum(node_values[1:, :-1], node_values[1:, 1:]))
        corner_min = np.minimum(np.minimum(node_values[:-1, :-1], node_values[:-1, 1:]),
                                np.minimum(node_values[1:, :-1], node_values[1:, 1:]))
        corner_max -= np.minimum(edge_a, edge_b)
        np.subtract(np.maximum(edge_a, edge_b), corner_min, out=corner_min)
        return np.maximum(corner_max, corner_min, out=corner_max)

    along_cols = np.diff(heights, axis=1)            # (rows, cols - 1)
    along_rows = np.diff(heights, axis=0)            # (rows - 1, cols)
    cell = np.maximum(cell_bound(along_cols[:-1], along_cols[1:], d_col),
                      cell_bound(along_rows[:, :-1], along_rows[:, 1:], d_row))
    padded = np.pad(cell, 1, mode="edge")
    return np.maximum(np.maximum(padded[:-1, :-1], padded[:-1, 1:]), np.maximum(padded[1:, :-1], padded[1:, 1:]))


def rough_nodes(terrain: Terrain, heights_m: np.ndarray) -> np.ndarray:
    """Nodes of a cell whose interpolated node normal is off by more than ``NORMAL_DEVIATION_LIMIT``.

    The nearest node of any point in such a cell is flagged (folded into :func:`static_nodes`).

    Parameters
    ----------
    terrain : Terrain
        The terrain (cache owner).
    heights_m : ndarray, shape (rows, cols)
        Its heights (m).

    Returns
    -------
    ndarray, shape (rows, cols), uint8
        1 where the node's :func:`normal_deviation` / mpp exceeds the limit.
    """
    if min(heights_m.shape) < 3:
        return np.ones(heights_m.shape, dtype=np.uint8)
    limit = np.float32(NORMAL_DEVIATION_LIMIT * terrain.metres_per_pixel)
    return (normal_deviation(heights_m) > limit).view(np.uint8)


def static_nodes(terrain: Terrain, sun: np.ndarray, config) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pose-independent node values of a relief terrain under a sun, cached per terrain and sun.

    Parameters
    ----------
    terrain : Terrain
        A terrain with ``height_m`` (:class:`simulator.scene.relief.ReliefTerrain`).
    sun : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table and ``shadow_diffuse_fraction``.

    Returns
    -------
    pack : ndarray, shape (rows, cols, 4), float32
        ``H``, ``H - S`` (``NEVER_SHADOWED`` without cast shadows), ``d (1 + n_z)/2`` (+ ``ROUGH_OFFSET`` at
        the nodes of cells whose interpolated normal is off, :func:`rough_nodes`) and ``max(n.s, 0)``, with the
        normal ``n = (normal_east, normal_north, 1)`` unnormalised (central differences).
    normal_east, normal_north : ndarray, shape (rows, cols), float16
        The normal's horizontal components (m per m; rows run south), in half precision (5e-4 relative).

    Notes
    -----
    ~100 MB per 1000 x 5000 strip: the values of the ``STATIC_TERRAINS_KEPT`` terrains used last are kept.
    """
    relief_config = config.relief
    diffuse = np.float32(config.shadow_diffuse_fraction)
    sun = np.asarray(sun, dtype=float)
    cache = DERIVED.of(terrain, "relief")
    key = ("static_nodes", tuple(np.round(sun, 12)), float(relief_config.march_step_terrain_px),
           relief_config.cast_shadows, relief_config.slope_photometry, float(diffuse), NORMAL_DEVIATION_LIMIT)
    if key in cache:
        return cache[key]
    heights = np.asarray(terrain.height_m, dtype=np.float32)  # type: ignore[attr-defined]
    rows, cols = heights.shape
    pack = np.empty((rows, cols, 4), dtype=np.float32)
    pack[..., 0] = heights
    if relief_config.cast_shadows:
        horizon = height_field.horizon_height(terrain, sun,  # type: ignore[arg-type]  # a ReliefTerrain
                                        relief_config.march_step_terrain_px, cached=False)
        pack[..., 1] = heights - horizon
    else:
        pack[..., 1] = np.float32(NEVER_SHADOWED)
    if relief_config.slope_photometry and min(rows, cols) >= 2:
        d_row, d_col = np.gradient(heights)
        inverse_mpp = np.float32(1.0 / terrain.metres_per_pixel)
        normal_east = d_col * -inverse_mpp
        normal_north = d_row * inverse_mpp              # rows run south
    else:
        normal_east = normal_north = np.zeros_like(heights)
    sun_x, sun_y, sun_z = (np.float32(value) for value in sun)
    sky_view = np.float32(1.0) / np.sqrt(np.float32(1.0) + normal_east * normal_east + normal_north * normal_north)
    sky_view += np.float32(1.0)
    sky_view *= np.float32(0.5) * diffuse
    if relief_config.slope_photometry:
        sky_view += rough_nodes(terrain, heights) * np.float32(ROUGH_OFFSET)
    pack[..., 2] = sky_view
    pack[..., 3] = np.maximum(normal_east * sun_x + normal_north * sun_y + sun_z, np.float32(0.0))
    _keep_static_nodes_of(terrain)
    cache[key] = (pack, normal_east.astype(np.float16), normal_north.astype(np.float16))
    return cache[key]


_static_owners: list = []      # weak references to the terrains holding static node values, oldest first


def _keep_static_nodes_of(terrain: Terrain) -> None:
    """Drop the static node values of all but the ``STATIC_TERRAINS_KEPT - 1`` most recent other terrains."""
    alive = [ref for ref in _static_owners if ref() is not None and ref() is not terrain]
    while len(alive) >= STATIC_TERRAINS_KEPT:
        oldest = alive.pop(0)()
        if oldest is not None:
            cache = DERIVED.of(oldest, "relief")
            for key in [key for key in cache if isinstance(key, tuple) and key[:1] == ("static_nodes",)]:
                del cache[key]
    _static_owners[:] = alive + [weakref.ref(terrain)]


def shading_nodes(terrain: Terrain, crop: Crop, origin_m: np.ndarray, sun: np.ndarray, config) -> np.ndarray:
    """The four values every pixel reads at its hit point (module doc), on a terrain window.

    Parameters
    ----------
    terrain : Terrain
        The relief terrain.
    crop : Crop
        The window.
    origin_m : ndarray, shape (3,)
        The rays' origin (m).
    sun : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table and ``shadow_diffuse_fraction``.

    Returns
    -------
    ndarray, shape (rows, cols, 4), float32
        ``H``, ``H - S``, ``d (1 + n_z) / 2`` (+ ``ROUGH_OFFSET``: :func:`static_nodes`) and
        ``(1 - d) LS(n, v) / LS(flat, v)`` with ``v`` the unit vector from the node to the camera.
    """
    pack, normal_east, normal_north = static_nodes(terrain, sun, config)
    window = (slice(crop.row0, crop.row1), slice(crop.col0, crop.col1))
    rows, cols = crop.row1 - crop.row0, crop.col1 - crop.col0
    mpp = terrain.metres_per_pixel
    east = terrain.origin_m[0] + (crop.col0 + np.arange(cols)) * mpp
    north = terrain.origin_m[1] - (crop.row0 + np.arange(rows)) * mpp
    nodes = np.empty((rows, cols, 4), dtype=np.float32)
    _view_term_kernel(pack[window], normal_east[window].view(np.uint16), normal_north[window].view(np.uint16),
                      (origin_m[0] - east).astype(np.float32), (origin_m[1] - north).astype(np.float32),
                      np.float32(origin_m[2]), max(np.float32(sun[2]), np.float32(1e-12)),
                      np.float32(1.0) - np.float32(config.shadow_diffuse_fraction), _half_table(), nodes)
    return nodes


#: 2^(e - 25) for the 32 exponent fields e of IEEE half precision (2^-24 for e = 0: subnormal)
HALF_SCALES = np.array([2.0 ** -24] + [2.0 ** (exponent - 25) for exponent in range(1, 32)], dtype=np.float32)


@njit(cache=True, nogil=True, boundscheck=False, inline="always")
def _half_to_float32(bits, scales):
    """The value of IEEE half-precision bits, exactly.

    Numba reads no float16 arrays; the normals hold no inf or nan. ``scales``: :data:`HALF_SCALES`.
    """
    exponent = (bits >> 10) & 0x1F
    significand = np.float32(bits & 0x3FF)
    if exponent != 0:
        significand += np.float32(1024.0)
    value = significand * scales[exponent]
    return -value if bits & 0x8000 else value


_half_tables: list[np.ndarray] = []


def _half_table() -> np.ndarray:
    """The float32 value of every IEEE half-precision bit pattern (:func:`_half_to_float32`), built once.

    Returns
    -------
    ndarray, shape (65536,), float32
        Indexed by the bits (256 KiB: a table read instead of a decode with branches per normal).
    """
    if not _half_tables:
        table = np.empty(65536, dtype=np.float32)
        _decode_all_halves(np.arange(65536, dtype=np.uint16), HALF_SCALES, table)
        _half_tables.append(table)
    return _half_tables[0]


@njit(cache=True, nogil=True, boundscheck=False)
def _decode_all_halves(bits, scales, out):
    """:func:`_half_to_float32` of each of ``bits``."""
    for index in range(bits.size):
        out[index] = _half_to_float32(bits[index], scales)


@njit(cache=True, nogil=True, boundscheck=False)
def _view_term_kernel(pack, normal_east, normal_north, to_camera_east, to_camera_north, origin_up, sun_z,
                      direct_fraction, half_table, nodes):
    """:func:`shading_nodes` in one pass over the window.

    The half-precision normals' bits are looked up in ``half_table`` (:func:`_half_table`). Channels 0-2 are
    copied from the static values, channel 3 is
    ``(1 - d) LS(n, v) / LS(flat, v) = (1 - d) A (s_z D + v_z) / (s_z (A D + B))`` with ``A = n.s`` (channel 3
    of the static values), ``B = max(n.(O - X), 0)`` and ``D = |O - X|`` (the normal's length cancels).
    """
    rows, cols = normal_east.shape
    for row in range(rows):
        north = to_camera_north[row]
        for col in range(cols):
            east = to_camera_east[col]
            slope_east = half_table[normal_east[row, col]]
            slope_north = half_table[normal_north[row, col]]
            height = pack[row, col, 0]
            up = origin_up - height
            distance = np.sqrt(up * up + (east * east + north * north))
            sun_term = pack[row, col, 3]
            view_term = max(slope_east * east + slope_north * north + up, np.float32(0.0))
            denominator = max((sun_term * distance + view_term) * sun_z, np.float32(1e-30))
            nodes[row, col, 0] = height
            nodes[row, col, 1] = pack[row, col, 1]
            nodes[row, col, 2] = pack[row, col, 2]
            nodes[row, col, 3] = (distance * sun_z + up) * sun_term * direct_fraction / denominator


def _secant(z, f, z_previous, f_previous, z_bottom, z_top):
    """One safeguarded secant step of f(z) = z - H(P(z)) (slope clipped to SECANT_SLOPE_RANGE)."""
    dz = z - z_previous
    safe = np.abs(dz) > np.float32(1e-6)
    slope = np.where(safe, (f - f_previous) / np.where(safe, dz, np.float32(1.0)), np.float32(1.0))
    np.clip(slope, np.float32(SECANT_SLOPE_RANGE[0]), np.float32(SECANT_SLOPE_RANGE[1]), out=slope)
    return np.clip(z - f / slope, np.float32(z_bottom), np.float32(z_top))


class RayFamily:
    """Pixel rays through one origin as lines on the terrain window: ``P(z) = P0 + z k (O - P0)``.

    Parameters
    ----------
    col0, row0 : ndarray, float32
        Level-ground (z = 0) window coordinates of each ray (any shape).
    origin_col, origin_row : float
        Window coordinates of the origin's nadir point.
    altitude_m : float
        Origin height above z = 0 (m).
    out : (ndarray, ndarray), optional
        Arrays for the grid px per metre of z along columns and rows.
    """

    def __init__(self, col0: np.ndarray, row0: np.ndarray, origin_col: float, origin_row: float, altitude_m: float,
                 out=(None, None)):
        self.col0, self.row0 = col0, row0
        scale = np.float32(1.0 / altitude_m)
        self.col_per_m = np.subtract(np.float32(origin_col), col0, out=out[0])
        self.col_per_m *= scale
        self.row_per_m = np.subtract(np.float32(origin_row), row0, out=out[1])
        self.row_per_m *= scale

    def at(self, z: np.ndarray | np.floating | float, index=None, out=(None, None)) -> tuple[np.ndarray, np.ndarray]:
        """Window coordinates of the rays (or of some of them) at heights z.

        Parameters
        ----------
        z : ndarray or float
            Heights (m), one per ray asked (or one for all).
        index : ndarray of int, optional
            The rays asked (flat families); None: all.
        out : (ndarray, ndarray), optional
            Arrays for the result when all rays are asked.

        Returns
        -------
        col, row : ndarray, float32
            Window coordinates.
        """
        if index is None:
            if isinstance(z, np.ndarray) and z.shape == self.col0.shape and z.dtype == np.float32 and all(
                    part.flags.c_contiguous for part in (z, self.col0, self.row0, self.col_per_m, self.row_per_m)):
                col = np.empty_like(z) if out[0] is None else out[0]
                row = np.empty_like(z) if out[1] is None else out[1]
                _family_points_kernel(z.reshape(-1), self.col0.reshape(-1), self.row0.reshape(-1),
                                      self.col_per_m.reshape(-1), self.row_per_m.reshape(-1), col.reshape(-1),
                                      row.reshape(-1))
                return col, row
            col = np.multiply(z, self.col_per_m, out=out[0])
            col += self.col0
            row = np.multiply(z, self.row_per_m, out=out[1])
            row += self.row0
            return col, row
        return self.col0[index] + z * self.col_per_m[index], self.row0[index] + z * self.row_per_m[index]


@njit(cache=True, nogil=True, boundscheck=False)
def _family_points_kernel(z, col0, row0, col_per_m, row_per_m, col, row):
    """:meth:`RayFamily.at` of every ray in one pass (float32 products and sums, as numpy rounds them)."""
    for ray in range(z.shape[0]):
        col[ray] = z[ray] * col_per_m[ray] + col0[ray]
        row[ray] = z[ray] * row_per_m[ray] + row0[ray]


@njit(cache=True, nogil=True, boundscheck=False)
def _ray_points_kernel(z, col0, row0, origin_col, origin_row, inverse_altitude, col, row):
    """Window coordinates of rays at heights z, their slopes formed from the origin on the way.

    ``(origin - col0) / altitude`` rounded to float32, times z, plus ``col0``: the float32 operations of
    :class:`RayFamily` and :meth:`RayFamily.at` (the same bits), without the slopes in memory.
    """
    for ray in range(z.shape[0]):
        col_per_m = (origin_col - col0[ray]) * inverse_altitude
        row_per_m = (origin_row - row0[ray]) * inverse_altitude
        col[ray] = z[ray] * col_per_m + col0[ray]
        row[ray] = z[ray] * row_per_m + row0[ray]


@njit(cache=True, nogil=True, boundscheck=False)
def _hit_points_kernel(z, col0, row0, origin_col, origin_row, inverse_altitude, window_col0, window_row0, col, row,
                       grid_col, grid_row):
    """:func:`_ray_points_kernel`, and the points' terrain grid coordinates ``col + window_col0`` (likewise rows)."""
    for ray in range(z.shape[0]):
        col_per_m = (origin_col - col0[ray]) * inverse_altitude
        row_per_m = (origin_row - row0[ray]) * inverse_altitude
        point_col = z[ray] * col_per_m + col0[ray]
        point_row = z[ray] * row_per_m + row0[ray]
        col[ray], row[ray] = point_col, point_row
        grid_col[ray], grid_row[ray] = point_col + window_col0, point_row + window_row0


@njit(cache=True, nogil=True, boundscheck=False)
def _level_lines_kernel(level_col, level_row, sky, any_sky, window_col0, window_row0, col0, row0):
    """The level map in window coordinates (0 at sky pixels), in one pass."""
    for pixel in range(level_col.shape[0]):
        if any_sky and sky[pixel]:
            col0[pixel], row0[pixel] = np.float32(0.0), np.float32(0.0)
        else:
            col0[pixel], row0[pixel] = level_col[pixel] - window_col0, level_row[pixel] - window_row0


@njit(cache=True, nogil=True, boundscheck=False)
def _hits_kernel(z, values, steep, any_steep, sky, any_sky, tolerance, shade, band, rough_above, sky_coordinate,
                 factor, grid_col, grid_row, redo, residual, rough_index, rough_lit):
    """The check of the heights and the radiance factor of flat pixels, in one pass.

    ``values``: (pixels, channels), the values read at the hits (the heights in channel 0; with ``shade``
    the four of :func:`shading_nodes`). Writes the indices and residuals ``z - H`` of the pixels with
    ``|z - H| > tolerance`` (neither steep nor sky), with ``shade`` the factor
    ``lit values[3] + values[2]`` (``lit = clip(values[1] band + 1/2, 0, 1)``; 1 for sky) and the indices and
    direct-sun fractions of the pixels whose sky term exceeds ``rough_above`` (a rough node in their read),
    and ``sky_coordinate`` as the grid coordinates of sky pixels. Returns the counts of pixels off the
    tolerance and of rough pixels.
    """
    redo_count = 0
    rough_count = 0
    for pixel in range(z.shape[0]):
        if any_sky and sky[pixel]:
            if shade:
                factor[pixel] = np.float32(1.0)
            grid_col[pixel] = sky_coordinate
            grid_row[pixel] = sky_coordinate
            continue
        difference = z[pixel] - values[pixel, 0]
        if abs(difference) > tolerance and not (any_steep and steep[pixel]):
            redo[redo_count] = pixel
            residual[redo_count] = difference
            redo_count += 1
        if shade:
            # the flat-pixel shading, written out in both kernels on purpose: as a shared compiled function (even
            # inlined) it cost the relief case ~25 ms (110 -> 135 ms, 2026-11-27)
            lit = min(max(values[pixel, 1] * band + np.float32(0.5), np.float32(0.0)), np.float32(1.0))
            factor[pixel] = lit * values[pixel, 3] + values[pixel, 2]
            if values[pixel, 2] > rough_above:
                rough_index[rough_count] = pixel
                rough_lit[rough_count] = lit
                rough_count += 1
    return redo_count, rough_count


def solve_coarse(heights: np.ndarray, rays: RayFamily, z_bottom: float, z_top: float,
                 steps: int = COARSE_SECANT_STEPS) -> np.ndarray:
    """Safeguarded secant steps of every ray of a family from the fixed-point start (all at once).

    The first secant point is the level ground ``(0, -H(P0))``, the second the fixed-point start
    ``z0 = H(P0)``; each step is a bilinear read of the heights and one compiled pass
    (:func:`_coarse_step_kernel`: the residuals, the step of :func:`_secant` and the rays' points at the
    new heights). No residual is checked here: the full-resolution pass of :func:`parallax_hits` checks every
    pixel against the tolerance.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols), float32
        Window heights (m).
    rays : RayFamily
        The rays (C-contiguous float32 arrays).
    z_bottom, z_top : float
        Height bounds (m).
    steps : int, optional
        Secant steps (:data:`COARSE_SECANT_STEPS`).

    Returns
    -------
    ndarray, float32, shape of the rays
        Heights z (m).
    """
    level = remap_points(heights, rays.col0, rays.row0)
    f_previous = -level
    z = np.clip(level, np.float32(z_bottom), np.float32(z_top))
    z_previous = np.zeros_like(rays.col0)
    col, row = rays.at(z)
    read = np.empty_like(z)
    for _ in range(steps):
        remap_points(heights, col, row, out=read)
        _coarse_step_kernel(z.reshape(-1), read.reshape(-1), z_previous.reshape(-1), f_previous.reshape(-1),
                            np.float32(z_bottom), np.float32(z_top), rays.col0.reshape(-1), rays.row0.reshape(-1),
                            rays.col_per_m.reshape(-1), rays.row_per_m.reshape(-1), col.reshape(-1), row.reshape(-1))
    return z


@njit(cache=True, nogil=True, boundscheck=False)
def _coarse_step_kernel(z, read, z_previous, f_previous, z_bottom, z_top, col0, row0, col_per_m, row_per_m, col, row):
    """One step of :func:`solve_coarse` after the read ``H(P(z))``, in place.

    ``f = z - read``; ``(z_previous, f_previous) <- (z, f)``; ``z <-`` the safeguarded secant step of
    :func:`_secant` (its float32 operations: the same bits); ``(col, row) <-`` the rays at the new ``z``.
    """
    for ray in range(z.shape[0]):
        height = z[ray]
        f = height - read[ray]
        dz = height - z_previous[ray]
        slope = (f - f_previous[ray]) / dz if abs(dz) > np.float32(1e-6) else np.float32(1.0)
        if slope < np.float32(SECANT_SLOPE_RANGE[0]):
            slope = np.float32(SECANT_SLOPE_RANGE[0])
        if slope > np.float32(SECANT_SLOPE_RANGE[1]):
            slope = np.float32(SECANT_SLOPE_RANGE[1])
        following = height - f / slope
        if following < z_bottom:
            following = z_bottom
        if following > z_top:
            following = z_top
        z_previous[ray], f_previous[ray], z[ray] = height, f, following
        col[ray] = following * col_per_m[ray] + col0[ray]
        row[ray] = following * row_per_m[ray] + row0[ray]


def solve_points(heights: np.ndarray, rays: RayFamily, index: np.ndarray, z: np.ndarray, f: np.ndarray,
                 z_bottom: float, z_top: float, tolerance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Secant iterations of some rays of a family, each until it is within the tolerance.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols), float32
        Window heights (m).
    rays : RayFamily
        The rays (flat arrays).
    index : ndarray of int
        The rays to solve.
    z, f : ndarray, float32, shape (len(index),)
        Their current heights and residuals ``z - H(P(z))``.
    z_bottom, z_top : float
        Height bounds (m).
    tolerance_m : float
        Residual to reach (m).

    Returns
    -------
    z : ndarray, float32, shape (len(index),)
        Heights (m).
    converged : ndarray, bool, shape (len(index),)
        Whether each reached the tolerance.
    """
    z = z.copy()
    converged = np.zeros(len(index), dtype=bool)
    active = np.arange(len(index))
    z_now = np.clip(z - f, np.float32(z_bottom), np.float32(z_top))     # the fixed-point step
    z_previous, f_previous = z, f
    for _ in range(MAX_PIXEL_ITERATIONS):
        if not active.size:
            break
        f_now = z_now - remap_points(heights, *rays.at(z_now, index[active]))
        done = np.abs(f_now) <= tolerance_m
        z[active[done]] = z_now[done]
        converged[active[done]] = True
        going = ~done
        active = active[going]
        z_next = _secant(z_now[going], f_now[going], z_previous[going], f_previous[going], z_bottom, z_top)
        z_previous, f_previous, z_now = z_now[going], f_now[going], z_next
    return z, converged


@dataclass(frozen=True)
class ParallaxHits:
    """Where each pixel's ray meets the height field (the ``parallax`` method).

    Attributes
    ----------
    terrain : Terrain
        The terrain they are on (a :class:`simulator.scene.relief.ReliefTerrain`).
    crop : Crop
        The terrain window holding every hit.
    heights : ndarray, shape (rows, cols), float32
        The window's heights (m).
    col, row : ndarray, shape (H, W), float32
        Window coordinates of each pixel's surface point (sky pixels: anything).
    sky : ndarray, shape (H, W), bool
        Rays that miss the level ground.
    any_sky : bool
        Whether any pixel sees the sky.
    origin_m : ndarray, shape (3,)
        The rays' origin (m).
    counts : dict
        ``pixels``, ``pixel_iterated`` (solved on their own at full resolution), ``marched`` (reference
        march), ``exact_shading``.
    factor : ndarray, shape (H, W), float32, or None
        The radiance factor when the sun was known at the intersection (:func:`parallax_hits`).
    sun : ndarray, shape (3,), or None
        That sun.
    """

    terrain: Terrain
    crop: Crop
    heights: np.ndarray
    col: np.ndarray
    row: np.ndarray
    sky: np.ndarray
    any_sky: bool
    origin_m: np.ndarray
    counts: dict
    factor: np.ndarray | None = None
    sun: np.ndarray | None = None


def parallax_hits(terrain, camera, pose: ground_mapping.CameraPose, level_map: ground_mapping.GroundMap,
                  config, march, sun: np.ndarray | None = None) -> tuple[ground_mapping.GroundMap, ParallaxHits]:
    """The ground map of the height field (module doc: parallax), and its shading when the sun is given.

    Parameters
    ----------
    terrain : simulator.scene.relief.ReliefTerrain
        The terrain with heights.
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    level_map : GroundMap
        The level-ground map of the pose.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table (and ``shadow_diffuse_fraction``).
    march : callable
        ``march(heights, rays, index, z_bottom, z_top) -> z``: the reference ray march of the rays ``index``
        of a flat :class:`RayFamily` (:func:`simulator.scene.relief.march_heights`, configured).
    sun : ndarray, shape (3,), optional
        World unit vector toward the sun: the shading is then read in the same pass as the last check of
        the heights (else :func:`parallax_factor` reads it).

    Returns
    -------
    ground_map : GroundMap
        Hit points as terrain grid coordinates (the level map's rays and sky).
    hits : ParallaxHits
        The hits (with the radiance factor when ``sun`` is given).
    """
    relief_config = config.relief
    tolerance = float(relief_config.height_tolerance_m)
    mpp = terrain.metres_per_pixel
    crop = height_field.march_window(terrain, camera, pose)
    heights = np.ascontiguousarray(terrain.height_m[crop.row0:crop.row1, crop.col0:crop.col1], dtype=np.float32)
    z_bottom, z_top = (float(value) for value in cv2.minMaxLoc(heights)[:2])      # exact extremes, one pass
    origin = pose.ray_origin_m
    origin_row, origin_col = terrain.world_to_pixel(origin[0], origin[1])
    origin_col, origin_row = float(origin_col) - crop.col0, float(origin_row) - crop.row0
    altitude = float(origin[2])

    sky = level_map.sky
    height_px, width_px = level_map.col.shape
    shape = (height_px, width_px)
    pooled = sun is not None      # the pose's arrays are used up before the next pose: reuse their memory

    def work(name, dtype=np.float32, channels=()):
        return _work_array(name, shape + channels, dtype) if pooled else np.empty(shape + channels, dtype=dtype)
    # the level map in window coordinates (sky pixels: any point of the window, masked at the end); the rays'
    # slopes (grid px per metre of z) are formed where they are used, from these and the origin
    col0, row0 = work("col0"), work("row0")
    _level_lines_kernel(level_map.col.reshape(-1), level_map.row.reshape(-1), sky.reshape(-1), level_map.any_sky,
                        np.float32(crop.col0), np.float32(crop.row0), col0.reshape(-1), row0.reshape(-1))
    lines = (np.float32(origin_col), np.float32(origin_row), np.float32(1.0 / altitude))

    def subset(index: np.ndarray) -> RayFamily:
        """The rays ``index`` (flat) as a family of their own."""
        return RayFamily(col0.reshape(-1)[index], row0.reshape(-1)[index], origin_col, origin_row, altitude)

    # 1. the solve on half-resolution pixels (2 x 2 block means), classified by the slope bound and by
    #    the node normals' error
    even = height_px % 2 == 0 and width_px % 2 == 0 and min(height_px, width_px) >= 4
    if even:
        size = (width_px // 2, height_px // 2)
        sample = RayFamily(cv2.resize(col0, size, interpolation=cv2.INTER_AREA),
                           cv2.resize(row0, size, interpolation=cv2.INTER_AREA), origin_col, origin_row, altitude)
        z_sample = solve_coarse(heights, sample, z_bottom, z_top)
        z = cv2.resize(z_sample, (width_px, height_px), dst=work("z"), interpolation=cv2.INTER_LINEAR)
    else:
        sample = RayFamily(col0, row0, origin_col, origin_row, altitude)
        z_sample = z = np.clip(remap_points(heights, col0, row0), np.float32(z_bottom), np.float32(z_top))
    spacing = _ray_spacing(sample) if even else 0.0
    bound = terrain_slope_bound(terrain)[crop.row0:crop.row1, crop.col0:crop.col1]
    steep = _steep_rays(bound, sample, z_bottom, z_top, mpp, spacing)
    any_steep = bool(steep.any())
    if any_steep:
        if even:
            steep = cv2.resize(steep.view(np.uint8), (width_px, height_px), interpolation=cv2.INTER_NEAREST).view(bool)
        if level_map.any_sky:
            steep &= ~sky
        any_steep = bool(steep.any())

    # 2. at full resolution: one fixed-point step from the upsampled heights for every pixel, then a check
    #    (reading the shading in the same pass when the sun is known); pixels off the tolerance iterate
    col, row = work("col"), work("row")
    grid_col, grid_row = work("grid_col"), work("grid_row")
    _ray_points_kernel(z.reshape(-1), col0.reshape(-1), row0.reshape(-1), *lines, col.reshape(-1), row.reshape(-1))
    z = remap_points(heights, col, row, out=work("z_step"))          # z = H(P(z))
    _hit_points_kernel(z.reshape(-1), col0.reshape(-1), row0.reshape(-1), *lines, np.float32(crop.col0),
                       np.float32(crop.row0), col.reshape(-1), row.reshape(-1), grid_col.reshape(-1),
                       grid_row.reshape(-1))
    # the values read at the hits: the four of the shading nodes when the sun is known, else the heights
    source = heights if sun is None else _nodes(heights, crop, terrain, origin, sun, config)
    shade = sun is not None
    values = remap_points(source, col, row, out=work("values", channels=(4,)) if shade else None)
    # in one compiled pass: the pixels off the tolerance (not steep, not sky) and the radiance factor (when the
    # sun is known)
    band = np.float32(1.0 / max(relief_config.shadow_edge_m, 1e-9))
    rough_above = np.float32(config.shadow_diffuse_fraction + ROUGH_MARGIN if relief_config.slope_photometry else np.inf)
    factor = work("factor") if shade else np.empty((1, 1), dtype=np.float32)
    pixels = height_px * width_px
    redo_buffer, residual_buffer = work("redo", np.int32).reshape(-1), work("residual").reshape(-1)
    rough_buffer = work("rough_index", np.int32).reshape(-1) if shade else np.empty(0, dtype=np.int32)
    rough_lit_buffer = work("rough_lit").reshape(-1) if shade else np.empty(0, dtype=np.float32)
    redo_count, rough_count = _hits_kernel(
        z.reshape(-1), values.reshape(pixels, -1), steep.reshape(-1), any_steep, sky.reshape(-1),
        level_map.any_sky, np.float32(tolerance), shade, band, rough_above,
        np.float32(-ground_mapping.MAX_MAP_COORDINATE), factor.reshape(-1), grid_col.reshape(-1),
        grid_row.reshape(-1), redo_buffer, residual_buffer, rough_buffer, rough_lit_buffer)
    redo = redo_buffer[:redo_count].astype(np.intp)
    z_flat = z.reshape(-1)
    marched_index = np.flatnonzero(steep) if any_steep else np.empty(0, dtype=np.intp)
    if redo.size:
        z_redo, converged = solve_points(heights, subset(redo), np.arange(redo.size), z_flat[redo],
                                         residual_buffer[:redo_count], z_bottom, z_top, tolerance)
        z_flat[redo] = z_redo
        if not converged.all():
            marched_index = _sorted_union(marched_index, redo[~converged], pixels)
        redo = redo[converged]
    # 3. rays where a nearer bump may hide the crossing: the reference march
    if marched_index.size:
        z_flat[marched_index] = march(heights, subset(marched_index), np.arange(marched_index.size), z_bottom, z_top)
        changed = _sorted_union(marched_index, redo, pixels)
    else:
        changed = redo
    rough_index = rough_buffer[:rough_count].astype(np.intp)
    rough_lit = rough_lit_buffer[:rough_count]
    if changed.size:
        # the changed pixels read again, and their factor and grid coordinates formed again by the same pass
        col_changed, row_changed = subset(changed).at(z_flat[changed])
        col.reshape(-1)[changed], row.reshape(-1)[changed] = col_changed, row_changed
        values_changed = remap_points(source, col_changed, row_changed).reshape(changed.size, -1)
        count = changed.size
        factor_changed = np.empty(count if shade else 1, dtype=np.float32)
        rough_changed = np.empty(count if shade else 0, dtype=np.int32)
        rough_lit_changed = np.empty(count if shade else 0, dtype=np.float32)
        no_pixels = np.empty(0, dtype=np.float32)
        _, rough_changed_count = _hits_kernel(
            z_flat[changed], values_changed, steep.reshape(-1)[:1], False, sky.reshape(-1)[:1], False,
            np.float32(np.inf), shade, band, rough_above, np.float32(0.0), factor_changed, no_pixels, no_pixels,
            np.empty(count, dtype=np.int32), np.empty(count, dtype=np.float32), rough_changed, rough_lit_changed)
        grid_col.reshape(-1)[changed] = col_changed + np.float32(crop.col0)
        grid_row.reshape(-1)[changed] = row_changed + np.float32(crop.row0)
        if shade:
            factor.reshape(-1)[changed] = factor_changed
            # the rough pixels: those of the first pass not changed, and the changed ones that are, in pixel order
            rough_index, rough_lit = _replace_rough(rough_index, rough_lit, changed,
                                                    changed[rough_changed[:rough_changed_count]],
                                                    rough_lit_changed[:rough_changed_count], pixels)
    counts = {"pixels": int(col.size), "pixel_iterated": int(redo.size), "marched": int(marched_index.size)}
    hits = ParallaxHits(terrain, crop, heights, col, row, sky, level_map.any_sky, origin, counts)
    if sun is not None:
        if rough_index.size:        # pixels whose read touches a rough node: shaded at their own normal
            factor.reshape(-1)[rough_index] = exact_shading(hits, rough_index, rough_lit, sun, config)
        counts["exact_shading"] = int(rough_index.size)
    ground_map = ground_mapping.GroundMap(grid_col, grid_row, sky, level_map.any_sky, level_map._step,
                                          level_map._nodes, level_map._full, level_map.camera_rays,
                                          level_map.camera_to_world, level_map.ray_dz)
    if sun is not None:
        hits = dataclasses.replace(hits, factor=factor, sun=np.asarray(sun, dtype=float))
    return ground_map, hits


def _sorted_union(first: np.ndarray, second: np.ndarray, pixels: int) -> np.ndarray:
    """Sorted union of two sets of flat pixel indices (a frame mask when they are large, else a sort)."""
    if first.size + second.size <= pixels // 64:
        return np.union1d(first, second)
    mask = np.zeros(pixels, dtype=bool)
    mask[first] = True
    mask[second] = True
    return np.flatnonzero(mask)


def _replace_rough(rough_index: np.ndarray, rough_lit: np.ndarray, changed: np.ndarray, changed_rough: np.ndarray,
                   changed_rough_lit: np.ndarray, pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """The rough pixels (sorted) and their direct-sun fractions once the ``changed`` pixels were formed again.

    Those of the first pass that did not change, and ``changed_rough`` (with ``changed_rough_lit``); a frame
    mask when the sets are large, else a sorted merge.
    """
    if rough_index.size + changed.size <= pixels // 64:
        kept = ~np.isin(rough_index, changed, assume_unique=True)
        index = np.concatenate([rough_index[kept], changed_rough])
        lit = np.concatenate([rough_lit[kept], changed_rough_lit])
        order = np.argsort(index, kind="stable")
        return index[order], lit[order]
    mask = np.zeros(pixels, dtype=bool)
    lit_of_pixel = np.empty(pixels, dtype=np.float32)
    mask[rough_index] = True
    lit_of_pixel[rough_index] = rough_lit
    mask[changed] = False
    mask[changed_rough] = True
    lit_of_pixel[changed_rough] = changed_rough_lit
    index = np.flatnonzero(mask)
    return index, lit_of_pixel[index]


def _nodes(heights: np.ndarray, crop: Crop, terrain: Terrain, origin_m: np.ndarray, sun: np.ndarray, config):
    """:func:`shading_nodes` of a window."""
    return shading_nodes(terrain, crop, origin_m, sun, config)


def _factor(hits: ParallaxHits, values: np.ndarray, sun: np.ndarray, config, out=(None, None)) -> np.ndarray:
    """``d (1 + n_z)/2 + (1 - d) LS(n)/LS(flat) lit`` from the four values read at the hits.

    One compiled pass; pixels whose read touches a rough node are then shaded at their own normal
    (:func:`exact_shading`).

    ``out``: arrays for the pass's rough-pixel buffer (flat, int32) and the factor.
    """
    relief_config = config.relief
    band = np.float32(1.0 / max(relief_config.shadow_edge_m, 1e-9))
    shape = hits.col.shape
    factor = np.empty(shape, dtype=np.float32) if out[1] is None else out[1]
    rough_index = np.empty(hits.col.size, dtype=np.int32) if out[0] is None else out[0].reshape(-1)
    rough_lit = np.empty(hits.col.size, dtype=np.float32)
    rough_above = np.float32(config.shadow_diffuse_fraction + ROUGH_MARGIN if relief_config.slope_photometry else np.inf)
    count = _factor_kernel(values.reshape(-1, 4), hits.sky.reshape(-1), hits.any_sky, band, rough_above,
                           factor.reshape(-1), rough_index, rough_lit)
    index = rough_index[:count].astype(np.intp)
    if index.size:
        factor.reshape(-1)[index] = exact_shading(hits, index, rough_lit[:count], sun, config)
    hits.counts["exact_shading"] = int(index.size)
    return factor


@njit(cache=True, nogil=True, boundscheck=False)
def _factor_kernel(values, sky, any_sky, band, rough_above, factor, rough_index, rough_lit):
    """:func:`_factor`'s pass over flat pixels; returns the count of rough pixels.

    Writes the factor (1 for sky), and the indices and direct-sun fractions of the pixels whose sky term
    exceeds ``rough_above`` (a rough node in their read).
    """
    count = 0
    for pixel in range(values.shape[0]):
        if any_sky and sky[pixel]:
            factor[pixel] = np.float32(1.0)
            continue
        # the flat-pixel shading, written out in both kernels on purpose: as a shared compiled function (even
        # inlined) it cost the relief case ~25 ms (110 -> 135 ms, 2026-11-27)
        lit = min(max(values[pixel, 1] * band + np.float32(0.5), np.float32(0.0)), np.float32(1.0))
        factor[pixel] = lit * values[pixel, 3] + values[pixel, 2]
        if values[pixel, 2] > rough_above:
            rough_index[count] = pixel
            rough_lit[count] = lit
            count += 1
    return count


def parallax_factor(hits: ParallaxHits, sun: np.ndarray, config) -> np.ndarray:
    """Radiance factor of slope photometry and cast shadows at the hits (module doc: shading).

    Parameters
    ----------
    hits : ParallaxHits
        The hits of the pose.
    sun : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table and ``shadow_diffuse_fraction``.

    Returns
    -------
    ndarray, shape (H, W), float32
        ``d (1 + n_z)/2 + (1 - d) LS(n)/LS(flat) lit``; 1 for sky pixels.
    """
    if not (config.relief.slope_photometry or config.relief.cast_shadows):
        return np.ones(hits.col.shape, dtype=np.float32)
    if hits.factor is not None and hits.sun is not None and np.array_equal(hits.sun, np.asarray(sun, dtype=float)):
        return hits.factor
    nodes = _nodes(hits.heights, hits.crop, hits.terrain, hits.origin_m, sun, config)
    return _factor(hits, remap_points(nodes, hits.col, hits.row), sun, config)


def exact_shading(hits: ParallaxHits, index: np.ndarray, lit: np.ndarray, sun: np.ndarray, config) -> np.ndarray:
    """The reference's per-point shading (the bilinear surface's own normal) of some pixels.

    Parameters
    ----------
    hits : ParallaxHits
        The hits of the pose.
    index : ndarray of int
        Flat pixel indices.
    lit : ndarray, shape (len(index),), float32
        Their direct-sun fraction (cast shadows).
    sun : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Its ``shadow_diffuse_fraction``.

    Returns
    -------
    ndarray, shape (len(index),), float32
        ``(1 - d) lit LS(n)/LS(flat) + d (1 + n_z)/2``.
    """
    terrain, crop, origin = hits.terrain, hits.crop, hits.origin_m
    mpp = terrain.metres_per_pixel
    col, row = hits.col.reshape(-1)[index], hits.row.reshape(-1)[index]
    height, d_col, d_row = height_field.bilinear(hits.heights, col, row, gradient=True)
    normal = np.stack([-d_col / mpp, d_row / mpp, np.ones_like(d_col)], axis=1).astype(np.float64)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    east = terrain.origin_m[0] + (col.astype(np.float64) + crop.col0) * mpp
    north = terrain.origin_m[1] - (row.astype(np.float64) + crop.row0) * mpp
    view = np.stack([origin[0] - east, origin[1] - north, origin[2] - height.astype(np.float64)], axis=1)
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    direct = photometry.lommel_seeliger(normal @ sun, np.einsum("ij,ij->i", normal, view))
    direct /= np.maximum(photometry.lommel_seeliger(np.full(len(view), sun[2]), view[:, 2]), 1e-12)
    diffuse = float(config.shadow_diffuse_fraction)
    return ((1.0 - diffuse) * direct * lit + diffuse * 0.5 * (1.0 + normal[:, 2])).astype(np.float32)


def _ray_spacing(rays: RayFamily) -> float:
    """Largest grid distance between the level-ground points of neighbouring rays of a 2-D family (px)."""
    if rays.col0.ndim != 2 or min(rays.col0.shape) < 2:
        return 0.0
    step = max(min(rays.col0.shape) // 64, 1)
    col, row = rays.col0[::step, ::step], rays.row0[::step, ::step]
    return float(max(np.hypot(np.diff(col, axis=1), np.diff(row, axis=1)).max(),
                     np.hypot(np.diff(col, axis=0), np.diff(row, axis=0)).max())) / step


def _steep_rays(heights_bound: np.ndarray, rays: RayFamily, z_bottom: float, z_top: float, mpp: float,
                spacing_px: float) -> np.ndarray:
    """Rays whose segment between the height bounds may hold a slope with ``|q| >= UNIQUE_SLOPE_BOUND``.

    A ray's segment lies within ``L`` grid px of its point at the middle height (``L`` the largest
    half-length), so every cell it crosses opens at a node within ``L + 1`` (Chebyshev) of that point and
    within ``L + 2`` of each of the four nodes the bilinear read uses: the bound map is dilated by
    ``ceil(L + 2)``, plus ``spacing_px`` when a ray also speaks for its neighbours (the half-resolution
    solve).
    """
    if z_top <= z_bottom:
        return np.zeros(rays.col0.shape, dtype=bool)
    # sqrt is monotone: the square root of the largest squared slope is the largest slope, exactly
    largest_px_per_m = float(np.sqrt(_largest_squared_slope(rays.col_per_m.reshape(-1), rays.row_per_m.reshape(-1))))
    # the bound is >= 0, so its half-precision bits order as unsigned integers (an exact, faster maximum)
    largest_bound = float(heights_bound.view(np.uint16).max().view(np.float16)) if heights_bound.dtype == np.float16 \
        else float(heights_bound.max())
    if largest_bound * largest_px_per_m * mpp * (1.0 + 1e-5) < UNIQUE_SLOPE_BOUND:
        return np.zeros(rays.col0.shape, dtype=bool)    # no slope in the window reaches the bound for any ray
    half_length = 0.5 * (z_top - z_bottom) * largest_px_per_m
    radius = int(np.ceil(half_length + spacing_px + 2.0))
    bound = cv2.dilate(np.asarray(heights_bound, dtype=np.float32), np.ones((2 * radius + 1, 2 * radius + 1), np.uint8),
                       borderType=cv2.BORDER_REPLICATE)
    middle = np.float32(0.5 * (z_top + z_bottom))
    local = remap_points(bound, *rays.at(middle))
    px_per_m = np.sqrt(rays.col_per_m * rays.col_per_m + rays.row_per_m * rays.row_per_m)
    return local * (px_per_m * np.float32(mpp)) >= np.float32(UNIQUE_SLOPE_BOUND)


@njit(cache=True, nogil=True, boundscheck=False)
def _largest_squared_slope(col_per_m, row_per_m):
    """The largest ``col_per_m^2 + row_per_m^2`` (float32, as numpy rounds it) of flat rays (0 for none)."""
    largest = np.float32(0.0)
    for ray in range(col_per_m.shape[0]):
        squared = col_per_m[ray] * col_per_m[ray] + row_per_m[ray] * row_per_m[ray]
        if squared > largest:
            largest = squared
    return largest
