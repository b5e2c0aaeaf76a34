"""Motion blur: how many sub-poses each CCD period needs, decided from the actual image motion.

Paper 3.2: radiance fields are generated along the descent profile during the fast flush, exposure and
frame transfer "in steps corresponding to one MOC pixel of image shift" and averaged (typically 2-4).

The shift of a period is measured on a 9 x 9 grid of sample pixels: each pixel's ground point at the
period start is followed to the period end, both on the ground (in terrain pixels) and in the image (in
camera pixels, by projecting the start ground point with the end pose). A pixel's shift counts in the
coarser of the two units, ``min(ground / terrain_mpp, image_px)``: when a camera pixel covers several
terrain pixels (far field) one step per camera pixel already samples the blur. The count is
``max(1, ceil(max shift))`` capped at ``max_substeps``; a still camera costs one field. Sub-poses sit
at the midpoints of equal sub-intervals of the period.
"""
from __future__ import annotations

import numpy as np

from flight_interface.camera import Camera
from simulator.scene import ground_mapping


def sample_pixels(camera: Camera, per_axis: int = 9) -> np.ndarray:
    """A per_axis x per_axis grid of pixel coordinates spanning the frame, (per_axis**2, 2)."""
    cols = np.linspace(0.0, camera.width_px - 1.0, per_axis)
    rows = np.linspace(0.0, camera.height_px - 1.0, per_axis)
    return np.stack(np.meshgrid(cols, rows), axis=-1).reshape(-1, 2)


def image_shift(camera: Camera, start: ground_mapping.CameraPose, end: ground_mapping.CameraPose,
                terrain_mpp: float, pixels: np.ndarray | None = None) -> float:
    """Largest shift of the sample pixels between two camera poses, in terrain pixels (see module doc)."""
    pixels = sample_pixels(camera) if pixels is None else pixels
    ground_start, hit_start = ground_mapping.ground_points(camera, start, pixels)
    ground_end, hit_end = ground_mapping.ground_points(camera, end, pixels)
    hit = hit_start & hit_end
    if not hit.any():
        return 0.0
    ground_shift = np.linalg.norm(ground_end - ground_start, axis=-1) / terrain_mpp
    reprojected, in_front = ground_mapping.world_to_pixels(camera, end, ground_start)
    image_shift_px = np.where(in_front, np.linalg.norm(reprojected - pixels, axis=-1), np.inf)
    shift = np.minimum(ground_shift, image_shift_px)[hit]
    return float(np.max(shift))


def substep_count(shift_terrain_px: float, max_substeps: int) -> int:
    """One sub-pose per terrain pixel of shift, at least 1, at most ``max_substeps``."""
    return int(min(max(1, int(np.ceil(shift_terrain_px - 1e-9))), max_substeps))


def substep_times(start_s: float, end_s: float, count: int) -> np.ndarray:
    """Midpoints of ``count`` equal sub-intervals of [start_s, end_s]."""
    return start_s + (np.arange(count) + 0.5) * (end_s - start_s) / count


def average_fields(fields: list[np.ndarray]) -> np.ndarray:
    """Pixel-by-pixel mean of radiance fields (float32); the single field itself when only one."""
    if len(fields) == 1:
        return fields[0]
    total = fields[0].copy()
    for field in fields[1:]:
        total += field
    total *= np.float32(1.0 / len(fields))
    return total
