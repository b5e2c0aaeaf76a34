"""Terrain relief: a height field under the orbital image.

Seen with parallax, occlusion, slope shading and cast shadows (issue 23).

A :class:`ReliefTerrain` is a :class:`~simulator.scene.terrain.Terrain` with a height field ``height_m``
on the same grid (m above the datum z = 0 of the level frame; bilinear between pixel centres). Its
``reflectance_if`` is the I/F the orbiter would have measured were the ground level (albedo pattern,
haze, grain; no slope shading and no cast shadows): the descent geometry adds those here. A plain
:class:`Terrain` never enters this module, so relief off renders exactly as before (same bits, same
cost).

Ray-height intersection (:func:`intersect_rays`), per pixel ray ``P(z) = O + (z - O_z) / d_z d``:

1. bounds: the camera footprint between the planes of the global height extremes fixes a terrain
   window; the window's own extremes ``z_top >= H >= z_bottom`` bound every first hit;
2. march: ``z`` goes down from ``z_top`` in steps moving the ray by at most ``march_step_terrain_px``
   terrain pixels horizontally, until ``f(z) = z - H(P(z)) <= 0`` (``f(z_bottom) <= 0`` always, so every
   downward ray brackets a hit); the first sign change is the visible surface: nearer bumps occlude;
3. refine: false position with the Illinois modification inside the bracket until ``|f| <=
   height_tolerance_m`` (1 mm by default; the ground point is then within ``tolerance x tan(view
   angle)`` of the exact one on the bilinear surface).

A feature thinner than the march step along a grazing ray can be missed (the march samples it);
at 0.5 px and DIMES view angles (< 45 deg) the bilinear surface has no such features.

Shading (:func:`shading_factor`), relative to what the level-ground chain already computed
(photometric ratio, atmosphere, spectral scale)::

    factor = (1 - d) lit LS(n) / LS(flat) + d (1 + n_z) / 2,    LS = mu0 / (mu + mu0)

with ``n`` the normal of the bilinear surface at the hit point, the phase function cancelling (the
phase angle does not depend on the normal), ``d`` the diffuse (sky) fraction of the illumination
(``shadow_diffuse_fraction``, reaching a facet in proportion to the sky it sees) and ``lit`` the direct
sun: a point at height z is lit when ``z >= S(x, y)``, with ``S`` the height of the lowest sun ray
clearing the terrain towards the sun, marched on the terrain grid once per terrain and sun
(:func:`horizon_height`, steps of ``march_step_terrain_px``: a shadow edge is exact to that step).
So a tilted plane with ``d = 0`` shows exactly eq. (1) at its tilted normal, and level ground keeps its
flat-ground radiance. The lander's shadows and the motion-blur warps still use the level ground near the
hit point (sub-pixel differences).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TypeGuard

import cv2
import numpy as np

from flight_interface.camera import Camera
from simulator.scene import ground_mapping, parallax, photometry, resample
from simulator.scene.height_field import MAX_MARCH_STEPS, ReliefTerrain, bilinear, horizon_height, march_window
from simulator.scene.relief_config import ReliefConfig  # noqa: F401  (re-exported: the [scene.relief] table)
from simulator.scene.terrain import Terrain

MAX_REFINE_ITERATIONS = 60
SKIP_PX = 8                      # coarse skip of the ray march (grid pixels), bounded by a dilated height map


def has_relief(terrain: Terrain, config) -> TypeGuard[ReliefTerrain]:
    """Whether a terrain carries a height field and the configuration renders it.

    Parameters
    ----------
    terrain : Terrain
        The terrain.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table.

    Returns
    -------
    bool
        True for a :class:`ReliefTerrain` rendered with relief.
    """
    return isinstance(terrain, ReliefTerrain) and config.relief.enabled


@dataclass(frozen=True)
class ReliefHits:
    """Where each pixel's ray meets the height field.

    Attributes
    ----------
    terrain : ReliefTerrain
        The terrain they are on.
    points_m : ndarray, shape (H, W, 3), float64
        World hit points (m), 0 for sky.
    sky : ndarray, shape (H, W), bool
        Rays that miss the terrain.
    crop : resample.Crop
        Window holding every hit point.
    view_world : ndarray, shape (H, W, 3), float64
        Unit vectors from the hit point to the camera.
    """

    terrain: ReliefTerrain
    points_m: np.ndarray
    sky: np.ndarray
    crop: resample.Crop
    view_world: np.ndarray


def intersect_rays(heights: np.ndarray, to_grid, origin_m: np.ndarray, rays: np.ndarray, z_top: float,
                   z_bottom: float, step_m: float, tolerance_m: float, skip_px: int = SKIP_PX,
                   metres_per_pixel: float | None = None) -> np.ndarray:
    """First intersection of downward rays with a bilinear height field (see module doc).

    Parameters
    ----------
    heights : ndarray, shape (rows, cols)
        Height grid (m).
    to_grid : callable
        ``(east, north) -> (col, row)`` into the grid.
    origin_m : ndarray, shape (3,)
        Ray origin (m).
    rays : ndarray, shape (N, 3)
        Directions with d_z < 0 (any length).
    z_top, z_bottom : float
        Bounds of the heights the rays can meet (m).
    step_m : float
        Horizontal march step (m).
    tolerance_m : float
        ``|z - H|`` at the returned points (m).
    skip_px : int, optional
        Before the march, rays skip ``skip_px`` grid pixels at a time while they stay above the maximum
        of the heights within ``skip_px + 2`` pixels (a safe bound; 0: no skip).
    metres_per_pixel : float, optional
        Grid spacing (m), needed for the skip.

    Returns
    -------
    ndarray, shape (N,), float64
        Heights z of the hit points (m); the point is ``origin + (z - O_z) / d_z d``.
    """
    rays = np.asarray(rays, dtype=np.float64)
    # grid coordinates are affine in z along each ray (to_grid is affine): col = col0 + z col1
    col0, row0 = to_grid(origin_m[0] - origin_m[2] / rays[:, 2] * rays[:, 0],
                         origin_m[1] - origin_m[2] / rays[:, 2] * rays[:, 1])
    col_z, row_z = to_grid(origin_m[0] + (1.0 - origin_m[2]) / rays[:, 2] * rays[:, 0],
                           origin_m[1] + (1.0 - origin_m[2]) / rays[:, 2] * rays[:, 1])
    col_z, row_z = col_z - col0, row_z - row0
    slope = np.hypot(rays[:, 0], rays[:, 1]) / -rays[:, 2]          # horizontal move per metre of z
    return march_lines(heights, (col0, col_z, row0, row_z), slope, z_top, z_bottom, step_m, tolerance_m,
                       skip_px, metres_per_pixel)


def march_lines(heights: np.ndarray, lines, slope: np.ndarray, z_top: float, z_bottom: float, step_m: float,
                tolerance_m: float, skip_px: int = SKIP_PX, metres_per_pixel: float | None = None) -> np.ndarray:
    """The ray march of :func:`intersect_rays` on rays given as lines of the grid.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols)
        Height grid (m).
    lines : tuple of 4 ndarray, shape (N,)
        ``col0, col_z, row0, row_z``: the ray at height z is at grid ``(col0 + z col_z, row0 + z row_z)``.
    slope : ndarray, shape (N,)
        Horizontal move per metre of z (m/m: tan of the view angle).
    z_top, z_bottom, step_m, tolerance_m, skip_px, metres_per_pixel
        As :func:`intersect_rays`.

    Returns
    -------
    ndarray, shape (N,), float64
        Heights z of the hit points (m).
    """
    count = len(slope)
    span = max(z_top - z_bottom, 0.0)
    dz = np.minimum(step_m / np.maximum(slope, 1e-12), max(span, 1e-9))
    dz = np.maximum(dz, span / MAX_MARCH_STEPS)

    # evaluated in float32 (coordinates to ~1e-4 px, heights to ~1e-5 m: far inside the tolerance)
    coarse = [np.asarray(item, dtype=np.float32) for item in lines]

    def residual32(index, z, grid=heights):
        z = np.asarray(z, dtype=np.float32)
        return z - bilinear(grid, coarse[0][index] + z * coarse[1][index], coarse[2][index] + z * coarse[3][index])

    start = np.full(count, z_top)
    if skip_px > 0 and metres_per_pixel is not None and span > 0:
        # coarse skip: from z to z - skip_dz the ray moves skip_px px, inside the dilation window of its start
        size = 2 * (skip_px + 2) + 1
        ceiling = cv2.dilate(np.asarray(heights, dtype=np.float32), np.ones((size, size), np.uint8),
                             borderType=cv2.BORDER_REPLICATE)
        skip_dz = skip_px * metres_per_pixel / np.maximum(slope, 1e-12)
        active = np.nonzero(skip_dz < span)[0]
        while active.size:
            following = start[active] - skip_dz[active]
            free = (following > z_bottom) & (residual32(active, following, ceiling) > 0)
            start[active[free]] = following[free]
            active = active[free]
    upper = start.copy()
    f_upper = residual32(np.arange(count), start).astype(np.float64)
    lower = np.full(count, z_bottom)
    f_lower = np.full(count, -1.0)
    touching = f_upper <= 0                         # the start point is on the surface (a maximum at z_top)
    lower[touching], f_lower[touching] = start[touching], np.minimum(f_upper[touching], 0.0)
    active = np.nonzero(~touching)[0]
    k = 0
    while active.size:
        k += 1
        z = np.maximum(start[active] - k * dz[active], z_bottom)
        f = residual32(active, z)
        hit = (f <= 0) | (z <= z_bottom)             # f(z_bottom) <= 0: every ray ends bracketed
        done, going = active[hit], active[~hit]
        lower[done], f_lower[done] = z[hit], np.minimum(f[hit], 0.0)
        upper[going], f_upper[going] = z[~hit], f[~hit]
        active = going
    # false position (Illinois) inside [lower, upper]: f(lower) <= 0 < f(upper)
    active = np.nonzero((f_lower < -tolerance_m) & (upper > lower))[0]
    result = lower.copy()
    side = np.zeros(count, dtype=np.int8)
    for _ in range(MAX_REFINE_ITERATIONS):
        if not active.size:
            break
        fu, fl = f_upper[active], f_lower[active]
        z = (lower[active] * fu - upper[active] * fl) / (fu - fl)
        z = np.where((z > lower[active]) & (z < upper[active]), z, 0.5 * (lower[active] + upper[active]))
        f = residual32(active, z).astype(np.float64)
        result[active] = z
        below = f <= 0
        i_below, i_above = active[below], active[~below]
        lower[i_below], f_lower[i_below] = z[below], f[below]
        f_upper[i_below[side[i_below] == -1]] *= 0.5          # Illinois: halve the stale end
        upper[i_above], f_upper[i_above] = z[~below], f[~below]
        f_lower[i_above[side[i_above] == 1]] *= 0.5
        side[i_below], side[i_above] = -1, 1
        converged = (np.abs(f) <= tolerance_m) | (upper[active] - lower[active] <= 1e-9)
        active = active[~converged]
    return result


def find_hits(terrain: ReliefTerrain, camera: Camera, pose: ground_mapping.CameraPose, rays: np.ndarray,
              sky: np.ndarray, config) -> ReliefHits:
    """Hit points of every pixel ray on the terrain's height field.

    Parameters
    ----------
    terrain : ReliefTerrain
        The terrain with heights.
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    rays : ndarray, shape (H, W, 3)
        World ray directions.
    sky : ndarray, shape (H, W), bool
        Rays that miss the level ground.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table (march step, tolerance).

    Returns
    -------
    ReliefHits
        The hits.
    """
    crop = march_window(terrain, camera, pose)
    heights = np.ascontiguousarray(terrain.height_m[crop.row0:crop.row1, crop.col0:crop.col1])
    mpp = terrain.metres_per_pixel

    def to_grid(east, north):
        row, col = terrain.world_to_pixel(east, north)
        return col - crop.col0, row - crop.row0

    flat = np.asarray(rays, dtype=np.float64).reshape(-1, 3)
    ground = np.flatnonzero(~sky) if sky.any() else slice(None)
    rays_ground = flat[ground]
    origin = pose.ray_origin_m
    z = intersect_rays(heights, to_grid, origin, rays_ground, float(heights.max()), float(heights.min()),
                       config.relief.march_step_terrain_px * mpp, config.relief.height_tolerance_m,
                       metres_per_pixel=mpp)
    points = np.zeros_like(flat)
    points[ground] = origin + ((z - origin[2]) / rays_ground[:, 2])[:, None] * rays_ground
    points[ground, 2] = z
    view = np.zeros_like(flat)
    view[ground] = rays_ground / -np.sqrt(np.einsum("ij,ij->i", rays_ground, rays_ground))[:, None]
    shape = rays.shape
    return ReliefHits(terrain, points.reshape(shape), sky, crop, view.reshape(shape))


def march_heights(heights: np.ndarray, rays, index: np.ndarray, z_bottom: float, z_top: float, config,
                  metres_per_pixel: float) -> np.ndarray:
    """The reference march of some rays of a :class:`simulator.scene.parallax.RayFamily`.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols), float32
        Window heights (m).
    rays : simulator.scene.parallax.RayFamily
        Flat rays in window coordinates.
    index : ndarray of int
        The rays to march.
    z_bottom, z_top : float
        Height bounds (m).
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table (march step, tolerance).
    metres_per_pixel : float
        Grid spacing (m).

    Returns
    -------
    ndarray, shape (len(index),), float32
        Heights z of the hits (m).
    """
    col_z, row_z = rays.col_per_m[index], rays.row_per_m[index]
    slope = np.sqrt(col_z.astype(np.float64) ** 2 + row_z.astype(np.float64) ** 2) * metres_per_pixel
    z = march_lines(heights, (rays.col0[index], col_z, rays.row0[index], row_z), slope, z_top, z_bottom,
                    config.relief.march_step_terrain_px * metres_per_pixel, config.relief.height_tolerance_m,
                    metres_per_pixel=metres_per_pixel)
    return z.astype(np.float32)


def relief_ground_map(terrain: ReliefTerrain, camera: Camera, pose: ground_mapping.CameraPose,
                      level_map: ground_mapping.GroundMap, config, sun_world: np.ndarray | None = None):
    """The ground map of the height field and the hits.

    Parameters
    ----------
    terrain : ReliefTerrain
        The terrain with heights.
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    level_map : GroundMap
        The level-ground map of the pose (its rays).
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table.
    sun_world : ndarray, shape (3,), optional
        World unit vector toward the sun: the ``parallax`` method then reads the shading in the same pass
        as the hits (:func:`shading_factor` returns it).

    Returns
    -------
    ground_map : GroundMap
        Hit points as terrain grid coordinates.
    hits : ReliefHits or simulator.scene.parallax.ParallaxHits
        The hits (``march`` or ``parallax`` method), for :func:`shading_factor`.
    """
    if config.relief.method == "parallax":
        def march(heights, rays, index, z_bottom, z_top):
            return march_heights(heights, rays, index, z_bottom, z_top, config, terrain.metres_per_pixel)
        sun = None if sun_world is None else np.asarray(sun_world, dtype=float)
        return parallax.parallax_hits(terrain, camera, pose, level_map, config, march, sun)
    rays = level_map.rays()
    hits = find_hits(terrain, camera, pose, rays, level_map.sky, config)
    row, col = terrain.world_to_pixel(hits.points_m[..., 0], hits.points_m[..., 1])
    col = col.astype(np.float32)
    row = row.astype(np.float32)
    if level_map.any_sky:
        col[level_map.sky] = -ground_mapping.MAX_MAP_COORDINATE
        row[level_map.sky] = -ground_mapping.MAX_MAP_COORDINATE
    return ground_mapping.GroundMap(col, row, level_map.sky, level_map.any_sky, 0, None, rays), hits


def hits_inside_terrain(terrain: ReliefTerrain, hits) -> bool:
    """Whether every hit point of a pose is inside the terrain (its reflectance needs no outside mask).

    The hits lie in their window (:func:`simulator.scene.height_field.march_window`: the footprint between
    the planes of the height extremes with a 3-px margin, clipped to the terrain); a window that no edge of
    the terrain clipped holds them inside the terrain.

    Parameters
    ----------
    terrain : ReliefTerrain
        The terrain.
    hits : ReliefHits or simulator.scene.parallax.ParallaxHits
        The hits of the pose.

    Returns
    -------
    bool
        True when the window keeps off all four edges of the terrain.
    """
    rows, cols = terrain.shape
    crop = hits.crop
    return crop.row0 > 0 and crop.col0 > 0 and crop.row1 < rows and crop.col1 < cols


def shading_factor(hits, sun_world: np.ndarray, config) -> np.ndarray:
    """Radiance factor of slope photometry and cast shadows over level-ground radiance (module doc).

    Parameters
    ----------
    hits : ReliefHits or simulator.scene.parallax.ParallaxHits
        The hits of the pose (the ``parallax`` method's shading: :func:`simulator.scene.parallax.parallax_factor`).
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Its ``relief`` table.

    Returns
    -------
    ndarray, shape (H, W), float32
        The factor; 1 for sky pixels.
    """
    if isinstance(hits, parallax.ParallaxHits):
        return parallax.parallax_factor(hits, np.asarray(sun_world, dtype=float), config)
    terrain = hits.terrain
    relief = config.relief
    shape = hits.sky.shape
    ground = ~hits.sky
    factor = np.ones(shape, dtype=np.float32)
    if not (relief.slope_photometry or relief.cast_shadows):
        return factor
    points = hits.points_m[ground]
    row, col = (item.astype(np.float32) for item in terrain.world_to_pixel(points[:, 0], points[:, 1]))
    mpp = terrain.metres_per_pixel
    sun = np.asarray(sun_world, dtype=float)
    view = hits.view_world[ground]
    diffuse = float(config.shadow_diffuse_fraction)
    if relief.slope_photometry:
        _, d_col, d_row = bilinear(terrain.height_m, col, row, gradient=True)
        normal = np.stack([-d_col / mpp, d_row / mpp, np.ones_like(d_col)], axis=1)   # rows run south
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        direct = photometry.lommel_seeliger(normal @ sun, np.einsum("ij,ij->i", normal, view))
        direct /= np.maximum(photometry.lommel_seeliger(np.full(len(view), sun[2]), view[:, 2]), 1e-12)
        sky_view = 0.5 * (1.0 + normal[:, 2])
    else:
        direct = np.ones(len(view))
        sky_view = np.ones(len(view))
    if relief.cast_shadows:
        horizon = horizon_height(terrain, sun, relief.march_step_terrain_px)
        above = points[:, 2] - bilinear(horizon, col, row)
        band = max(relief.shadow_edge_m, 1e-9)
        direct = direct * np.clip(above / band + 0.5, 0.0, 1.0)
    factor[ground] = (1.0 - diffuse) * direct + diffuse * sky_view
    return factor
