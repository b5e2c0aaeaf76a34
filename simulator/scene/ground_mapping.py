"""Ray-ground mapping: which point of the level ground plane (z = 0) each camera pixel sees.

A pixel's world ray starts at the CAHVOR centre C (moved to the world by the lander pose and the camera
mounting) and points along ``R_cw @ r``, with ``r`` the pixel's unit ray in the camera frame
(:attr:`flight_interface.camera.Camera.pixel_rays`). It meets the ground at ``t = -O_z / d_z`` when
``d_z < 0``; other rays are *sky* (masked, zero radiance, never NaN).

Speed: the unit rays of a camera are fixed, so per pose we only rotate rays. With
``grid_step_px > 0`` the rays are rotated on a coarse grid of nodes every ``grid_step_px`` pixels and
interpolated bilinearly (``cv2.resize``) to every pixel *before* the division by ``d_z``; node rays are
scaled to unit boresight component, which makes them exactly affine in pixel coordinates for a
distortion-free camera, so the interpolation is exact there and the horizon stays sharp (the division is
per pixel). Lens distortion adds a small smooth residual (measured by the tests and the benchmark).
With no sky in view the interpolation and the divisions are one compiled pass that writes only the map
(:func:`simulator.scene.node_grid_fused.divided_node_planes`: OpenCV's arithmetic, the same bits).
``grid_step_px = 0`` uses every cached pixel ray (reference): the numerators ``P_c``, ``P_r`` and
``d_z`` are linear forms of the camera-frame ray, so each is one ``cv2.transform`` of the cached
(H, W, 3) float32 rays with a 1 x 3 matrix (the rotation folded into the form) instead of rotating
every ray and combining the components; the world rays themselves are rotated only for the windows
that need them (shadows, heat shield) or on request (:meth:`GroundMap.rays`). Same equations, float32
rounding of the folded coefficients (~1e-7 relative).

Work arrays: full-frame intermediates that die inside one call (the upsampled planes before the
division, an upsampled ratio or flow before it is applied) are written into per-thread scratch arrays
(:func:`simulator.scratch.scratch`) instead of new allocations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from flight_interface import cahvor
from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED
from simulator.scene.descent_profile import Pose, unit_quat
from simulator.scene.node_grid import interpolate_nodes_window, node_positions, upsample_nodes
from simulator.scratch import scratch

HORIZON_EPSILON = 1e-6      # |d_z| below this (unit ray) counts as sky
MAX_MAP_COORDINATE = 1.0e7  # map coordinates are clipped here (far beyond any terrain)


@dataclass(frozen=True)
class CameraPose:
    """Where the camera is and how it is turned, in the world frame.

    Attributes
    ----------
    frame_origin_m : (3,) world position of the camera frame origin (lander position + mounting offset)
    ray_origin_m : (3,) world position of the CAHVOR centre C (origin of every pixel ray)
    camera_to_world : (3, 3) rotation matrix, ``v_world = camera_to_world @ v_camera``
    """

    frame_origin_m: np.ndarray
    ray_origin_m: np.ndarray
    camera_to_world: np.ndarray

    @property
    def altitude_m(self) -> float:
        """Height of the CAHVOR centre above the ground plane z = 0 (m)."""
        return float(self.ray_origin_m[2])

    @property
    def boresight_world(self) -> np.ndarray:
        """World direction of the camera frame's z axis, shape (3,)."""
        return self.camera_to_world[:, 2]


def camera_pose(camera: Camera, pose: Pose) -> CameraPose:
    """The camera's world pose from the lander pose and the camera mounting.

    Parameters
    ----------
    camera : Camera
        The camera (mounting in the lander frame, CAHVOR centre).
    pose : Pose
        Lander pose (attitude body-to-world).

    Returns
    -------
    CameraPose
        Frame origin, ray origin (m) and camera-to-world rotation.
    """
    cache = camera_cache(camera)
    mounting = cache.get("mounting")
    if mounting is None:      # (camera-to-lander rotation, camera position in the lander, CAHVOR centre C)
        mounting = cache["mounting"] = (camera.camera_to_lander_matrix,
                                        np.asarray(camera.camera_position_in_lander_m, dtype=float),
                                        np.asarray(camera.model.c, dtype=float))
    camera_to_lander, position_in_lander, centre = mounting
    lander_to_world = _rotation_matrix(pose.attitude_quat)
    camera_to_world = lander_to_world @ camera_to_lander
    frame_origin = np.asarray(pose.position_m, dtype=float) + lander_to_world @ position_in_lander
    return CameraPose(frame_origin, frame_origin + camera_to_world @ centre, camera_to_world)


def _rotation_matrix(quaternion: np.ndarray) -> np.ndarray:
    """:func:`flight_interface.frames.quat_to_matrix` of one quaternion, in scalar arithmetic (3, 3)."""
    w, x, y, z = unit_quat(quaternion.tolist() if isinstance(quaternion, np.ndarray) else quaternion)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def camera_cache(camera: Camera) -> dict:
    """A per-camera cache dict (cameras are frozen dataclasses holding arrays, hence unhashable).

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    dict
        The scene stage's cache of ``camera`` (:data:`simulator.derived_cache.DERIVED`).
    """
    return DERIVED.of(camera, "scene")


def node_rays(camera: Camera, step_px: int) -> np.ndarray:
    """Camera-frame rays at the coarse grid nodes, scaled to unit component along the pointing axis A (cached per camera).

    Parameters
    ----------
    camera : Camera
        The camera.
    step_px : int
        Node spacing (px).

    Returns
    -------
    ndarray, shape (ny, nx, 3), float64
        Rays.
    """
    cache = camera_cache(camera)
    key = ("node_rays", step_px)
    if key not in cache:
        rows = node_positions(camera.height_px, step_px)
        cols = node_positions(camera.width_px, step_px)
        grid = np.stack(np.meshgrid(cols, rows), axis=-1)
        rays = cahvor.unproject(camera.model, grid)
        cache[key] = rays / (rays @ camera.model.a)[..., None]
    return cache[key]


def pixel_rays_f32(camera: Camera) -> np.ndarray:
    """The camera's unit pixel rays as float32 (cached).

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    ndarray, shape (height, width, 3), float32
        Camera-frame unit rays.
    """
    cache = camera_cache(camera)
    if "pixel_rays_f32" not in cache:
        cache["pixel_rays_f32"] = np.ascontiguousarray(camera.pixel_rays, dtype=np.float32)
    return cache["pixel_rays_f32"]


class GroundMap:
    """Ground points seen by every pixel, as fractional coordinates of a north-up ground grid.

    :meth:`rays` gives the world ray directions of any window (interpolated from the nodes, so not unit
    length, when the map was built on the coarse grid; exact unit rays otherwise).

    Parameters
    ----------
    col, row : ndarray, shape (height, width), float32
        Grid coordinates ``col = (east - east0)/mpp``, ``row = (north0 - north)/mpp``; sky pixels hold
        ``-MAX_MAP_COORDINATE``.
    sky : ndarray, shape (height, width), bool
        True where the ray does not meet the ground.
    any_sky : bool
        False when no pixel sees the sky (decided on the node grid or the exact rays).
    step_px : int
        Node spacing of a coarse map (px), 0 for an exact map.
    node_rays_world : ndarray, shape (ny, nx, 3), optional
        Coarse map: the world rays at the nodes.
    full_rays : ndarray, shape (height, width, 3), optional
        World rays of every pixel, when already known.
    camera_rays : ndarray, shape (height, width, 3), float32, optional
        Exact map: the camera's unit pixel rays.
    camera_to_world : ndarray, shape (3, 3), optional
        Exact map: rotation of those rays.
    ray_dz : ndarray, shape (height, width), float32, optional
        Exact map: world d_z of every unit pixel ray.
    cos_phase : ndarray, shape (height, width), float32, optional
        Exact map built with a sun vector: the phase-angle cosine of every pixel, handed over (and
        dropped) by :func:`view_cosines`.
    """

    def __init__(self, col, row, sky, any_sky, step_px, node_rays_world=None, full_rays=None,
                 camera_rays=None, camera_to_world=None, ray_dz=None, cos_phase=None):
        self.col, self.row, self.sky, self.any_sky = col, row, sky, any_sky
        self._step = step_px
        self._nodes = node_rays_world
        self._full = full_rays
        self.camera_rays = camera_rays          # exact map: the camera's unit pixel rays (H, W, 3) float32
        self.camera_to_world = camera_to_world  # exact map: (3, 3) rotation of those rays
        self.ray_dz = ray_dz                    # exact map: world d_z of every unit pixel ray (H, W) float32
        self.cos_phase = cos_phase              # exact map: phase cosine per pixel (scratch), read once by view_cosines

    def rays(self, row0: int = 0, row1: int | None = None, col0: int = 0, col1: int | None = None) -> np.ndarray:
        """World ray directions of the pixels ``[row0:row1, col0:col1]``.

        Parameters
        ----------
        row0, row1, col0, col1 : int, optional
            Window (default: the whole frame).

        Returns
        -------
        ndarray, shape (rows, cols, 3), float32
            Ray directions (unit on an exact map).
        """
        height, width = self.col.shape
        row1 = height if row1 is None else row1
        col1 = width if col1 is None else col1
        if self._full is not None:
            return self._full[row0:row1, col0:col1]
        full = (row0, row1, col0, col1) == (0, height, 0, width)
        if self.camera_rays is not None:      # exact map: rotate the cached unit rays of the window
            window = self.camera_rays[row0:row1, col0:col1]
            rotated = cv2.transform(window, self.camera_to_world)
            if full:
                self._full = rotated
            return rotated
        if full:
            self._full = upsample_nodes(self._nodes, self._step, height, width)
            return self._full
        return interpolate_nodes_window(self._nodes, self._step, row0, row1, col0, col1)


#: Scratch names of a coarse map's upsampled planes (P_c, P_r, d_z): dead once the map is divided, so the
#: next full-frame intermediate of the same shape (a pose's upsampled photometric ratio) reuses one of them.
COARSE_PLANE_SCRATCH = ("map_col", "map_row", "map_dz")
EXACT_STRIP_ROWS = 128   # rows per strip of the exact map (1.5 MiB of rays): read from memory once, reused from cache


def map_to_ground_grid(camera: Camera, pose: CameraPose, grid_origin_m: tuple[float, float],
                       metres_per_pixel: float, grid_step_px: int, scratch_maps: bool = False,
                       phase_sun_world: np.ndarray | None = None) -> GroundMap:
    """Intersect every pixel's ray with the ground and express the points on a ground grid.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    grid_origin_m : (float, float)
        World coordinates (east0, north0) of the grid's (row 0, col 0) pixel centre (m).
    metres_per_pixel : float
        Grid spacing (m).
    grid_step_px : int
        Coarse interpolation step (0: exact per-pixel rays).
    scratch_maps : bool, optional
        Write ``col``, ``row`` (and the exact map's ``d_z``) into this thread's
        :func:`~simulator.scratch.scratch` arrays: the map is then valid only until the next such call
        for a frame of the same size (a render that is done with its map before it renders again).
    phase_sun_world : ndarray, shape (3,), optional
        Exact map: also the cosine of the phase angle of every pixel for this world sun vector, read
        once by :func:`view_cosines` (computed in the same pass over the rays).

    Returns
    -------
    GroundMap
        Grid coordinates and sky mask of every pixel.

    Notes
    -----
    ``col = col0 - O_z d_x / (d_z mpp)`` is written as ``P_c / d_z`` with ``P_c = col0 d_z - O_z d_x / mpp``
    (likewise for rows); on the coarse grid ``P_c``, ``P_r`` and ``d_z`` are interpolated and divided per
    pixel, so the map is exact for a pinhole camera and the horizon is found per pixel.

    The exact map runs over :data:`EXACT_STRIP_ROWS`-row strips: each linear form (and the phase
    cosine) is a ``cv2.transform`` of the strip's rays and each map value a ``cv2.divide`` of the strip,
    element by element as over the whole frame (the same bits), but the (H, W, 3) rays - 12 MiB per
    camera, one camera per supersampling offset - are read from memory once per pose instead of once
    per form.
    """
    from simulator.scene import node_grid_fused  # numba: loaded by rendering, not with the configuration

    height, width = camera.height_px, camera.width_px
    altitude = float(pose.ray_origin_m[2])
    inv_mpp = 1.0 / metres_per_pixel
    col0 = (pose.ray_origin_m[0] - grid_origin_m[0]) * inv_mpp
    row0 = (grid_origin_m[1] - pose.ray_origin_m[1]) * inv_mpp
    k = altitude * inv_mpp
    if grid_step_px > 0:
        nodes = node_rays(camera, grid_step_px) @ pose.camera_to_world.T
        dz_nodes = nodes[..., 2]
        planes = [col0 * dz_nodes - k * nodes[..., 0], row0 * dz_nodes + k * nodes[..., 1], dz_nodes]
        # interpolation is a convex combination: all nodes below the horizon -> every pixel is
        unit_dz_max = float(np.max(dz_nodes / np.linalg.norm(nodes, axis=-1)))
        any_sky = altitude <= 0 or unit_dz_max >= -HORIZON_EPSILON
        if not any_sky and node_grid_fused.fused_passes_match_opencv(height, width, grid_step_px):
            # no sky: the planes are interpolated and divided in one pass, never written upsampled (node_grid)
            col, row = ((scratch(name, (height, width)) if scratch_maps else np.empty((height, width), np.float32))
                        for name in ("map_col_out", "map_row_out"))
            node_grid_fused.divided_node_planes(planes[0], planes[1], planes[2], grid_step_px, col, row)
            return GroundMap(col, row, np.zeros((height, width), dtype=bool), False, grid_step_px, nodes)
        col_num, row_num, dz = (upsample_nodes(plane, grid_step_px, height, width, scratch_name=name)
                                for plane, name in zip(planes, COARSE_PLANE_SCRATCH))
    else:
        exact = _exact_map(pixel_rays_f32(camera), pose.camera_to_world, col0, row0, k, scratch_maps, phase_sun_world)
        col, row, dz, cos_phase, dz_max = exact
        any_sky = altitude <= 0 or dz_max >= -HORIZON_EPSILON
        sky = _sky_and_clip(col, row, dz, any_sky, altitude)
        return GroundMap(col, row, sky, any_sky, 0, camera_rays=pixel_rays_f32(camera),
                         camera_to_world=pose.camera_to_world, ray_dz=dz, cos_phase=cos_phase)
    if scratch_maps:
        col = cv2.divide(col_num, dz, dst=scratch("map_col_out", (height, width)))
        row = cv2.divide(row_num, dz, dst=scratch("map_row_out", (height, width)))
    else:
        col = cv2.divide(col_num, dz)
        row = cv2.divide(row_num, dz)
    sky = _sky_and_clip(col, row, dz, any_sky, altitude)
    return GroundMap(col, row, sky, any_sky, grid_step_px, nodes)


def _exact_map(camera_rays: np.ndarray, rotation: np.ndarray, col0: float, row0: float, k: float,
               scratch_maps: bool, phase_sun_world: np.ndarray | None):
    """The exact map's ``col, row, d_z``, the phase cosine (or None) and ``max d_z``, strip by strip.

    ``P_c``, ``P_r`` and ``d_z`` are linear forms of the camera-frame ray (one ``cv2.transform`` each);
    see :func:`map_to_ground_grid`.
    """
    height, width = camera_rays.shape[:2]

    def frame(name: str) -> np.ndarray:
        return scratch(name, (height, width)) if scratch_maps else np.empty((height, width), dtype=np.float32)
    forms = [form[None, :] for form in (col0 * rotation[2] - k * rotation[0], row0 * rotation[2] + k * rotation[1],
                                        rotation[2])]
    col, row, dz = frame("map_col_out"), frame("map_row_out"), frame("exact_dz")
    cos_phase = None
    if phase_sun_world is not None:   # as view_cosines: cos phase = -(R^T s) . r
        phase_form = -(rotation.T @ np.asarray(phase_sun_world, dtype=float))[None, :]
        cos_phase = scratch("cos_phase", (height, width))
    strip_col = scratch("exact_strip_col_num", (EXACT_STRIP_ROWS, width))
    strip_row = scratch("exact_strip_row_num", (EXACT_STRIP_ROWS, width))
    dz_max = -np.inf
    for row_start in range(0, height, EXACT_STRIP_ROWS):
        row_end = min(row_start + EXACT_STRIP_ROWS, height)
        rays = camera_rays[row_start:row_end]
        strip_dz = cv2.transform(rays, forms[2], dst=dz[row_start:row_end])
        cv2.divide(cv2.transform(rays, forms[0], dst=strip_col[:row_end - row_start]), strip_dz,
                   dst=col[row_start:row_end])
        cv2.divide(cv2.transform(rays, forms[1], dst=strip_row[:row_end - row_start]), strip_dz,
                   dst=row[row_start:row_end])
        if cos_phase is not None:
            cv2.transform(rays, phase_form, dst=cos_phase[row_start:row_end])
        dz_max = max(dz_max, float(strip_dz.max()))
    return col, row, dz, cos_phase, dz_max


def _sky_and_clip(col: np.ndarray, row: np.ndarray, dz: np.ndarray, any_sky: bool, altitude: float) -> np.ndarray:
    """The sky mask; with sky in view, the map clipped to +-MAX_MAP_COORDINATE and set to its minimum on sky."""
    if not any_sky:
        return np.zeros(col.shape, dtype=bool)
    sky = dz >= -np.float32(HORIZON_EPSILON)
    if altitude <= 0:   # camera at or below the ground: nothing sensible to see, all sky
        sky[:] = True
    np.clip(col, -MAX_MAP_COORDINATE, MAX_MAP_COORDINATE, out=col)
    np.clip(row, -MAX_MAP_COORDINATE, MAX_MAP_COORDINATE, out=row)
    col[sky] = -MAX_MAP_COORDINATE
    row[sky] = -MAX_MAP_COORDINATE
    return sky


CACHED_RAY_SETS = 64            # distinct small pixel sets whose camera rays are kept per camera
CACHED_RAY_SET_MAX_PIXELS = 20_000


def view_directions(camera: Camera, pose: CameraPose, ground_map: GroundMap,
                    grid_step_px: int) -> np.ndarray:
    """Unit ground-to-camera directions (minus the pixel rays).

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    ground_map : GroundMap
        The pose's ground map (its rays, per pixel).
    grid_step_px : int
        Node spacing ``s`` (px), 0 for every pixel.

    Returns
    -------
    ndarray
        (H / s + 2, W / s + 2, 3) float64 on the node grid when ``s > 0``, else (H, W, 3) float32.
    """
    if grid_step_px > 0:
        nodes = node_rays(camera, grid_step_px) @ pose.camera_to_world.T
        return -nodes / np.linalg.norm(nodes, axis=-1, keepdims=True)
    rays = ground_map.rays()
    norm = np.sqrt(np.einsum("...i,...i->...", rays, rays))
    return -rays / norm[..., None]


def view_cosines(camera: Camera, pose: CameraPose, ground_map: GroundMap,
                 sun_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel cosines of the emission angle and of the phase angle.

    Emission: ground-to-camera direction against the vertical; phase: against the sun. On an exact map
    (``grid_step_px = 0``) the pixel rays are unit vectors, so ``cos e = -d_z`` and
    ``cos phase = -(R^T s) . r`` (one transform of the cached camera-frame rays); otherwise from
    :func:`view_directions`.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    ground_map : GroundMap
        The pose's ground map.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.

    Returns
    -------
    cos_emission, cos_phase : ndarray, shape (H, W), float32
        On an exact map this thread's :func:`~simulator.scratch.scratch` arrays ``cos_emission``,
        ``cos_phase`` (use them before the next call).
    """
    if ground_map.ray_dz is not None:
        cos_emission = np.negative(ground_map.ray_dz, out=scratch("cos_emission", ground_map.ray_dz.shape))
        return cos_emission, phase_cosines(ground_map, sun_world)
    view = view_directions(camera, pose, ground_map, 0)
    return np.ascontiguousarray(view[..., 2]), view @ np.asarray(sun_world, dtype=np.float32)


def phase_cosines(ground_map: GroundMap, sun_world: np.ndarray) -> np.ndarray:
    """Per-pixel cosines of the phase angle on an exact map: ``-(R^T s) . r`` of the cached camera-frame rays.

    Parameters
    ----------
    ground_map : GroundMap
        An exact map (``ray_dz`` set); the phase cosines computed with it are taken (once) when given.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun (the one the map's phase cosines were computed for, if any).

    Returns
    -------
    ndarray, shape (H, W), float32
        This thread's :func:`~simulator.scratch.scratch` array ``cos_phase`` (use it before the next call).
    """
    assert ground_map.ray_dz is not None, "phase_cosines needs an exact map"
    cos_phase = ground_map.cos_phase      # computed with the map (for this sun: radiance_at_pose's)
    ground_map.cos_phase = None           # the caller overwrites it
    if cos_phase is None:
        cos_phase = cv2.transform(ground_map.camera_rays,
                                  -(ground_map.camera_to_world.T @ np.asarray(sun_world, dtype=float))[None, :],
                                  dst=scratch("cos_phase", ground_map.ray_dz.shape))
    return cos_phase


def field_at_pixels(values: np.ndarray, camera: Camera, grid_step_px: int,
                    scratch_name: str | None = None) -> np.ndarray:
    """A field computed in :func:`view_directions`' layout, at every pixel.

    Parameters
    ----------
    values : ndarray
        Values on the node grid (``grid_step_px > 0``) or per pixel (H, W).
    camera : Camera
        The camera.
    grid_step_px : int
        Node spacing (px), 0 for per-pixel values.
    scratch_name : str, optional
        Upsample into that :func:`~simulator.scratch.scratch` array.

    Returns
    -------
    ndarray, shape (H, W), float32
        The field at every pixel.
    """
    if grid_step_px > 0:
        return upsample_nodes(values, grid_step_px, camera.height_px, camera.width_px, scratch_name=scratch_name)
    return np.asarray(values, dtype=np.float32)


def camera_frame_rays(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Camera-frame unit rays of pixels.

    Rays do not depend on the pose, so the rays of small pixel sets used at every pose (motion-blur
    sample grid, footprint border, flow nodes) are cached per camera, keyed by the exact coordinates.

    Parameters
    ----------
    camera : Camera
        The camera.
    pixels : ndarray, shape (..., 2)
        (column, row) coordinates (px).

    Returns
    -------
    ndarray, shape (..., 3), float64
        Unit rays (read-only when cached).
    """
    pixels = np.asarray(pixels, dtype=float)
    if pixels.size > 2 * CACHED_RAY_SET_MAX_PIXELS:
        return cahvor.unproject(camera.model, pixels)
    cache = camera_cache(camera).setdefault("frame_rays", {})
    key = (pixels.shape, pixels.tobytes())
    rays = cache.get(key)
    if rays is None:
        rays = cahvor.unproject(camera.model, pixels)
        rays.setflags(write=False)
        if len(cache) < CACHED_RAY_SETS:
            cache[key] = rays
    return rays


def ground_points(camera: Camera, pose: CameraPose, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact world ground points (z = 0) seen by given pixels.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    pixels : ndarray, shape (..., 2)
        (column, row) coordinates (px).

    Returns
    -------
    points_m : ndarray, shape (..., 3)
        World points (m), 0 where the ray sees the sky.
    hit : ndarray, shape (...), bool
        False for sky.
    """
    rays = camera_frame_rays(camera, pixels) @ pose.camera_to_world.T
    hit = (rays[..., 2] < -HORIZON_EPSILON) & (pose.ray_origin_m[2] > 0)
    t = np.where(hit, -pose.ray_origin_m[2] / np.where(hit, rays[..., 2], -1.0), 0.0)
    points = pose.ray_origin_m + t[..., None] * rays
    points[..., 2] = 0.0
    return np.where(hit[..., None], points, 0.0), hit


def world_to_pixels(camera: Camera, pose: CameraPose, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into the image.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    points_m : ndarray, shape (..., 3)
        World points (m).

    Returns
    -------
    pixels : ndarray, shape (..., 2)
        (column, row) coordinates (px).
    in_front : ndarray, shape (...), bool
        True for points in front of the camera.
    """
    in_camera = (np.asarray(points_m, dtype=float) - pose.frame_origin_m) @ pose.camera_to_world
    return cahvor.project(camera.model, in_camera)


def pixel_window(pixels: np.ndarray, width_px: int, height_px: int) -> tuple[int, int, int, int]:
    """Rows and columns of the frame that hold projected points, with a 2-pixel margin, clipped to the frame.

    The margin covers the bilinear footprint and rounding.

    Parameters
    ----------
    pixels : ndarray, shape (N, 2)
        (column, row) coordinates (px).
    width_px, height_px : int
        Frame size (px).

    Returns
    -------
    tuple of int
        ``(row0, row1, col0, col1)``; empty when ``row1 <= row0`` or ``col1 <= col0``.
    """
    return _window_of_extent(float(pixels[:, 0].min()), float(pixels[:, 0].max()), float(pixels[:, 1].min()),
                             float(pixels[:, 1].max()), width_px, height_px)


def _window_of_extent(col_min: float, col_max: float, row_min: float, row_max: float, width_px: int,
                      height_px: int) -> tuple[int, int, int, int]:
    """:func:`pixel_window` of points whose coordinates span these bounds (px)."""
    col0 = max(math.floor(col_min) - 2, 0)
    col1 = min(math.ceil(col_max) + 3, width_px)
    row0 = max(math.floor(row_min) - 2, 0)
    row1 = min(math.ceil(row_max) + 3, height_px)
    return row0, row1, col0, col1


def outline_extent(pixels: np.ndarray, in_front: np.ndarray) -> tuple[float, float, float, float, bool, bool]:
    """A projected outline reduced to what :func:`outline_window` needs, once for several shifted cameras.

    Parameters
    ----------
    pixels : ndarray, shape (N, 2)
        (column, row) of the outline points (px).
    in_front : ndarray, shape (N,), bool
        Points in front of the camera.

    Returns
    -------
    tuple
        ``(col_min, col_max, row_min, row_max, any in front, all in front)``.
    """
    return (float(pixels[:, 0].min()), float(pixels[:, 0].max()), float(pixels[:, 1].min()),
            float(pixels[:, 1].max()), bool(in_front.any()), bool(in_front.all()))


def outline_window(extent: tuple[float, float, float, float, bool, bool], column_offset_px: float,
                   row_offset_px: float, width_px: int, height_px: int) -> tuple[int, int, int, int] | None:
    """The frame window of a projected outline, seen by a camera shifted by a sub-pixel offset.

    A camera whose pixel (c, r) sees what the outline's camera sees at (c + dc, r + dr)
    (:func:`simulator.scene.radiance.subpixel_camera`) sees each outline point at its pixel minus
    ``(dc, dr)``; rounding is monotone, so the shifted points' bounds are the bounds shifted, bit for bit.

    Parameters
    ----------
    extent : tuple
        :func:`outline_extent` of the outline.
    column_offset_px, row_offset_px : float
        The offset ``(dc, dr)`` (px); 0, 0 for the outline's own camera.
    width_px, height_px : int
        Frame size (px).

    Returns
    -------
    tuple of int or None
        ``(row0, row1, col0, col1)``: :func:`pixel_window` of the shifted points; the whole frame when the
        outline straddles the image plane (some points behind the camera); None when every point is
        behind the camera or the window is empty.
    """
    col_min, col_max, row_min, row_max, any_in_front, all_in_front = extent
    if not any_in_front:
        return None
    if not all_in_front:
        return 0, height_px, 0, width_px
    row0, row1, col0, col1 = _window_of_extent(col_min - column_offset_px, col_max - column_offset_px,
                                               row_min - row_offset_px, row_max - row_offset_px, width_px, height_px)
    if col1 <= col0 or row1 <= row0:
        return None
    return row0, row1, col0, col1


def border_pixels(camera: Camera, per_side: int = 16) -> np.ndarray:
    """Pixel coordinates around the image border (outer pixel edges), in closed polygon order.

    Parameters
    ----------
    camera : Camera
        The camera.
    per_side : int, optional
        Points per side.

    Returns
    -------
    ndarray, shape (4 * per_side, 2)
        (column, row) coordinates (px).
    """
    w, h = camera.width_px - 0.5, camera.height_px - 0.5
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    top = np.stack([-0.5 + t * (w + 0.5), np.full_like(t, -0.5)], axis=-1)
    right = np.stack([np.full_like(t, w), -0.5 + t * (h + 0.5)], axis=-1)
    bottom = np.stack([w - t * (w + 0.5), np.full_like(t, h)], axis=-1)
    left = np.stack([np.full_like(t, -0.5), h - t * (h + 0.5)], axis=-1)
    return np.concatenate([top, right, bottom, left])


def footprint_m(camera: Camera, pose: CameraPose, per_side: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Ground footprint polygon of the image border.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    per_side : int, optional
        Points per side of the border.

    Returns
    -------
    points : ndarray, shape (n, 2)
        East, north of each border point on the ground (m).
    hit : ndarray, shape (n,), bool
        False where the border ray sees the sky.
    """
    cache = camera_cache(camera)
    key = ("border_pixels", per_side)
    if key not in cache:           # the same pixels every call (and so the same cached camera-frame rays)
        cache[key] = border_pixels(camera, per_side)
        cache[key].setflags(write=False)
    points, hit = ground_points(camera, pose, cache[key])
    return points[:, :2], hit
