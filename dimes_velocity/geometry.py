"""Geometry: camera poses from the measurements, and rectification of binned images to a level ground plane.

Every image of a pair is rectified at one common ground sampling.

Frames follow :mod:`flight_interface.frames` (world x east, y north, z up, ground z = 0). The lander's
horizontal position at image k is the IMU prediction ``P_k`` relative to image 0 (``P_0 = 0``): the
IMU-propagated positions when given, else the trapezoidal integration of the measured, biased IMU
velocity; its height is the radar altitude. The
camera frame maps to the world by ``R(attitude) @ R(camera_to_lander)``, and the camera centre is
``lander + R(attitude) @ camera_position_in_lander_m``.

A rectified image is an ``N x N`` north-up grid on the ground: pixel ``(u, v)`` (column, row) is
the ground point ``(east, north) = origin + s * (u, -v)``. Binned pixel ``(c, r)`` of the
``b``-binned image covers full-frame pixels ``b c .. b c + b - 1`` (centre ``b c + (b - 1)/2``),
so full-frame coordinates map to binned ones by ``(x - (b - 1)/2) / b``.

The ground -> image map is not a homography (CAHVOR radial distortion), so it is evaluated exactly
on a ``(K + 2) x (K + 2)`` grid of knots and interpolated in between by Catmull-Rom cubic convolution
(separable, four knots per axis; 17 knots on 256 pixels: < 0.01 pixel);
``cv2.remap`` then resamples bilinearly. Points behind the camera spoil only the cells next to them,
which are marked not visible. The exclusion cones (zero-phase zone, heat shield) are tested on the
interpolated cosine of the ray's angle to the cone axis, evaluated only over the knot cells where it
can exceed the cone's cosine: a Catmull-Rom value is at most ``max + 0.28125 (max - min)`` of its
cell's 4 x 4 knots, so every other cell is outside the cone (the same mask as interpolating the whole grid).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from dimes_velocity import compiled
from flight_interface import cahvor
from flight_interface.camera import Camera
from flight_interface.frames import quat_to_matrix
from flight_interface.measurements import DescentMeasurements


def predicted_positions_m(measurements: DescentMeasurements) -> np.ndarray:
    """IMU-predicted horizontal lander positions relative to image 0.

    From the IMU positions when every image has one, else by trapezoidal integration of the IMU
    velocities.

    Parameters
    ----------
    measurements : DescentMeasurements
        The K images' measurements.

    Returns
    -------
    ndarray, shape (K, 2)
        East and north positions (m); row 0 is zero.
    """
    images = measurements.images
    if all(image.imu_position_m is not None for image in images):
        positions = np.array([np.asarray(image.imu_position_m, dtype=float)[:2] for image in images])
        return positions - positions[0]
    # in Python floats, the same operations in the same order as the array form
    # ``cumsum(0.5 * (v[1:] + v[:-1]) * diff(t))`` (a running sum from the first step)
    times = [float(image.time_s) for image in images]
    velocities = [np.asarray(image.imu_velocity_mps, dtype=float)[:2].tolist() for image in images]
    east = north = 0.0
    positions_list = [[0.0, 0.0]]
    for k in range(len(images) - 1):
        dt = times[k + 1] - times[k]
        step_east = 0.5 * (velocities[k + 1][0] + velocities[k][0]) * dt
        step_north = 0.5 * (velocities[k + 1][1] + velocities[k][1]) * dt
        east, north = (step_east, step_north) if k == 0 else (east + step_east, north + step_north)
        positions_list.append([east, north])
    return np.array(positions_list)


@dataclass(frozen=True)
class CameraPose:
    """One image's camera as the estimator believes it is (from the measurements).

    Attributes
    ----------
    model : Cahvor
        The camera model in the world frame.
    centre_m : ndarray (3,)
        Camera centre (world, m); ``centre_m[2]`` is the camera height above the ground.
    boresight : ndarray (3,)
        Unit pointing axis in the world frame.
    off_nadir_rad : float
        Angle between the boresight and straight down.
    """

    model: cahvor.Cahvor
    centre_m: np.ndarray
    boresight: np.ndarray
    off_nadir_rad: float


_CAMERA_TO_LANDER: dict[int, tuple[Camera, np.ndarray]] = {}


def _camera_to_lander(camera: Camera) -> np.ndarray:
    """``camera.camera_to_lander_matrix``, computed once per camera (a camera is immutable)."""
    cached = _CAMERA_TO_LANDER.get(id(camera))
    if cached is not None and cached[0] is camera:
        return cached[1]
    matrix = camera.camera_to_lander_matrix
    matrix.setflags(write=False)
    if len(_CAMERA_TO_LANDER) > 16:
        _CAMERA_TO_LANDER.clear()
    _CAMERA_TO_LANDER[id(camera)] = (camera, matrix)
    return matrix


def camera_pose(camera: Camera, attitude_quat: np.ndarray, altitude_m: float,
                horizontal_position_m: np.ndarray) -> CameraPose:
    """World-frame camera model for a lander at ``horizontal_position_m`` and ``altitude_m``.

    Parameters
    ----------
    camera : Camera
        The camera (model in the camera frame, mounting on the lander).
    attitude_quat : ndarray, shape (4,)
        Lander body-to-world unit quaternion (w, x, y, z).
    altitude_m : float
        Lander height above the ground (m).
    horizontal_position_m : ndarray, shape (2,)
        Lander east and north position (m).

    Returns
    -------
    CameraPose
        The camera model, centre, boresight and off-nadir angle in the world frame.
    """
    body_to_world = quat_to_matrix(attitude_quat)
    camera_to_world = body_to_world @ _camera_to_lander(camera)
    lander = np.array([horizontal_position_m[0], horizontal_position_m[1], altitude_m], dtype=float)
    origin = lander + body_to_world @ camera.camera_position_in_lander_m
    model = camera.model.transformed(camera_to_world, origin)
    boresight = model.a / np.linalg.norm(model.a)
    return CameraPose(model=model, centre_m=model.c.copy(), boresight=boresight,
                      off_nadir_rad=float(np.arccos(min(max(-float(boresight[2]), -1.0), 1.0))))


def binned_focal_px(camera: Camera) -> float:
    """Focal length in binned pixels.

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    float
        Geometric mean of the CAHVOR hs and vs over the row binning (binned px).
    """
    return float(np.sqrt(camera.model.hs * camera.model.vs)) / camera.binning_rows


@lru_cache(maxsize=8)
def knot_operator(size: int, knots: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Catmull-Rom interpolation from knots to every integer position of ``0 .. size - 1``.

    The knots are ``linspace(0, size - 1, knots)`` plus one more spacing beyond each end. Position
    ``p`` in interval ``j`` (between inner knots ``j`` and ``j + 1``) is
    ``sum_k weights[p, k] * value[first[p] + k]`` over extended knots ``j .. j + 3`` (``first = j``),
    so an unusable knot spoils only the cells around it.

    Parameters
    ----------
    size : int
        Number of integer positions (px).
    knots : int
        Number of inner knots, >= 2.

    Returns
    -------
    positions : ndarray, shape (knots + 2,)
        Knot positions (px), the extended ones included.
    first : ndarray of int, shape (size,)
        First extended knot of each position's interval.
    weights : ndarray, shape (size, 4)
        Catmull-Rom weights of the four extended knots.
    """
    spacing = (size - 1.0) / (knots - 1)
    positions = np.concatenate([[-spacing], np.linspace(0.0, size - 1.0, knots), [size - 1.0 + spacing]])
    pixel = np.arange(size, dtype=float)
    cell = cell_of_pixel(size, knots)
    t = pixel / spacing - cell
    weights = np.stack([((-0.5 * t + 1.0) * t - 0.5) * t, (1.5 * t - 2.5) * t * t + 1.0,
                        ((-1.5 * t + 2.0) * t + 0.5) * t, (0.5 * t - 0.5) * t * t], axis=1)
    return positions, cell, weights


def cell_of_pixel(size: int, knots: int) -> np.ndarray:
    """Interval index of every integer position (see :func:`knot_operator`).

    Parameters
    ----------
    size : int
        Number of integer positions (px).
    knots : int
        Number of inner knots, >= 2.

    Returns
    -------
    ndarray of int, shape (size,)
        Interval of each position, 0 .. knots - 2.
    """
    spacing = (size - 1.0) / (knots - 1)
    return np.minimum(np.floor(np.arange(size) / spacing).astype(int), knots - 2)


@dataclass(frozen=True)
class Rectification:
    """Map from a rectified ground grid into one binned image.

    Attributes
    ----------
    origin_m : ndarray (2,)
        Ground (east, north) of rectified pixel (0, 0), m.
    sample_m : float
        Ground sampling (m per rectified pixel).
    map_x, map_y : ndarray float32 (N, N)
        Binned-image column and row of each rectified pixel.
    visible : ndarray uint8 (N, N)
        1 where the ground point is in front of the camera and inside the image.
    excluded_zone : ndarray uint8 (N, N)
        1 inside the zero-phase zone or the heat shield cone.
    """

    origin_m: np.ndarray
    sample_m: float
    map_x: np.ndarray
    map_y: np.ndarray
    visible: np.ndarray
    excluded_zone: np.ndarray

    def ground_of(self, column: float, row: float) -> np.ndarray:
        """Ground point of a rectified pixel position.

        Parameters
        ----------
        column, row : float
            Rectified pixel position (px).

        Returns
        -------
        ndarray, shape (2,)
            Ground east and north (m).
        """
        return self.origin_m + self.sample_m * np.array([column, -row])

    def pixel_of(self, ground_m: np.ndarray) -> np.ndarray:
        """Rectified pixel position of a ground point.

        Parameters
        ----------
        ground_m : ndarray, shape (2,)
            Ground east and north (m).

        Returns
        -------
        ndarray, shape (2,)
            Rectified (column, row) (px).
        """
        offset = (np.asarray(ground_m, dtype=float) - self.origin_m) / self.sample_m
        return np.array([offset[0], -offset[1]])


@lru_cache(maxsize=8)
def _segments(size: int, knots: int) -> tuple[tuple[int, int, int, np.ndarray, np.ndarray], ...]:
    """The knot intervals of :func:`knot_operator`.

    Returned as ``(lo, hi, first knot, weights (hi - lo, 4), weights.T (4, hi - lo))``, contiguous (per
    rectified size and knot count, cached).
    """
    _, first, weights = knot_operator(size, knots)
    starts = np.flatnonzero(np.diff(first, prepend=-1))
    ends = np.append(starts[1:], size)
    segments = tuple((int(lo), int(hi), int(first[lo]), np.ascontiguousarray(weights[lo:hi]),
                      np.ascontiguousarray(weights[lo:hi].T)) for lo, hi in zip(starts, ends))
    for segment in segments:
        segment[3].setflags(write=False)
        segment[4].setflags(write=False)
    return segments


_UPSAMPLE_CHUNK_LINES = 512     # lines per column-pass chunk of _upsample: 1 MiB of float64 products at 256 columns


def _upsample(size: int, knots: int, knot_values: np.ndarray,
              cells: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Knot values (K+2, K+2, C) -> (C, size, size) float32 by separable Catmull-Rom (:func:`knot_operator`).

    One small matrix product per knot interval and axis (4 knots each), written straight into the
    output (``out=``): O(size^2) work, and no large BLAS call (a single big product may start BLAS
    threads that stall for ~20 ms on a busy machine). Both passes are 2-D products on contiguous
    arrays: the row pass over all channels at once, the column pass over all channels' rows in chunks of
    ``_UPSAMPLE_CHUNK_LINES`` lines, each converted to float32 while its float64 products are still in the cache
    (one (C size, size) float64 product array is 3 MiB for six channels, beyond a core's 1 MiB L2; the same
    products per pixel, so the same values).

    ``cells = (first row cell, end row cell, first column cell, end column cell)`` computes only the
    pixels of those knot intervals (the same products, fewer of them): (C, rows, columns) of that block.
    """
    values = np.asarray(knot_values, dtype=np.float64)
    extended, channels = values.shape[0], values.shape[2]
    segments = _segments(size, knots)
    row_segments = column_segments = segments
    if cells is not None:
        row_segments = tuple(seg for seg in segments if cells[0] <= seg[2] < cells[1])
        column_segments = tuple(seg for seg in segments if cells[2] <= seg[2] < cells[3])
        if not row_segments or not column_segments:
            return np.empty((channels, 0, 0), np.float32)
    row_lo, row_count = row_segments[0][0], row_segments[-1][1] - row_segments[0][0]
    column_lo, column_count = column_segments[0][0], column_segments[-1][1] - column_segments[0][0]
    flat = values.reshape(extended, extended * channels)
    rows = np.empty((row_count, extended * channels))
    for lo, hi, first, weights, _ in row_segments:
        np.matmul(weights, flat[first: first + 4], out=rows[lo - row_lo: hi - row_lo])
    rows = np.ascontiguousarray(rows.reshape(row_count, extended, channels).transpose(2, 0, 1)).reshape(
        channels * row_count, extended)                                     # (C rows, K+2)
    lines = channels * row_count
    out = np.empty((lines, column_count), np.float32)
    chunk = min(lines, _UPSAMPLE_CHUNK_LINES)
    products = np.empty((chunk, column_count))
    for start in range(0, lines, chunk):                 # float64 products of a chunk of lines, then float32
        block = rows[start: start + chunk]
        part = products[: len(block)]
        for lo, hi, first, _, weights_t in column_segments:
            np.matmul(block[:, first: first + 4], weights_t, out=part[:, lo - column_lo: hi - column_lo])
        out[start: start + len(block)] = part
    return out.reshape(channels, row_count, column_count)


# Catmull-Rom weights of a cell sum to 1 with at most 0.28125 negative (1-D: -t (1 - t) / 2 <= 1/8 for each
# axis; 2-D: (1 + 1/8) / 8 twice): an interpolated value is at most max + 0.28125 (max - min) of the cell's
# 4 x 4 knots.
_CATMULL_ROM_OVERSHOOT = 0.28125
_CONE_TEST_MARGIN = 1e-6       # covers float64 rounding and the float32 map values


def _cone_cells(cosines: np.ndarray, threshold: float) -> tuple[int, int, int, int] | None:
    """The block of knot cells (first row, end row, first column, end column).

    Outside the block no interpolated cosine can exceed ``threshold`` (None: nowhere).
    """
    # every cell's largest and smallest of its 4 x 4 knots, tested in one compiled pass
    found, first_row, end_row, first_column, end_column = compiled.cone_cells(
        np.ascontiguousarray(cosines, dtype=np.float64), threshold - _CONE_TEST_MARGIN, _CATMULL_ROM_OVERSHOOT)
    return (int(first_row), int(end_row), int(first_column), int(end_column)) if found else None


_FIELD_RADIUS: dict[int, tuple[Camera, float]] = {}
_TWO_DEGREES_RAD = float(np.radians(2.0))


def field_radius_rad(camera: Camera) -> float:
    """Largest angle between the boresight and the rays of the frame's corners (cached per camera).

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    float
        The angle (rad).
    """
    cached = _FIELD_RADIUS.get(id(camera))
    if cached is not None and cached[0] is camera:
        return cached[1]
    corners = np.array([[0.0, 0.0], [camera.width_px - 1.0, 0.0], [0.0, camera.height_px - 1.0],
                        [camera.width_px - 1.0, camera.height_px - 1.0]])
    rays = cahvor.unproject(camera.model, corners)
    axis = camera.model.a / np.linalg.norm(camera.model.a)
    radius = float(np.arccos(np.clip(rays @ axis, -1.0, 1.0)).max())
    if len(_FIELD_RADIUS) > 16:
        _FIELD_RADIUS.clear()
    _FIELD_RADIUS[id(camera)] = (camera, radius)
    return radius


def ground_centre_m(pose: CameraPose, max_off_nadir_rad: float) -> np.ndarray:
    """Where the rectified grid is centred: the boresight's ground point (tilt capped).

    Parameters
    ----------
    pose : CameraPose
        The image's camera.
    max_off_nadir_rad : float
        Largest tilt used (rad).

    Returns
    -------
    ndarray, shape (2,)
        Ground east and north (m).
    """
    horizontal = pose.boresight[:2]
    norm = float(np.linalg.norm(horizontal))
    tilt = min(pose.off_nadir_rad, max_off_nadir_rad)
    if norm < 1e-12:
        return pose.centre_m[:2].copy()
    return pose.centre_m[:2] + pose.centre_m[2] * np.tan(tilt) * horizontal / norm


def rectify_map(pose: CameraPose, camera: Camera, size: int, sample_m: float, centre_m: np.ndarray,
                knots: int, anti_sun: np.ndarray | None, zero_phase_half_angle_rad: float,
                heat_shield_m: np.ndarray | None = None, heat_shield_half_angle_rad: float = 0.0) -> Rectification:
    """Rectification of one image onto a ``size x size`` ground grid centred at ``centre_m``.

    Parameters
    ----------
    pose : CameraPose
        The image's camera in the world frame.
    camera : Camera
        The camera (binning, frame size, field radius).
    size : int
        Rectified grid size N (px).
    sample_m : float
        Ground sampling (m per rectified pixel).
    centre_m : ndarray, shape (2,)
        Ground east and north of the grid's centre (m).
    knots : int
        Knots per axis of the Catmull-Rom map (:func:`knot_operator`).
    anti_sun : ndarray (3,) or None
        Unit vector from the sun's direction reversed (-sun); the zero-phase zone is the set of rays
        within ``zero_phase_half_angle_rad`` of it (None: no zone).
    zero_phase_half_angle_rad : float
        Half angle of the zero-phase zone (rad).
    heat_shield_m : ndarray (3,) or None
        Predicted heat shield centre (world, m); rays within ``heat_shield_half_angle_rad`` of it
        are excluded.
    heat_shield_half_angle_rad : float, optional
        Half angle of the heat shield's cone (rad).

    Returns
    -------
    Rectification
        The map of the grid into the binned image, and where it is visible or excluded.
    """
    return rectify_maps([RectificationRequest(pose, centre_m, heat_shield_m, heat_shield_half_angle_rad)], camera,
                        size, sample_m, knots, anti_sun, zero_phase_half_angle_rad)[0]


@dataclass(frozen=True)
class RectificationRequest:
    """One image's part of :func:`rectify_maps`: its camera, grid centre and heat shield cone.

    Attributes
    ----------
    pose : CameraPose
        The image's camera in the world frame.
    centre_m : ndarray, shape (2,)
        Ground east and north of the grid's centre (m).
    heat_shield_m : ndarray (3,) or None
        Predicted heat shield centre (world, m); None: no heat shield cone.
    heat_shield_half_angle_rad : float
        Half angle of the heat shield's cone (rad).
    """

    pose: CameraPose
    centre_m: np.ndarray
    heat_shield_m: np.ndarray | None = None
    heat_shield_half_angle_rad: float = 0.0


def rectify_maps(requests: list[RectificationRequest], camera: Camera, size: int, sample_m: float, knots: int,
                 anti_sun: np.ndarray | None, zero_phase_half_angle_rad: float) -> list[Rectification]:
    """:func:`rectify_map` of several images at one ground sampling.

    The knot maps of all the images are interpolated in one :func:`_upsample` (the same products per pixel as
    one image at a time, in fewer calls).

    Parameters
    ----------
    requests : list of RectificationRequest
        Each image's camera, grid centre and heat shield cone.
    camera : Camera
        The camera (binning, frame size, field radius).
    size : int
        Rectified grid size N (px).
    sample_m : float
        Ground sampling (m per rectified pixel).
    knots : int
        Knots per axis of the Catmull-Rom map (:func:`knot_operator`).
    anti_sun : ndarray (3,) or None
        Unit vector from the sun's direction reversed (-sun); None: no zero-phase zone.
    zero_phase_half_angle_rad : float
        Half angle of the zero-phase zone (rad).

    Returns
    -------
    list of Rectification
        One per request, in order.
    """
    if not requests:
        return []
    b = camera.binning_rows
    n_cols, n_rows = camera.width_px // b, camera.height_px // b
    half = 0.5 * (size - 1)
    knot_px = knot_operator(size, knots)[0]
    extended = len(knot_px)
    reach = field_radius_rad(camera) + _TWO_DEGREES_RAD       # only cones that can meet the frame
    knot_maps = np.zeros((extended, extended, 2 * len(requests)))
    parts = []
    for index, request in enumerate(requests):
        pose = request.pose
        origin = np.asarray(request.centre_m, dtype=float) + sample_m * np.array([-half, half])
        # (K+2, K+2, 3): east varies along columns, north along rows, height 0 (the same values as broadcasting
        # ``origin + s (u, -v)`` over the grid)
        ground = np.empty((extended, extended, 3))
        ground[:, :, 0] = origin[0] + sample_m * knot_px
        ground[:, :, 1] = (origin[1] - sample_m * knot_px)[:, None]
        ground[:, :, 2] = 0.0
        pixels, in_front = cahvor.project(pose.model, ground)
        binned = (pixels - 0.5 * (b - 1)) / b
        usable = in_front & np.all(np.abs(binned) < 1e5, axis=-1)
        np.copyto(knot_maps[:, :, 2 * index: 2 * index + 2], binned, where=usable[:, :, None])   # 0 where not usable
        cones = []
        if anti_sun is not None and zero_phase_half_angle_rad > 0:
            cones.append((np.asarray(anti_sun, dtype=float), zero_phase_half_angle_rad))
        if request.heat_shield_m is not None and request.heat_shield_half_angle_rad > 0:
            shield = np.asarray(request.heat_shield_m, dtype=float) - pose.centre_m
            cones.append((shield / max(float(np.linalg.norm(shield)), 1e-9), request.heat_shield_half_angle_rad))
        boresight = pose.boresight
        cones = [(axis, cone_half) for axis, cone_half in cones
                 if np.arccos(min(max(axis @ boresight, -1.0), 1.0)) < reach + cone_half]
        parts.append((pose, origin, ground, usable, cones))
    maps = _upsample(size, knots, knot_maps)
    rectifications = []
    for index, (pose, origin, ground, usable, cones) in enumerate(parts):
        map_x, map_y = maps[2 * index], maps[2 * index + 1]
        rows_ok = usable[:-3] & usable[1:-2] & usable[2:-1] & usable[3:]
        cells = rows_ok[:, :-3] & rows_ok[:, 1:-2] & rows_ok[:, 2:-1] & rows_ok[:, 3:]     # (K-1, K-1)
        visible = compiled.inside_frame(map_x, map_y, np.float32(n_cols - 1), np.float32(n_rows - 1)).view(bool)
        if not cells.all():
            counts = np.bincount(cell_of_pixel(size, knots), minlength=knots - 1)
            visible &= np.repeat(np.repeat(cells, counts, axis=0), counts, axis=1)
        excluded = np.zeros((size, size), dtype=np.uint8)
        if cones:
            rays = ground - pose.centre_m
            rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
            segments = _segments(size, knots)
        for axis, cone_half in cones:
            # the cone's cosine is interpolated only over the knot cells where it may exceed cos(half angle)
            cosines = rays @ axis
            threshold = float(np.cos(cone_half))
            block = _cone_cells(cosines, threshold)
            if block is None:
                continue
            cosine = _upsample(size, knots, cosines[:, :, None], block)[0]
            rows = [seg for seg in segments if block[0] <= seg[2] < block[1]]
            columns = [seg for seg in segments if block[2] <= seg[2] < block[3]]
            if rows and columns:
                inside = excluded[rows[0][0]: rows[-1][1], columns[0][0]: columns[-1][1]].view(bool)
                inside |= cosine > threshold
        rectifications.append(Rectification(origin_m=origin, sample_m=float(sample_m), map_x=map_x, map_y=map_y,
                                            visible=visible.view(np.uint8), excluded_zone=excluded))
    return rectifications


def warp(image: np.ndarray, rectification: Rectification, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Resample a binned image onto the rectified grid.

    Parameters
    ----------
    image : ndarray, shape (rows, columns), float32 or uint8
        The binned image.
    rectification : Rectification
        The grid's map into the image.
    interpolation : int, optional
        OpenCV interpolation flag (``cv2.INTER_LINEAR``; ``cv2.INTER_NEAREST`` for masks).

    Returns
    -------
    ndarray, shape (N, N), the dtype of ``image``
        The resampled image, 0 outside the image.
    """
    return cv2.remap(image, rectification.map_x, rectification.map_y, interpolation,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
