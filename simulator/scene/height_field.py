"""The height field of a relief terrain and what both relief methods read from it.

The terrain type, its height extremes, bilinear heights (and their gradient) at fractional grid positions, the terrain window a
pose's rays can hit, and the sun's horizon height (cast shadows). :mod:`simulator.scene.relief` (the
reference ray march) and :mod:`simulator.scene.parallax` (fixed-point parallax) both build on it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED
from simulator.scene import ground_mapping, resample
from simulator.scene.terrain import Terrain

MAX_MARCH_STEPS = 20_000        # a ray skimming the horizon stops marching here (taken at z_bottom)


@dataclass(frozen=True)
class ReliefTerrain(Terrain):
    """A terrain with a height field.

    Attributes
    ----------
    height_m : ndarray, float32, shape (rows, cols)
        Height above the level datum z = 0 at each pixel centre (m), bilinear in between.
    (others as :class:`Terrain`; ``reflectance_if`` holds no slope shading or cast shadows)
    """

    height_m: np.ndarray = field(kw_only=True)

    def __post_init__(self):
        super().__post_init__()
        if self.height_m.shape != self.reflectance_if.shape or not np.all(np.isfinite(self.height_m)):
            raise ValueError(f"terrain {self.name}: height_m must be finite, of the image's shape "
                             f"{self.reflectance_if.shape}; got shape {self.height_m.shape}")


def height_extremes(terrain: ReliefTerrain) -> tuple[float, float]:
    """Lowest and highest height of the terrain, cached per terrain.

    Parameters
    ----------
    terrain : ReliefTerrain
        The terrain with heights.

    Returns
    -------
    (float, float)
        Lowest and highest height (m).
    """
    cache = DERIVED.of(terrain, "relief")
    if "extremes" not in cache:
        cache["extremes"] = (float(terrain.height_m.min()), float(terrain.height_m.max()))
    return cache["extremes"]


def bilinear(grid: np.ndarray, col: np.ndarray, row: np.ndarray, gradient: bool = False):
    """Bilinear interpolation of a grid at fractional coordinates, edges replicated.

    Parameters
    ----------
    grid : ndarray, shape (rows, cols)
        Values.
    col, row : ndarray
        Fractional grid coordinates, equal shapes.
    gradient : bool, optional
        Also return the exact derivatives of the bilinear surface.

    Returns
    -------
    value : ndarray, float64, shape of ``col``
        Interpolated values.
    d_dcol, d_drow : ndarray, float64, shape of ``col``
        Only with ``gradient``: the derivatives along columns and rows (per grid pixel).
    """
    rows, cols = grid.shape
    flat = grid.ravel() if grid.flags.c_contiguous else np.ascontiguousarray(grid).ravel()
    col = np.clip(col, 0.0, cols - 1.0)
    row = np.clip(row, 0.0, rows - 1.0)
    c0 = np.minimum(col.astype(np.int64), max(cols - 2, 0))
    r0 = np.minimum(row.astype(np.int64), max(rows - 2, 0))
    fc, fr = col - c0.astype(col.dtype), row - r0.astype(row.dtype)
    index = r0 * cols + c0
    right = 1 if cols > 1 else 0
    down = cols if rows > 1 else 0
    h00 = flat.take(index)
    h01 = flat.take(index + right)
    h10 = flat.take(index + down)
    h11 = flat.take(index + down + right)
    top = h00 + fc * (h01 - h00)
    bottom = h10 + fc * (h11 - h10)
    value = top + fr * (bottom - top)
    if not gradient:
        return value
    return value, (1.0 - fr) * (h01 - h00) + fr * (h11 - h10), bottom - top


def march_window(terrain: ReliefTerrain, camera: Camera, pose: ground_mapping.CameraPose) -> resample.Crop:
    """Terrain window holding every first hit of the pixel rays.

    The footprint between the planes of the global extremes (the whole terrain when a border ray misses
    one of them).

    Parameters
    ----------
    terrain : ReliefTerrain
        The terrain with heights.
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.

    Returns
    -------
    resample.Crop
        The window of the terrain grid.
    """
    low, high = height_extremes(terrain)
    rays = ground_mapping.camera_frame_rays(camera, ground_mapping.border_pixels(camera)) @ pose.camera_to_world.T
    origin = pose.ray_origin_m
    if not (np.all(rays[:, 2] < -ground_mapping.HORIZON_EPSILON) and origin[2] > high):
        rows, cols = terrain.shape
        return resample.Crop(0, rows, 0, cols)
    corners = [origin + ((level - origin[2]) / rays[:, 2])[:, None] * rays for level in (low, high)]
    points = np.concatenate(corners)
    cols_px, rows_px = terrain.world_to_pixel(points[:, 0], points[:, 1])[::-1]
    return resample.footprint_crop(terrain, cols_px, rows_px, True, margin_px=3)


def horizon_height(terrain: ReliefTerrain, sun_world: np.ndarray, step_terrain_px: float,
                   cached: bool = True) -> np.ndarray:
    """Height of the lowest sun ray that clears the terrain towards the sun, from each pixel centre.

    ``S = max_k H(p + k s) - k s tan(elevation)`` over steps ``s`` of ``step_terrain_px`` towards the
    sun's azimuth (k >= 1, until the height range is climbed); a point at height z is in the sun when
    ``z >= S``. Cached per terrain, sun and step.

    Parameters
    ----------
    terrain : ReliefTerrain
        The terrain with heights.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    step_terrain_px : float
        March step (terrain pixels).
    cached : bool, optional
        Keep the result in the terrain's cache (False: a caller that keeps what it derives from it).

    Returns
    -------
    ndarray, shape (rows, cols), float32
        ``S`` (m).
    """
    sun = np.asarray(sun_world, dtype=float)
    cache = DERIVED.of(terrain, "relief")
    key = ("horizon", tuple(np.round(sun, 12)), float(step_terrain_px))
    if key in cache:
        return cache[key]
    low, high = height_extremes(terrain)
    heights = terrain.height_m
    horizontal = float(np.hypot(sun[0], sun[1]))
    result = np.full(heights.shape, low - 1.0, dtype=np.float32)   # below every height: lit
    if horizontal > 1e-12 and high > low:
        d_col, d_row = step_terrain_px * sun[0] / horizontal, -step_terrain_px * sun[1] / horizontal
        climb = step_terrain_px * terrain.metres_per_pixel * sun[2] / horizontal
        steps = min(int(np.ceil((high - low) / climb)), MAX_MARCH_STEPS)
        pad = int(np.ceil(steps * step_terrain_px)) + 2
        padded = np.pad(np.asarray(heights, dtype=np.float32), pad, mode="edge")
        rows, cols = heights.shape
        for k in range(1, steps + 1):
            row_shift, col_shift = k * d_row, k * d_col
            r, c = int(np.floor(row_shift)), int(np.floor(col_shift))
            fr, fc = np.float32(row_shift - r), np.float32(col_shift - c)

            def window(dr, dc, r=r, c=c):
                return padded[pad + r + dr:pad + r + dr + rows, pad + c + dc:pad + c + dc + cols]
            top = window(0, 0) * (1 - fc) + window(0, 1) * fc
            bottom = window(1, 0) * (1 - fc) + window(1, 1) * fc
            shifted = top * (1 - fr) + bottom * fr
            shifted -= np.float32(k * climb)
            np.maximum(result, shifted, out=result)
    if cached:
        cache[key] = result
    return result
