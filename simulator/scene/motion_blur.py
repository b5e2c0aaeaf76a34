"""Motion blur: how each CCD period's motion is integrated, and how many sub-poses it needs.

Paper 3.2: radiance fields are generated along the descent profile during the fast flush, exposure and
frame transfer "in steps corresponding to one MOC pixel of image shift" and averaged (typically 2-4).

The shift of a period is measured on a 9 x 9 grid of sample pixels: each pixel's ground point at the
period start is followed to the period end, both on the ground (in terrain pixels) and in the image (in
camera pixels, by projecting the start ground point with the end pose). A pixel's shift counts in the
coarser of the two units, ``min(ground / terrain_mpp, image_px)``: when a camera pixel covers several
terrain pixels (far field) one step per camera pixel already samples the blur. The count is
``max(1, ceil(max shift))`` capped at ``max_substeps``; a still camera costs one field. Sub-poses sit
at the midpoints of equal sub-intervals of the period.

The method is chosen here, in one place (:func:`choose_blur`), from the motion and the fidelity switches:

* ``"still"``: the whole window moves the image by less than ``still_shift_terrain_px`` (switch
  ``share_still_fields``), or neither motion blur nor smear is wanted: the field at the exposure
  mid-time stands for all three periods;
* ``"warp"``: warp-and-accumulate of one rendered field (:mod:`simulator.scene.blur_warp`, switch
  ``warp_motion_blur``) when the exposure needs at least :data:`MIN_EXPOSURE_SUBSTEPS` sub-poses;
  the warp checks its own validity and, when the scene does not allow it, the periods fall back to
  ``"sub_poses"``;
* ``"sub_poses"``: each period is the mean of the fields rendered at its sub-poses; with
  ``warp_smear_fields`` the flush and transfer sub-poses are warped from the exposure-centre field
  instead (:mod:`simulator.scene.smear_warp`).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from flight_interface import cahvor
from flight_interface.camera import Camera
from simulator.scene import ground_mapping


def sample_pixels(camera: Camera, per_axis: int = 9) -> np.ndarray:
    """A grid of pixel coordinates spanning the frame.

    Parameters
    ----------
    camera : Camera
        The camera.
    per_axis : int, optional
        Points per axis.

    Returns
    -------
    ndarray, shape (per_axis**2, 2)
        (column, row) coordinates (px).
    """
    cols = np.linspace(0.0, camera.width_px - 1.0, per_axis)
    rows = np.linspace(0.0, camera.height_px - 1.0, per_axis)
    return np.stack(np.meshgrid(cols, rows), axis=-1).reshape(-1, 2)


def _cached_sample_pixels(camera: Camera) -> np.ndarray:
    """:func:`sample_pixels` of the camera (default grid), computed once per camera (read-only)."""
    cache = ground_mapping.camera_cache(camera)
    pixels = cache.get("motion_blur_sample_pixels")
    if pixels is None:
        pixels = cache["motion_blur_sample_pixels"] = sample_pixels(camera)
        pixels.setflags(write=False)
    return pixels


def image_shift(camera: Camera, start: ground_mapping.CameraPose, end: ground_mapping.CameraPose,
                terrain_mpp: float, pixels: np.ndarray | None = None, ground: dict | None = None) -> float:
    """Largest shift of the sample pixels between two camera poses, in terrain pixels (see module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    start, end : CameraPose
        The two world poses.
    terrain_mpp : float
        Terrain pixel size (m).
    pixels : ndarray, shape (n, 2), optional
        Sample pixels (default :func:`sample_pixels`).
    ground : dict, optional
        Memo of the sample pixels' ground points per pose (``id(pose) -> (pose, points, hit)``), shared
        by the calls of one image (the window ends recur).

    Returns
    -------
    float
        Shift (terrain pixels); 0 when no sample sees the ground at both poses.
    """
    return image_shifts(camera, [(start, end)], terrain_mpp, pixels, ground)[0]


def image_shifts(camera: Camera, pairs: list[tuple[ground_mapping.CameraPose, ground_mapping.CameraPose]],
                 terrain_mpp: float, pixels: np.ndarray | None = None, ground: dict | None = None) -> list[float]:
    """:func:`image_shift` of several ``(start, end)`` pose pairs at once.

    Each pose's ground points are computed once, and the start ground points of every pair are
    projected with their end poses in one CAHVOR projection (a point's pixel does not depend on the
    other points projected with it), so a window and its three periods cost one projection, not four.

    Parameters
    ----------
    camera : Camera
        The camera.
    pairs : list of (CameraPose, CameraPose)
        ``(start, end)`` world poses.
    terrain_mpp : float
        Terrain pixel size (m).
    pixels : ndarray, shape (n, 2), optional
        Sample pixels (default :func:`sample_pixels`).
    ground : dict, optional
        Memo of the sample pixels' ground points per pose (``id(pose) -> (pose, points, hit)``; each
        pose object is kept alive in it, so its id is not reused).

    Returns
    -------
    list of float
        Per pair, the shift (terrain pixels); 0 when no sample sees the ground at both poses.
    """
    pixels = sample_pixels(camera) if pixels is None else pixels
    ground = {} if ground is None else ground
    for pair in pairs:
        for pose in pair:
            if id(pose) not in ground:
                ground[id(pose)] = (pose, *ground_mapping.ground_points(camera, pose, pixels))
    ground_start = np.stack([ground[id(start)][1] for start, _ in pairs])      # (pairs, n, 3)
    ground_end = np.stack([ground[id(end)][1] for _, end in pairs])
    hit = np.stack([ground[id(start)][2] & ground[id(end)][2] for start, end in pairs])
    # ground_mapping.world_to_pixels of each pair's start points with its end pose, one projection for all
    in_camera = np.stack([(ground_start[index] - end.frame_origin_m) @ end.camera_to_world
                          for index, (_, end) in enumerate(pairs)])
    reprojected, in_front = cahvor.project(camera.model, in_camera)
    ground_shift = np.linalg.norm(ground_end - ground_start, axis=-1) / terrain_mpp
    image_shift_px = np.where(in_front, np.linalg.norm(reprojected - pixels, axis=-1), np.inf)
    shift = np.where(hit, np.minimum(ground_shift, image_shift_px), -np.inf).max(axis=-1)
    seen = np.asarray(hit.any(axis=-1))
    return [float(shift[index]) if seen[index] else 0.0 for index in range(len(pairs))]


def substep_count(shift_terrain_px: float, max_substeps: int) -> int:
    """One sub-pose per terrain pixel of shift, at least 1, at most ``max_substeps``.

    Parameters
    ----------
    shift_terrain_px : float
        Shift over the period (terrain pixels, times the configured sub-poses per pixel).
    max_substeps : int
        Cap.

    Returns
    -------
    int
        Number of sub-poses.
    """
    return int(min(max(1, int(np.ceil(shift_terrain_px - 1e-9))), max_substeps))


def substep_times(start_s: float, end_s: float, count: int) -> np.ndarray:
    """Midpoints of equal sub-intervals of a period.

    Parameters
    ----------
    start_s, end_s : float
        The period (s).
    count : int
        Number of sub-intervals.

    Returns
    -------
    ndarray, shape (count,)
        Times (s).
    """
    return start_s + (np.arange(count) + 0.5) * (end_s - start_s) / count


def average_fields(fields: list[np.ndarray]) -> np.ndarray:
    """Pixel-by-pixel mean of radiance fields.

    Parameters
    ----------
    fields : list of ndarray, shape (H, W), float32
        Fields (W m^-2 sr^-1 um^-1), summed in order.

    Returns
    -------
    ndarray, shape (H, W), float32
        The mean; the single field itself when only one.
    """
    if len(fields) == 1:
        return fields[0]
    total = fields[0].copy()
    for field in fields[1:]:
        total += field
    total *= np.float32(1.0 / len(fields))
    return total


MIN_EXPOSURE_SUBSTEPS = 4      # fewer exposure sub-poses: rendered exactly (cheap enough, and bits unchanged)

BlurMethod = Literal["still", "warp", "sub_poses"]


@dataclass(frozen=True)
class BlurChoice:
    """How the motion of one image's three CCD periods is integrated (module doc).

    Parameters
    ----------
    method : {"still", "warp", "sub_poses"}
        One shared field, warp-and-accumulate, or the mean of rendered sub-poses.
    substeps : dict of str to int
        Sub-poses per period (``"flush"``, ``"exposure"``, ``"transfer"``); 0 when the period's
        field is shared or unused.
    warp_smear_fields : bool
        With ``"sub_poses"``: the flush and transfer sub-poses are warped from the exposure-centre field.
    """

    method: BlurMethod
    substeps: dict[str, int]
    warp_smear_fields: bool


def choose_blur(camera: Camera, cam_at: Callable[[float], ground_mapping.CameraPose],
                windows: dict[str, tuple[float, float]], terrain_mpp: float, config,
                need_smear_fields: bool) -> BlurChoice:
    """Choose how the three CCD periods of one image integrate the motion, and their sub-pose counts.

    Parameters
    ----------
    camera : Camera
        The descent camera.
    cam_at : callable
        ``time_s -> CameraPose``: the camera's world pose at a time (s).
    windows : dict of str to (float, float)
        ``period -> (start_s, end_s)`` of the fast flush, exposure and frame transfer (s).
    terrain_mpp : float
        Terrain pixel size (m), the unit of the image shift.
    config : simulator.scene_config.SceneConfig
        Effect switches (``motion_blur``, ``share_still_fields``, ``warp_motion_blur``,
        ``warp_smear_fields``), ``still_shift_terrain_px``, ``substeps_per_terrain_px``, ``max_substeps``.
    need_smear_fields : bool
        False when the camera's smear is off: only the exposure field is needed.

    Returns
    -------
    BlurChoice
        The method and the sub-poses per period.
    """
    effects = config.effects
    first = windows["flush"][0] if need_smear_fields else windows["exposure"][0]
    last = windows["transfer"][1] if need_smear_fields else windows["exposure"][1]
    measured = [period for period in windows if effects.motion_blur and (period == "exposure" or need_smear_fields)]
    # the whole window's shift and the periods' in one projection (a still image wastes two ground-point sets)
    shifts = image_shifts(camera, [(cam_at(first), cam_at(last))]
                          + [(cam_at(windows[period][0]), cam_at(windows[period][1])) for period in measured],
                          terrain_mpp, _cached_sample_pixels(camera))
    still = effects.share_still_fields and shifts[0] < config.still_shift_terrain_px
    if still or not effects.motion_blur and not need_smear_fields:
        return BlurChoice("still", {"flush": 0, "exposure": 1, "transfer": 0}, False)
    counts = {}
    for period in windows:
        if period != "exposure" and not need_smear_fields:
            counts[period] = 0
        elif effects.motion_blur:
            shift = shifts[1 + measured.index(period)]
            counts[period] = substep_count(shift * config.substeps_per_terrain_px, config.max_substeps)
        else:
            counts[period] = 1
    warp = (effects.warp_motion_blur and effects.motion_blur and need_smear_fields
            and counts["exposure"] >= MIN_EXPOSURE_SUBSTEPS)
    return BlurChoice("warp" if warp else "sub_poses", counts, bool(effects.warp_smear_fields))
