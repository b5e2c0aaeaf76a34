"""Terrain resampling: crop the orbital image to the camera footprint, then bilinear sampling.

The paper resamples the MOC image bilinearly at each camera position (section 2.3). We crop the
terrain to the footprint's bounding box (plus a margin) so that ``cv2.remap`` reads a small source
image (and stays under its 32767-pixel source limit), then sample it at the fractional grid
coordinates of every pixel's ground point. Ground points outside the orbital strip are *flagged*
(``outside``) and filled with the mean I/F of the sampled area: flat grey, no texture, as in the
paper's Fig. 10 where the field of view left the MOC image.

When the whole terrain is within ``cv2.remap``'s source limit the remap reads the terrain in place at
the full-frame grid coordinates (no copy of the crop, no shifted coordinate maps: subtracting the
crop's integer origin from a float32 coordinate is exact, and remap's bilinear weights depend only on
the fractional part, so the samples are the same bits); the crop still gives the fill value.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from simulator.scene.terrain import Terrain

CROP_MARGIN_PX = 2
REMAP_MAX_SOURCE_PX = 32767      # cv2.remap reads sources below this size in both axes


@dataclass(frozen=True)
class Crop:
    """Rows ``row0:row1`` and columns ``col0:col1`` of the terrain; empty when ``row1 <= row0``.

    Attributes
    ----------
    row0, row1 : int
        Row range (terrain pixels).
    col0, col1 : int
        Column range (terrain pixels).
    """

    row0: int
    row1: int
    col0: int
    col1: int

    @property
    def empty(self) -> bool:
        """True when the window holds no pixel."""
        return self.row1 <= self.row0 or self.col1 <= self.col0


def footprint_crop(terrain: Terrain, footprint_cols: np.ndarray, footprint_rows: np.ndarray,
                   bounded: bool, margin_px: int = CROP_MARGIN_PX) -> Crop:
    """Terrain window holding a footprint given in terrain grid coordinates.

    Parameters
    ----------
    terrain : Terrain
        The terrain.
    footprint_cols, footprint_rows : ndarray, shape (n,)
        Fractional terrain coordinates of the footprint polygon.
    bounded : bool
        False when part of the image border sees the sky (the footprint is unbounded): the whole
        terrain is used.
    margin_px : int, optional
        Margin around the footprint (terrain pixels).

    Returns
    -------
    Crop
        The window.
    """
    rows, cols = terrain.shape
    if not bounded or len(footprint_cols) == 0:
        return Crop(0, rows, 0, cols)
    col0 = int(np.floor(np.min(footprint_cols))) - margin_px
    col1 = int(np.ceil(np.max(footprint_cols))) + margin_px + 1
    row0 = int(np.floor(np.min(footprint_rows))) - margin_px
    row1 = int(np.ceil(np.max(footprint_rows))) + margin_px + 1
    return Crop(max(row0, 0), min(row1, rows), max(col0, 0), min(col1, cols))


def outside_mask(terrain: Terrain, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Where grid coordinates fall outside the terrain's pixel edges.

    Parameters
    ----------
    terrain : Terrain
        The terrain.
    col, row : ndarray
        Fractional grid coordinates, equal shapes.

    Returns
    -------
    ndarray, bool, shape of ``col``
        True outside.
    """
    rows, cols = terrain.shape
    return (col < -0.5) | (col > cols - 0.5) | (row < -0.5) | (row > rows - 0.5)


def sample_terrain(terrain: Terrain, col: np.ndarray, row: np.ndarray, invalid: np.ndarray | None,
                   crop: Crop, may_leave_terrain: bool = True,
                   out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear terrain I/F at fractional grid coordinates.

    Parameters
    ----------
    terrain : Terrain
        The terrain.
    col, row : ndarray, shape (H, W), float32
        Terrain grid coordinates (full terrain frame).
    invalid : ndarray, shape (H, W), bool, or None
        Pixels that see no ground (sky); they get 0 and are not flagged outside. None: every pixel sees
        the ground.
    crop : Crop
        Window holding every in-strip ground point (see :func:`footprint_crop`).
    may_leave_terrain : bool, optional
        False when the caller knows every ground point is inside the strip (skips the mask pass).
    out : ndarray, shape (H, W), float32, optional
        Array to write the samples into (e.g. a scratch array the caller filters at once).

    Returns
    -------
    reflectance_if : ndarray, shape (H, W), float32
        MOC I/F (fill value outside the strip, 0 for sky).
    outside : ndarray, shape (H, W), bool
        Ground points outside the strip.
    """
    any_invalid = invalid is not None and bool(invalid.any())
    if crop.empty:
        outside = np.ones(col.shape, dtype=bool) if invalid is None else ~invalid
        fill = float(np.mean(terrain.reflectance_if[::16, ::16]))
        filled = np.where(outside, np.float32(fill), np.float32(0.0)).astype(np.float32)
        if out is not None:
            out[...] = filled
            return out, outside
        return filled, outside
    terrain_if = terrain.reflectance_if

    def crop_source() -> np.ndarray:
        return np.ascontiguousarray(terrain_if[crop.row0:crop.row1, crop.col0:crop.col1], dtype=np.float32)
    source: np.ndarray
    map_x: np.ndarray
    map_y: np.ndarray
    if (terrain_if.dtype == np.float32 and terrain_if.flags.c_contiguous
            and max(terrain_if.shape) < REMAP_MAX_SOURCE_PX):
        source, map_x, map_y = terrain_if, col, row      # the crop's samples, read in place (module doc)
    else:
        source = crop_source()
        map_x = col - np.float32(crop.col0) if crop.col0 else col
        map_y = row - np.float32(crop.row0) if crop.row0 else row
    sampled = cv2.remap(source, map_x, map_y, dst=out, interpolation=cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
    if may_leave_terrain:
        outside = outside_mask(terrain, col, row)
        if invalid is not None:
            outside &= ~invalid
        if outside.any():
            sampled[outside] = np.float32(np.mean(crop_source()))
    else:
        outside = np.zeros(col.shape, dtype=bool)
    if any_invalid:
        sampled[invalid] = 0.0
    return sampled, outside


def warped_field(field_w_m2_sr_um: np.ndarray, flow: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Resample a radiance field at the coordinates of a flow map (bilinear unless ``interpolation`` says).

    Pixels whose source lies beyond the frame take the nearest edge value.

    Parameters
    ----------
    field_w_m2_sr_um : ndarray, shape (H, W), float32
        Radiance (W m^-2 sr^-1 um^-1).
    flow : ndarray, shape (H', W', 2), float32
        (column, row) source coordinates of every output pixel.
    interpolation : int, optional
        OpenCV interpolation flag (``cv2.INTER_LINEAR``; the warped blur's block warps use ``cv2.INTER_CUBIC``).

    Returns
    -------
    ndarray, shape (H', W'), float32
        The warped field.
    """
    # map2=None is OpenCV's documented form for one two-channel CV_32FC2 map; the cv2 stubs declare map2 as an
    # array, hence the ignore. The alternatives measured on OpenCV 5.0.0: an empty array as map2 gives NaN under
    # INTER_LINEAR; two CV_32FC1 planes give the same bits but cost a copy of each plane per warp.
    return cv2.remap(field_w_m2_sr_um, flow, None, interpolation=interpolation,  # type: ignore[call-overload]
                     borderMode=cv2.BORDER_REPLICATE)
