"""Can a class's terrain hold the descent images' footprints? Refuse it, or fit it when the user asks.

The three image footprints of a trajectory (ground outlines at mid-exposure, :mod:`campaign.plan.placement`)
turned to a heading span a box ``W(h) x H(h)``. A terrain of extent ``Wt x Ht`` and pixel ``p`` holds
the trajectory when some heading (10 deg steps, as the planner searches) gives ``W <= Wt - 4p`` and
``H <= Ht - 4p`` (the planner keeps 2 px of bilinear support inside each edge). Over all trajectories
of the site's set (not just the planned ones, so the answer does not depend on case counts) this gives
the smallest factor ``s`` by which the terrain would have to be larger.

A class whose terrain cannot hold every trajectory is refused in one line naming the largest
first-image altitude it holds (footprints scale with altitude: about ``H1 / s``), the pixel scale at
which the same image would hold them (``p x s``) and the mosaic size, unless the class's terrain
table asks for ``resample``:

* ``"stretch"``: the same image at ``p x s`` m/pixel (features grow by ``s``; stated in the plan);
* ``"mosaic"``: the image mirror-tiled (reflected copies, seamless at the joins) around the original,
  at its own scale, to the smallest extent holding every trajectory (features repeat).

Trajectories that see the sky (no footprint can be held) are left to the case task, which scores any
image with more than ``max_outside_terrain_fraction`` of its pixels outside the terrain invalid
(``outside_terrain``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from campaign.plan.placement import HEADING_SEARCH_STEP_RAD, _turn, footprint_points_m
from simulator.scene.ground_mapping import border_pixels, camera_pose, ground_points
from simulator.scene.height_field import ReliefTerrain
from simulator.scene.terrain import Terrain
from sitedata.sites import RESAMPLE_MODES

MARGIN_PX = 2.0


@dataclass(frozen=True)
class Coverage:
    """How well a terrain holds a trajectory set's footprints.

    Attributes
    ----------
    scale_needed : float
        Smallest factor by which the terrain's extent must grow (<= 1: it holds every trajectory;
        inf: fewer than 5 pixels across, no stretch helps).
    failing : int
        Trajectories it cannot hold (of ``trajectories`` with a ground footprint).
    required_extent_m : (float, float)
        East-west and north-south extent (m) a mosaic needs, margins included.
    first_altitude_m : float
        Median first-image altitude of the set (m).
    """

    scale_needed: float
    failing: int
    trajectories: int
    required_extent_m: tuple[float, float]
    first_altitude_m: float

    @property
    def holds(self) -> bool:
        return self.failing == 0


def _boxes(outline: np.ndarray) -> np.ndarray:
    """(headings, 2) width and height of the outline's bounding box at each 10 deg heading step."""
    steps = int(round(2.0 * math.pi / HEADING_SEARCH_STEP_RAD))
    boxes = []
    for k in range(steps):
        turned = _turn(outline, k * HEADING_SEARCH_STEP_RAD)
        boxes.append(turned.max(axis=0) - turned.min(axis=0))
    return np.array(boxes)


def trajectory_boxes(camera, profiles) -> list[np.ndarray | None]:
    """Footprint bounding boxes of every trajectory at every heading step (None: sky in view)."""
    boxes = []
    for profile in profiles:
        outline = footprint_points_m(camera, profile)
        boxes.append(None if outline is None else _boxes(outline))
    return boxes


def relief_margin_m(terrain: Terrain, camera, profiles) -> float:
    """Extra margin (m) for a terrain with heights: a border ray meets ground at height h < 0 further out,
    by ``-h tan(theta)`` (theta its angle from the vertical), bounded by the strip's lowest height and the
    steepest border ray of the trajectory set's images. 0 without heights (plans unchanged)."""
    if not isinstance(terrain, ReliefTerrain):
        return 0.0
    lowest = float(np.min(terrain.height_m))
    if lowest >= 0.0:
        return 0.0
    border = border_pixels(camera, 2)           # corners and edge midpoints: the farthest-reaching rays
    steepest = 0.0
    for profile in profiles:
        for start in profile.image_times_s:
            pose = camera_pose(camera, profile.pose(camera.timing.exposure_mid_time_s(float(start))))
            points, hit = ground_points(camera, pose, border)
            if hit.all():
                reach = np.hypot(*(points[:, :2] - pose.ray_origin_m[:2]).T).max()
                steepest = max(steepest, float(reach / pose.ray_origin_m[2]))
    return -lowest * steepest


def coverage(terrain: Terrain, camera, profiles, boxes: list[np.ndarray | None] | None = None) -> Coverage:
    """How ``terrain`` holds the footprints of ``profiles`` (see module doc; a terrain with heights keeps
    :func:`relief_margin_m` more on each side)."""
    boxes = trajectory_boxes(camera, profiles) if boxes is None else boxes
    west, east, south, north = terrain.extent_m
    margin = 2.0 * MARGIN_PX * terrain.metres_per_pixel + 2.0 * relief_margin_m(terrain, camera, profiles)
    usable = np.array([east - west - margin, north - south - margin])
    factors, required, failing = [], np.zeros(2), 0
    for box in boxes:
        if box is None:
            continue
        with np.errstate(divide="ignore"):
            per_heading = np.where(usable > 0, box / np.maximum(usable, 1e-300), np.inf).max(axis=1)
        best = int(np.argmin(per_heading))
        factors.append(float(per_heading[best]))
        failing += per_heading[best] > 1.0
        required = np.maximum(required, box[best] + margin)
    altitudes = [float(p.pose(float(p.image_times_s[0])).position_m[2]) for p in profiles]
    return Coverage(scale_needed=max(factors) if factors else 0.0, failing=int(failing), trajectories=len(factors),
                    required_extent_m=(float(required[0]), float(required[1])),
                    first_altitude_m=float(np.median(altitudes)) if altitudes else float("nan"))


def refusal(class_name: str, terrain: Terrain, cover: Coverage) -> str:
    """The one-line reason a class is refused."""
    west, east, south, north = terrain.extent_m
    rows, cols = terrain.shape
    what = (f"class {class_name}: terrain {terrain.name} ({cols} x {rows} px at {terrain.metres_per_pixel:g} m = "
            f"{(east - west) / 1e3:.3g} x {(north - south) / 1e3:.3g} km) cannot hold the three image footprints "
            f"of {cover.failing} of {cover.trajectories} trajectories (they need up to "
            f"{cover.required_extent_m[0] / 1e3:.3g} x {cover.required_extent_m[1] / 1e3:.3g} km)")
    if math.isinf(cover.scale_needed):
        return (f"{what}; it is under {2 * MARGIN_PX + 1:.0f} pixels across, so no altitude or scale fits; "
                f"terrain.resample = \"mosaic\" tiles it to fit")
    return (f"{what}; it holds them only with first images below about "
            f"{cover.first_altitude_m / cover.scale_needed:.0f} m (now {cover.first_altitude_m:.0f} m), or at "
            f"{terrain.metres_per_pixel * cover.scale_needed:.3g} m/pixel or coarser; set terrain.resample = "
            f"\"stretch\" (that scale) or \"mosaic\" (mirror tiles) in its [site.classes] terrain table")


def fit_terrain(terrain: Terrain, mode: str, cover: Coverage) -> Terrain:
    """The terrain stretched or mosaicked to hold every trajectory (unchanged when it already does)."""
    if mode == "none" or cover.holds:
        return terrain
    if mode == "stretch":
        if math.isinf(cover.scale_needed):
            raise ValueError(f"terrain {terrain.name}: under {2 * MARGIN_PX + 1:.0f} pixels across, cannot be stretched")
        factor = cover.scale_needed * (1.0 + 1e-6)
        return replace(terrain, metres_per_pixel=terrain.metres_per_pixel * factor,
                       origin_m=np.asarray(terrain.origin_m) * factor,
                       name=f"{terrain.name}@{terrain.metres_per_pixel * factor:.3g}m")
    if mode != "mosaic":
        raise ValueError(f"terrain.resample = {mode!r}; allowed: {', '.join(RESAMPLE_MODES)}")
    rows, cols = terrain.shape
    mpp = terrain.metres_per_pixel
    need_cols = max(cols, int(math.ceil(cover.required_extent_m[0] / mpp)) + 1)
    need_rows = max(rows, int(math.ceil(cover.required_extent_m[1] / mpp)) + 1)
    pad_c, pad_r = need_cols - cols, need_rows - rows
    pads = (pad_r // 2, pad_r - pad_r // 2), (pad_c // 2, pad_c - pad_c // 2)
    tiled = _mirror_pad(terrain.reflectance_if, *pads)
    origin = np.array([-(need_cols - 1) / 2 * mpp, (need_rows - 1) / 2 * mpp])
    name = f"{terrain.name}-mosaic{need_cols}x{need_rows}"
    if isinstance(terrain, ReliefTerrain):
        return replace(terrain, reflectance_if=tiled, origin_m=origin, name=name,
                       height_m=_mirror_pad(terrain.height_m, *pads))
    return replace(terrain, reflectance_if=tiled, origin_m=origin, name=name)


def _mirror_pad(image: np.ndarray, rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
    """Symmetric (reflected, edge pixel repeated) tiling to any size, also beyond the image's own size."""
    out = np.asarray(image, dtype=np.float32)
    for axis, (before, after) in ((0, rows), (1, cols)):
        size = out.shape[axis]
        index = np.arange(-before, size + after)
        period = 2 * size
        folded = np.mod(index, period)
        folded = np.where(folded >= size, period - 1 - folded, folded)
        out = np.take(out, folded, axis=axis)
    return np.ascontiguousarray(out)
