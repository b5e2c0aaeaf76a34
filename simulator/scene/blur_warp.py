"""High motion blur at nominal cost: the three period fields as warp-and-accumulate of one rendered field.

Physics. The terrain is the plane z = 0, so a ground point seen at pixel ``x`` at time ``t`` is seen
at pixel ``sigma(x)`` at time ``t'``, where ``sigma`` is the ground-plane flow between the two camera
poses (exact ray / plane intersection and CAHVOR projection, distortion included). The radiance a
pixel integrates over a CCD period is the mean over sub-poses of the field of one rendered pose read
through those flows. Everything ground-fixed (terrain, photometry, the opposition halo: the view
direction of a ground point changes by the lander's translation only, centimetres in a 5 ms period)
moves exactly with the flow. Relief (scene.relief) only adds the parallax of that translation,
``f T dh / Z^2``: 0.006 px for 50 m of relief seen from 2000 m at 72 m/s over 5 ms (rotation, the
blur of the high-rate scenes, moves every depth alike); features that move on their own (the lander's and the heat shield's
shadows, the heat shield itself) are checked in the exposure: their true pixel at every sub-pose must
land within :data:`MOVING_TOLERANCE_PX` of where the warp puts them, else the scene is rendered per
sub-pose. The flush and transfer fields follow the ground flow everywhere, as the ``warp_smear_fields``
shortcut always has (they reach the image only through column sums over the whole frame).

Cost. One field is rendered at the exposure's middle sub-pose on a camera enlarged by margins (the CAHVOR
model with ``H' = H + L A``, ``V' = V + T A`` sees the original pixel (c, r) at (c + L, r + T)), each
side's margin as wide as the path reaches beyond it, so every exposure sub-pose's view lies inside it (the
flush and transfer reads may pass it by :data:`SMEAR_EDGE_PX` and take the edge values there, the bound of
the ``warp_smear_fields`` shortcut: those fields reach the image only through column sums). The rows
enter the image only through 4-row binning blocks
(smear and binning sum them), so the warps run at binned resolution on block means: columns keep full
resolution, rows are resolved to a block, which is what the binned image can show. A fractional-block
shift of a field with structure finer than a block along the motion would smooth it, so the first
doubling levels, whose step moves the rows by less than :data:`FULL_RESOLUTION_ROW_SHIFT_PX`, run at full
resolution; by then the accumulated field is averaged along the motion over that length and the
rest runs on block means. ``N = 2^K`` equally
spaced sub-poses are averaged with ``K`` warps by recursive doubling,
``G_{m+1}(y) = (G_m(y) + G_m(sigma_{s_m}(y))) / 2`` with steps ``s_m = 2^m`` sub-poses forward and the last
one ``2^(K-1)`` backward, exact when the flow over a time step does not
depend on when the step starts (constant rates: a rotation at constant rate is a one-parameter group
of image maps; the translation's departure from it is second order). That assumption is verified, not
trusted: for a 5 x 5 grid of pixels and 5 sub-poses spread along the path (ends included) the composed map is compared with the exact one
and must agree to :data:`GROUP_TOLERANCE_PX`: half a pixel for the exposure (the default count rule
itself spaces sub-poses up to several pixels apart on long paths, ``max_substeps``), one pixel for
the flush and transfer fields, which reach the image only through column sums over many rows (smear),
and whose average is moved furthest from the rendered pose (1 to 1.5 periods). Rendered at the exposure's
sub-pose N / 2 (half a sub-pose after the mid-time) with the last step backward, the doubling's leaves are
the exposure's sub-poses themselves (leaf j takes the steps of the bits of ``j XOR N/2``): their average is
the exposure field, with no further warp; a last warp per smear period moves it by one period to the flush's
and the transfer's. So a 64-sub-pose blur costs about 6 + 2 block-resolution warps instead of 3 x 64
rendered fields. Each warp resamples the accumulated field; bilinear resampling at fractional offsets is
a low-pass filter, and compounded over the levels it took a third of the texture that survives a x60
blur (RMS of the high-pass, against the exact sub-poses), which moved the estimated velocity by 0.2-0.3
m/s; the block-row levels are therefore bicubic (the texture kept to 0.9-0.96; the full-resolution
levels and the smear fields' warps stay bilinear).

Where the remaining difference from the exact sub-poses lives (the bench's x30 / x60 cases, exposure
field block means against the 16 rendered sub-poses, relative RMS): not in the composition (the composed
maps agree with the exact ones to 0.03 px, 0.004 px on average), nor at the margins or the flow's node
seams (the error is largest inside the frame and has no 32-px period), nor in the sub-pose count; it is
resampling, and mostly the block-row levels: a field averaged along the motion is still sharp across
it, and block means of it alias. Warping every level at full resolution and taking the block means at
the end cuts the error from 1.0-1.5e-3 to 0.16-0.36e-3 with bicubic levels (0.24e-3 with Lanczos, near
the 0.19-0.21e-3 of warping the rendered field to each sub-pose once), but full-resolution bicubic
warps of the enlarged field cost ~23 ms per image more here (the x60 case at 3.0x nominal instead of
1.9-2.1x; bilinear levels with a bicubic last one: 2.4x, 0.4-0.6e-3): not taken. The last exposure warp,
a shift by half the path on block rows, was the other large term: leaves that are the sub-poses remove
it (x30 image: 1.48 -> 1.19e-3, x60 image: 1.02 -> 0.73e-3; one block warp and its flow map less; rendered
at the first sub-pose instead, with forward steps only, a self-moving feature would drift twice as far
from where the warp puts it and sit half its drift off on average). A self-moving feature in view (the
parachute's and backshell's shadows swing with the scaled attitude) drifts by 0.04-0.13 px over an x30-x60
exposure against the ground flow (within :data:`MOVING_TOLERANCE_PX`): local errors of up to 0.5 % of the
signal in its 10-30 px; rendering a window around it per sub-pose removed them without
changing the estimated velocity. The estimated velocity answers these image changes at its own noise
floor: ``benchmarks/bench_offnominal.py`` (rows ``dv_noise_draws_mps``).

Checks cost numpy's per-call overhead, not arithmetic (25 pixels): every map of the checks is computed
in a few batched calls (:func:`_flows`: many target poses, one ray / ground pass and one projection; one
unprojection per doubling level for every period's composed positions, held in one array), and the small
unprojections run compiled (:mod:`simulator.scene.unproject_compiled`, the array code's bits).

Bounds: the path (with margin) must stay within :data:`MAX_MARGIN_PX`, no pixel of the enlarged field
may see the sky (the flow is defined on the ground only); otherwise :func:`warped_period_fields`
returns None and the caller renders each sub-pose exactly. Measured against the exact sub-pose
integration of the reference preset: ``make bench`` (offnominal rows) and tests/simulator.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from flight_interface import cahvor
from flight_interface.camera import Camera
from simulator.fields import RadianceFields, block_means
from simulator.scene import ground_mapping, motion_blur, node_grid, resample, shadow, unproject_compiled
from simulator.scene.descent_profile import Pose

MARGIN_STEP_PX = 32            # margins are multiples of the flow node step (and of the binning rows)
MAX_MARGIN_PX = 512            # a 2048 x 2048 field at most: still ~8x cheaper than 16 rendered sub-poses
EXPANDED_CAMERAS_KEPT = 4      # enlarged cameras cached per camera (least recently used dropped)
GROUP_TOLERANCE_PX = {"exposure": 0.5, "flush": 1.0, "transfer": 1.0}   # composed vs exact map (px)
MOVING_TOLERANCE_PX = 0.5      # shadows and heat shield: true pixel vs where the warp puts them
FLOW_STEP_PX = 32
FULL_RESOLUTION_ROW_SHIFT_PX = 4.0   # doubling levels with less row motion per step run at full resolution
SMEAR_INTERPOLATION = cv2.INTER_LINEAR    # flush / transfer: the average moved by one period, block rows
CHECK_GRID = 5
SMEAR_EDGE_PX = 32.0           # flush / transfer reads allowed beyond the rendered field (smear_warp's node step)
CHECKED_LEAVES = 5


@dataclass(frozen=True)
class WarpedPeriods:
    """The three period fields by warp-and-accumulate, plus exposure masks and diagnostics.

    Attributes
    ----------
    fields : RadianceFields
        Flush, exposure and transfer radiance as block means, (H / b, W) (W m^-2 sr^-1 um^-1).
    sky : ndarray, shape (H, W), bool
        Sky pixels (none: the warp needs ground everywhere).
    outside : ndarray, shape (H, W), bool
        Ground outside the terrain strip (exposure union).
    heat_shield : ndarray, shape (H, W), bool
        Heat-shield pixels (exposure union).
    substeps : dict of str to int
        Sub-poses averaged per period (a power of two).
    centre_radiance : ndarray, shape (H, W), float32
        The one rendered field (at the exposure's sub-pose N / 2; the scene's diagnostic exposure-centre field),
        a view of the enlarged field's frame (the image chain does not read it: no copy).
    centre_heat_shield : ndarray, shape (H, W), bool, or None
        The heat shield in the rendered field (a view, as ``centre_radiance``).
    shadow_centres_m : list of ndarray, shape (3,)
        Ground shadow centres at the rendered pose (m).
    margins_px : tuple of int
        (left, right, top, bottom) margins of the enlarged rendered field (px).
    """

    fields: RadianceFields
    sky: np.ndarray
    outside: np.ndarray
    heat_shield: np.ndarray
    substeps: dict
    centre_radiance: np.ndarray       # the rendered field, (H, W)
    centre_heat_shield: np.ndarray | None
    shadow_centres_m: list
    margins_px: tuple[int, int, int, int]


def expanded_camera(camera: Camera, margins_px: tuple[int, int, int, int]) -> Camera:
    """A camera enlarged by margins: its pixel (c + left, r + top) sees what ``camera``'s pixel (c, r) sees.

    Cached per camera and margins.

    Parameters
    ----------
    camera : Camera
        The camera.
    margins_px : tuple of int
        (left, right, top, bottom) margins (px).

    Returns
    -------
    Camera
        The enlarged camera.
    """
    cache = ground_mapping.camera_cache(camera).setdefault("expanded", {})
    left, right, top, bottom = (int(m) for m in margins_px)
    key = (left, right, top, bottom)
    if key in cache:
        cache[key] = cache.pop(key)               # most recently used last
    else:
        while len(cache) >= EXPANDED_CAMERAS_KEPT:   # each holds its own ray caches (tens of MiB): keep a few
            del cache[next(iter(cache))]
        model = camera.model
        detector = camera.detector.model_copy(update={"width_px": camera.width_px + left + right,
                                                      "height_px": camera.height_px + top + bottom})
        cache[key] = replace(camera, detector=detector,
                             model=replace(model, h=model.h + left * model.a, v=model.v + top * model.a))
    return cache[key]


def _flows(camera: Camera, source: ground_mapping.CameraPose,
           groups: list[tuple[ground_mapping.CameraPose, np.ndarray]]) -> list[np.ndarray] | None:
    """Exact source pixels of the ground points seen along camera-frame rays from several target poses, at once.

    Parameters
    ----------
    camera : Camera
        The camera of both images.
    source : CameraPose
        The pose of the image read from.
    groups : list of (CameraPose, ndarray of shape (..., 3))
        Target poses, each with the camera-frame unit rays of pixels of the image made at it.

    Returns
    -------
    list of ndarray, shape (..., 2), or None
        Per group, the (column, row) source pixels (px); None when any ray sees the sky or its ground
        point lies behind the source camera. One projection serves every group (the small arrays of
        the checks cost numpy's per-call overhead, not arithmetic).
    """
    pixels = _flat_flows(camera, source, groups)
    if pixels is None:
        return None
    if len(groups) == 1:
        return [pixels]
    parts, start = [], 0
    for _, rays in groups:          # views of the one projection, each shaped as its group's rays
        stop = start + rays.size // 3
        parts.append(pixels[start:stop].reshape(*rays.shape[:-1], 2))
        start = stop
    return parts


def _flat_flows(camera: Camera, source: ground_mapping.CameraPose,
                groups: list[tuple[ground_mapping.CameraPose, np.ndarray]]) -> np.ndarray | None:
    """:func:`_flows` before the split: every group's source pixels in group order, (n, 2).

    Shaped as the one group's rays (..., 2) when there is one group; None as :func:`_flows`.
    """
    if not all(target.ray_origin_m[2] > 0 for target, _ in groups):
        return None
    # each group's rays turned by its own rotation (one product per group, as always); the ray / ground
    # intersection is elementwise, so it runs once on all the groups' rays with each row's own origin
    worlds = [rays @ target.camera_to_world.T for target, rays in groups]
    if len(groups) == 1:
        world, origin = worlds[0], groups[0][0].ray_origin_m
        down = world[..., 2]
        if not bool((down < -ground_mapping.HORIZON_EPSILON).all()):
            return None
        flat = origin + (-origin[2] / down)[..., None] * world
    else:
        world = np.concatenate([item.reshape(-1, 3) for item in worlds])
        down = world[:, 2]
        if not bool((down < -ground_mapping.HORIZON_EPSILON).all()):
            return None
        origins = np.repeat(np.stack([target.ray_origin_m for target, _ in groups]),
                            [item.size // 3 for item in worlds], axis=0)
        flat = origins + (-origins[:, 2] / down)[:, None] * world
    pixels, in_front = ground_mapping.world_to_pixels(camera, source, flat)
    return pixels if bool(in_front.all()) else None


def _flow_points(camera: Camera, target: ground_mapping.CameraPose, source: ground_mapping.CameraPose,
                 pixels: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray | None:
    """Exact source pixels (..., 2) of the ground points that ``pixels`` see at ``target``.

    Camera-frame ``rays`` of the pixels when known; None when any of them sees the sky or lands behind the camera.
    """
    rays = _unproject(camera, pixels) if rays is None else rays
    return _flat_flows(camera, source, [(target, rays)])


def _unproject(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Camera-frame unit rays (..., 3) of a few pixels (..., 2): :func:`flight_interface.cahvor.unproject`'s bits.

    Compiled (:mod:`simulator.scene.unproject_compiled`): the checks' small sets cost numpy's per-call
    overhead, ~100 us each, not arithmetic.
    """
    return unproject_compiled.unproject(camera.model, pixels)


def _project_many(camera: Camera, items: list[tuple[ground_mapping.CameraPose, np.ndarray]]
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`~simulator.scene.ground_mapping.world_to_pixels` of several (pose, points (n, 3)) pairs in one projection."""
    in_camera = np.concatenate([(np.asarray(points, dtype=float) - pose.frame_origin_m) @ pose.camera_to_world
                                for pose, points in items])
    pixels, in_front = cahvor.project(camera.model, in_camera)
    parts, start = [], 0
    for _, points in items:
        stop = start + len(points)
        parts.append((pixels[start:stop], in_front[start:stop]))
        start = stop
    return parts


def _block_flows(camera: Camera, targets: list[tuple[ground_mapping.CameraPose, int]],
                 source: ground_mapping.CameraPose, source_offset_px: tuple[float, float]) -> list[np.ndarray] | None:
    """Flow maps over ``camera``'s frame from several target poses to one source pose, one projection for all.

    Parameters
    ----------
    camera : Camera
        The camera of both images.
    targets : list of (CameraPose, int)
        Per map, the pose of the image made and its row resolution ``block_rows`` (1: full resolution).
    source : CameraPose
        The pose of the image read from.
    source_offset_px : tuple of float
        (column, row) shift of the source pixels (px; the source is an enlarged frame).

    Returns
    -------
    list of ndarray, shape (H / b, W, 2), float32, or None
        Per target, the (column, block row) source pixels of every output pixel (bilinear between nodes
        every :data:`FLOW_STEP_PX` pixels); None when any node ray misses the ground.
    """
    rays = _node_rays(camera)
    nodes = _flows(camera, source, [(target, rays) for target, _ in targets])
    if nodes is None:
        return None
    maps = []
    for source_pixels, (_, block_rows) in zip(nodes, targets):
        source_pixels = source_pixels + np.asarray(source_offset_px, dtype=float)
        source_pixels[..., 1] = (source_pixels[..., 1] - 0.5 * (block_rows - 1)) / block_rows
        maps.append(node_grid.upsample_nodes(source_pixels, FLOW_STEP_PX, camera.height_px // block_rows,
                                             camera.width_px, row_step_px=FLOW_STEP_PX // block_rows))
    return maps


@functools.lru_cache(maxsize=16)
def _checked_leaves(count: int) -> np.ndarray:
    """:meth:`_Plan.checked_leaves` of a sub-pose count (read-only, computed once per count)."""
    leaves = np.unique(np.linspace(0, count - 1, min(count, CHECKED_LEAVES)).round().astype(int))
    leaves.setflags(write=False)
    return leaves


def _node_rays(camera: Camera) -> np.ndarray:
    """Camera-frame unit rays (ny, nx, 3) of the flow nodes, once per camera (read-only).

    The nodes are :func:`~simulator.scene.node_grid.node_positions` every :data:`FLOW_STEP_PX` pixels.
    """
    cache = ground_mapping.camera_cache(camera)
    rays = cache.get("blur_warp_node_rays")
    if rays is None:
        rows = node_grid.node_positions(camera.height_px, FLOW_STEP_PX)
        cols = node_grid.node_positions(camera.width_px, FLOW_STEP_PX)
        rays = cache["blur_warp_node_rays"] = ground_mapping.camera_frame_rays(camera, np.stack(np.meshgrid(cols, rows),
                                                                                                 axis=-1))
        rays.setflags(write=False)
    return rays


class _Plan:
    """Times and exact maps of the doubling scheme for one image (see module doc)."""

    def __init__(self, camera: Camera, cam_at: Callable[[float], ground_mapping.CameraPose], windows: dict,
                 count: int):
        self.levels = max(1, math.ceil(math.log2(count)))
        self.count = 2 ** self.levels
        self.camera, self.cam_at, self.windows = camera, cam_at, windows
        lengths = {round(end - start, 12) for start, end in windows.values()}
        self.step_s = {period: (end - start) / self.count for period, (start, end) in windows.items()}
        self.ok = len(lengths) == 1          # one chain serves the three periods of equal length
        self.delta_s = next(iter(self.step_s.values()))
        # the field is rendered at the exposure's middle sub-pose (index N / 2) and the last level steps
        # backward, so the doubling's leaves are the exposure's sub-poses themselves: their average needs no
        # last warp (module doc); leaf j takes the steps of the bits of j XOR N / 2
        self.base_index = self.count // 2
        self.base_s = float(self.leaf_times("exposure")[self.base_index])
        self.average_centre_s = self.base_s - 0.5 * self.delta_s

    def step_sub_poses(self, level: int) -> int:
        """The step of ``level`` in sub-poses: ``2^level`` forward, the last level ``2^level`` backward."""
        return -(2 ** level) if level == self.levels - 1 else 2 ** level

    def step_pose(self, level: int) -> ground_mapping.CameraPose:
        """The camera pose one step of ``level`` away from the rendered pose."""
        return self.cam_at(self.base_s + self.step_sub_poses(level) * self.delta_s)

    def leaf_times(self, period: str) -> np.ndarray:
        start, end = self.windows[period]
        return motion_blur.substep_times(start, end, self.count)

    def checked_leaves(self) -> np.ndarray:
        """The leaves whose composed maps are checked.

        Both ends and at most CHECKED_LEAVES in all, evenly spread (the composition error varies smoothly
        along the path; measured on the nightly cases).
        """
        return _checked_leaves(self.count)

    def composed(self, queries: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]
                 ) -> list[tuple[np.ndarray, np.ndarray]] | None:
        """Where the doubling scheme reads the rendered field for given leaves, for several queries at once.

        Parameters
        ----------
        queries : list of (str, ndarray (L,), ndarray (L, P, 2), ndarray (L, P, 3))
            Period, leaves, the pixels of each leaf's image (px) and their camera-frame unit rays.

        Returns
        -------
        list of (ndarray (L, P, 2), ndarray (2, 2)) or None
            Per query, the positions read in the rendered field (px) and how far any intermediate position
            lies from its pixel as (column, row) lows and highs (px; the end leaves, always checked, reach
            furthest on a path that does not turn back); None when a ray misses the ground. Each level
            moves the chosen positions of every query with one unprojection and one projection.
        """
        centre = self.cam_at(self.base_s)
        # every query's positions in one (n, 2) array, query by query, leaf by leaf: the rows a level moves,
        # taken in that order, are the concatenation of each query's chosen leaves (one unprojection)
        first = _flat_flows(self.camera, self.cam_at(self.average_centre_s),
                            [(self.cam_at(0.5 * sum(self.windows[period])), rays) for period, _, _, rays in queries])
        if first is None:
            return None
        positions = first.reshape(-1, 2)
        pixels = np.concatenate([query_pixels.reshape(-1, 2) for _, _, query_pixels, _ in queries])
        leaf_bits = np.concatenate([np.repeat(leaves, query_pixels[0, ..., 0].size)
                                    for _, leaves, query_pixels, _ in queries]) ^ self.base_index
        # the offsets of every intermediate position from its pixel, one snapshot per moving level
        offsets = np.empty((self.levels + 1, *positions.shape))
        np.subtract(positions, pixels, out=offsets[0])
        snapshots = 1
        for level in reversed(range(self.levels)):
            chosen = (leaf_bits >> level) & 1 == 1
            if not chosen.any():
                continue
            moved = _flow_points(self.camera, self.step_pose(level), centre, positions[chosen])
            if moved is None:
                return None
            positions[chosen] = moved
            np.subtract(positions, pixels, out=offsets[snapshots])
            snapshots += 1
        results, start = [], 0
        for _, _, query_pixels, _ in queries:
            stop = start + query_pixels[..., 0].size
            reached = offsets[:snapshots, start:stop]
            extent = np.array([np.minimum(reached.min(axis=(0, 1)), 0.0), np.maximum(reached.max(axis=(0, 1)), 0.0)])
            results.append((positions[start:stop].reshape(query_pixels.shape), extent))
            start = stop
        return results


def warped_period_fields(camera: Camera, pose_at: Callable[[float], Pose],
                         cam_at: Callable[[float], ground_mapping.CameraPose], windows: dict, count: int, render: Callable[[Camera, Pose], Any],
                         moving_points: Callable[[float], list]) -> WarpedPeriods | None:
    """The flush, exposure and transfer fields of one image by warp-and-accumulate (module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    pose_at : callable
        ``time_s -> Pose``.
    cam_at : callable
        ``time_s -> CameraPose``.
    windows : dict of str to (float, float)
        ``period -> (start_s, end_s)`` (s).
    count : int
        Sub-poses the blur needs (rounded up to a power of two).
    render : callable
        ``(camera, pose) -> PoseField``: the scene at one pose.
    moving_points : callable
        ``time_s -> list`` of world points (m) that move on their own (shadow centres, heat shield).

    Returns
    -------
    WarpedPeriods or None
        The fields, or None when the scene does not allow the warp (then render each sub-pose).
    """
    plan = _Plan(camera, cam_at, windows, count)
    if not plan.ok:
        return None
    checked = _checked_extent(plan, moving_points)
    if checked is None:
        return None
    extent, row_shifts = checked
    # per side: the furthest any read position lies beyond the frame (+10 % for pixels between samples)
    left, top = (MARGIN_STEP_PX * math.ceil((1.1 * max(-low, 0.0) + 4.0) / MARGIN_STEP_PX) for low in extent[0])
    right, bottom = (MARGIN_STEP_PX * math.ceil((1.1 * max(high, 0.0) + 4.0) / MARGIN_STEP_PX) for high in extent[1])
    margins = (left, right, top, bottom)
    if max(margins) > MAX_MARGIN_PX:
        return None
    big = expanded_camera(camera, margins)
    field = render(big, pose_at(plan.base_s))
    if field.sky.any():
        return None
    b = camera.binning_rows
    height, width = camera.height_px, camera.width_px
    inner = (slice(top, top + height), slice(left, left + width))
    # every level at full resolution (block-mean levels alias the rows the blur leaves sharp: module doc)
    # early levels (short paths, fine structure along the motion) at full resolution, then block means:
    # a field already averaged over >= FULL_RESOLUTION_ROW_SHIFT_PX of row motion is smoother along it, and
    # its fractional-block shifts interpolate better (module doc)
    accumulated, block = field.radiance, 1
    base_cam = cam_at(plan.base_s)
    # a level's block rows: b from the first level whose step moves the rows by FULL_RESOLUTION_ROW_SHIFT_PX on
    level_blocks = np.where(np.maximum.accumulate(np.asarray(row_shifts) >= FULL_RESOLUTION_ROW_SHIFT_PX), b, 1)
    flows = _block_flows(big, [(plan.step_pose(level), int(level_blocks[level])) for level in range(plan.levels)],
                         base_cam, (0.0, 0.0))
    if flows is None:
        return None
    for level, flow in enumerate(flows):
        if block == 1 and level_blocks[level] == b:
            accumulated, block = block_means(accumulated, b), b
        # block rows: bicubic (bilinear at fractional-block shifts would smooth the rows at the block scale)
        warped = resample.warped_field(accumulated, flow, cv2.INTER_LINEAR if block == 1 else cv2.INTER_CUBIC)
        accumulated = cv2.addWeighted(accumulated, 0.5, warped, 0.5, 0.0, dst=warped)   # in place: no new array
    blocks = accumulated if block == b else block_means(accumulated, b)
    # the leaves are the exposure's sub-poses: the exposure is the average itself; flush and transfer are it
    # moved by one period, at block resolution (they reach the image only through column sums, as with
    # warp_smear_fields)
    averaged = {"exposure": np.ascontiguousarray(blocks[top // b:(top + height) // b, left:left + width])}
    smear_periods = ("flush", "transfer")
    smear_flows = _block_flows(camera, [(cam_at(0.5 * sum(windows[period])), b) for period in smear_periods],
                               cam_at(plan.average_centre_s), (left, top))
    if smear_flows is None:
        return None
    for period, flow in zip(smear_periods, smear_flows):
        averaged[period] = resample.warped_field(blocks, flow, SMEAR_INTERPOLATION)
    outside = _mask_union(field.outside, camera, (left, top), plan, cam_at)
    shield_full = field.heat_shield
    shield = (_mask_union(shield_full, camera, (left, top), plan, cam_at) if shield_full is not None
              else np.zeros((height, width), dtype=bool))
    return WarpedPeriods(
        RadianceFields(averaged["flush"], averaged["exposure"], averaged["transfer"]),
        np.zeros((height, width), dtype=bool), outside, shield,
        {period: plan.count for period in windows},
        field.radiance[inner], None if shield_full is None else shield_full[inner],   # diagnostics: views, no copy
        field.shadow_centres_m, margins)


def _checked_extent(plan: _Plan, moving_points: Callable[[float], list]) -> tuple[np.ndarray, list[float]] | None:
    """Verify the doubling scheme on this image, measure how far its reads reach and each level's row motion (module doc).

    For a :data:`CHECK_GRID` grid of pixels and the :meth:`_Plan.checked_leaves` of each period, the
    composed map must agree with the exact one to :data:`GROUP_TOLERANCE_PX`; every self-moving point
    (shadow centres, heat shield) in or near the frame must land, at every checked exposure sub-pose,
    within :data:`MOVING_TOLERANCE_PX` of where the composed warp reads it in the rendered field (where
    the point is at the rendered pose). All maps are computed together (:func:`_flows`).

    Parameters
    ----------
    plan : _Plan
        The doubling scheme of the image.
    moving_points : callable
        ``time_s -> list`` of world points (m) that move on their own.

    Returns
    -------
    (ndarray (2, 2), list of float) or None
        (column, row) lows and highs of the read positions relative to their pixels (px) and each doubling
        level's largest row motion of those pixels over one step (px), or None when a check fails or a step's
        ray misses the ground (then the scene is rendered per sub-pose).
    """
    camera, cam_at = plan.camera, plan.cam_at
    pixels, rays = _check_pixels(camera)
    checked = plan.checked_leaves()
    shape = (len(checked), *pixels.shape)
    grid_pixels, grid_rays = np.broadcast_to(pixels, shape), np.broadcast_to(rays, (*shape[:2], 3))
    queries = [(period, checked, grid_pixels, grid_rays) for period in plan.windows]
    moving = _moving_query(plan, checked, moving_points)
    if moving is not None:
        where_centre, moving_pixels = moving
        queries.append(("exposure", checked, moving_pixels, _unproject(camera, moving_pixels)))
    composed = plan.composed(queries)
    if composed is None:
        return None
    centre = cam_at(plan.base_s)
    leaf_times = {period: plan.leaf_times(period) for period in plan.windows}
    # with the exact maps, each level's step (its row motion decides the level's resolution): one projection
    exact = _flat_flows(camera, centre, [(cam_at(float(leaf_times[period][leaf])), rays)
                                         for period in plan.windows for leaf in checked]
                        + [(plan.step_pose(level), rays) for level in range(plan.levels)])
    if exact is None:
        return None
    exact = exact.reshape(-1, *pixels.shape)      # (periods x checked leaves, then levels, P, 2)
    row_shifts = np.abs(exact[len(exact) - plan.levels:, :, 1] - pixels[:, 1]).max(axis=1).tolist()
    extent = np.zeros((2, 2))
    leaves = len(checked)
    for index, period in enumerate(plan.windows):
        positions, period_extent = composed[index]
        # the largest error over the period's checked leaves
        error = float(np.abs(positions - exact[index * leaves:(index + 1) * leaves]).max())
        if not error <= GROUP_TOLERANCE_PX[period]:
            return None
        if period != "exposure":      # the smear fields may read up to SMEAR_EDGE_PX beyond the field (edge values)
            period_extent = np.array([np.minimum(period_extent[0] + SMEAR_EDGE_PX, 0.0),
                                      np.maximum(period_extent[1] - SMEAR_EDGE_PX, 0.0)])
        extent = np.array([np.minimum(extent[0], period_extent[0]), np.maximum(extent[1], period_extent[1])])
    if moving is not None and not float(np.max(np.abs(composed[-1][0] - where_centre))) <= MOVING_TOLERANCE_PX:
        return None
    return extent, row_shifts


def _check_pixels(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The :data:`CHECK_GRID` grid of pixels (P, 2) and their camera-frame unit rays (P, 3), once per camera (read-only)."""
    cache = ground_mapping.camera_cache(camera)
    found = cache.get("blur_warp_check_pixels")
    if found is None:
        pixels = motion_blur.sample_pixels(camera, CHECK_GRID)
        pixels.setflags(write=False)
        found = cache["blur_warp_check_pixels"] = (pixels, ground_mapping.camera_frame_rays(camera, pixels))
    return found


def _moving_query(plan: _Plan, checked: np.ndarray, moving_points: Callable[[float], list]
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """The self-moving points to check: their pixels at the centre (S, 2) and at the checked exposure leaves (L, S, 2).

    Only the points seen at the centre and at every checked leaf, within 64 px of the frame; None when
    there are none.
    """
    camera = plan.camera
    reference = moving_points(plan.base_s)
    if not reference:
        return None
    times = plan.leaf_times("exposure")
    items = [(plan.cam_at(plan.base_s), np.asarray(reference))]
    # the rendered pose is the exposure leaf N / 2, itself a checked leaf: its points are the reference's
    items += [(plan.cam_at(float(times[leaf])),
               np.asarray(reference if float(times[leaf]) == plan.base_s else moving_points(float(times[leaf]))))
              for leaf in checked]
    projected = _project_many(camera, items)
    where_centre, seen = projected[0][0], np.array(projected[0][1], dtype=bool)
    pixels = np.stack([leaf_pixels for leaf_pixels, _ in projected[1:]])
    for _, in_front in projected[1:]:
        seen &= in_front
    size = np.array([camera.width_px, camera.height_px], dtype=float)
    seen &= np.all((pixels > -64.0) & (pixels < size + 64.0), axis=(0, 2))
    if not seen.any():
        return None
    return where_centre[seen], np.ascontiguousarray(pixels[:, seen])


def _mask_union(mask: np.ndarray, camera: Camera, offset: tuple[int, int], plan: _Plan,
                cam_at: Callable[[float], ground_mapping.CameraPose]) -> np.ndarray:
    """Exposure-period union of a mask of the enlarged rendered field.

    The mask as rendered (the middle exposure sub-pose) and at the first and last sub-poses, each moved
    rigidly by the flow at the centre of the mask's bounding box (the masks are compact: the heat shield,
    terrain beyond the strip's edge), nearest pixel.
    """
    height, width = camera.height_px, camera.width_px
    union = mask[offset[1]:offset[1] + height, offset[0]:offset[0] + width].copy()
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return union
    cols = np.flatnonzero(mask[rows[0]:rows[-1] + 1].any(axis=0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    box = mask[r0:r1, c0:c1]
    centre = np.array([[0.5 * (c0 + c1 - 1) - offset[0], 0.5 * (r0 + r1 - 1) - offset[1]]])
    rays = _unproject(camera, centre)
    for time_s in plan.leaf_times("exposure")[[0, -1]]:
        source = _flow_points(camera, cam_at(float(time_s)), cam_at(plan.base_s), centre, rays)
        if source is None:
            continue
        # a pixel x of the sub-pose image reads the rendered field at x + d: the mask moves by -d
        shift_col, shift_row = (int(round(v)) for v in (centre - source)[0])
        top, left = r0 - offset[1] + shift_row, c0 - offset[0] + shift_col
        dst_r0, dst_r1 = max(top, 0), min(top + box.shape[0], height)
        dst_c0, dst_c1 = max(left, 0), min(left + box.shape[1], width)
        if dst_r1 > dst_r0 and dst_c1 > dst_c0:
            union[dst_r0:dst_r1, dst_c0:dst_c1] |= box[dst_r0 - top:dst_r1 - top, dst_c0 - left:dst_c1 - left]
    return union


def moving_world_points(pose: Pose, casters: list, sun: np.ndarray) -> list:
    """World points that move on their own at a pose: each caster's ground shadow centre and the heat shield.

    Parameters
    ----------
    pose : Pose
        Lander pose.
    casters : list of shadow.Caster
        The shadow casters at the pose.
    sun : ndarray, shape (3,)
        World unit vector toward the sun.

    Returns
    -------
    list of ndarray, shape (3,)
        World points (m).
    """
    points = [shadow.shadow_centre_m(np.asarray(caster.centre_m, dtype=float), sun) for caster in casters]
    if pose.heat_shield_position_m is not None:
        points.append(np.asarray(pose.heat_shield_position_m, dtype=float))
    return points
