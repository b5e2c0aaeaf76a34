"""Placement of EDL trajectories on terrain strips (paper section 5, Fig. 5).

For each appearance class, case ``k`` (its index within the class) gets

* a trajectory from the site's pregenerated set (a seeded permutation, cycled when there are more
  cases than trajectories);
* a heading: the whole flight (positions, velocities, attitudes, winds, heat shield) turned about the
  vertical, so the sun azimuth relative to the flight varies; if the three footprints cannot fit in
  the strip at that heading, the nearest heading in 10 deg steps that fits is used;
* a position: the offsets for which all three image footprints (ground outlines of the image borders at
  mid-exposure) stay inside the strip form a rectangle; a point ``(u, v)`` of the unit square is mapped
  onto that rectangle.

``(u, v)`` and the heading fraction are point ``k`` of a scrambled 3-D Halton sequence
(:mod:`campaign.plan.halton`: scipy's engine's bits, seeded by the campaign seed and the class): a
low-discrepancy sequence covers the headings and the strip evenly for *every* prefix, so the plan does not
depend on the number of cases. Case ``k`` is the same whether the class has 10 or 1000 cases: a quick look
(``--cases-scale 0.1``) is the first tenth of the full run, and a later full run reuses it. Case identity is
(class, k): ``case_id = class_index *`` :data:`CASE_ID_STRIDE` ``+ k``.

A case whose footprints cannot fit at any heading is still planned (never dropped) with
``footprint_inside = False``; the simulator then renders the outside as "no texture" like the paper's
Fig. 10.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from campaign.plan.halton import scrambled_halton
from flight_interface.camera import Camera
from simulator.scene.descent_profile import DescentProfile
from simulator.scene.ground_mapping import border_pixels, camera_pose, ground_points

PLAN_STREAM = 0x504C414E  # "PLAN": the planner's SeedSequence key, apart from the cases' streams
HEADING_SEARCH_STEP_RAD = math.radians(10.0)
CASE_ID_STRIDE = 1_000_000  # case_id = class_index * CASE_ID_STRIDE + index within the class


@dataclass(frozen=True)
class ClassPlanInput:
    """What the planner needs of one appearance class."""

    class_name: str
    class_index: int
    ellipse_fraction: float
    cases: int
    terrain_name: str
    terrain_extent_m: tuple[float, float, float, float]   # west, east, south, north
    margin_m: float = 6.0                                   # keep bilinear support inside the strip


def footprint_outlines(camera: Camera, profile: DescentProfile, per_side: int = 8) -> list[np.ndarray | None]:
    """Ground outline of each image of ``profile`` at mid-exposure: a closed polygon (4 * per_side, 2)
    of (east, north) points, or None for an image whose border rays miss the ground (sky in view)."""
    border = border_pixels(camera, per_side)
    outlines = []
    for start in profile.image_times_s:
        pose = profile.pose(camera.timing.exposure_mid_time_s(float(start)))
        points, hit = ground_points(camera, camera_pose(camera, pose), border)
        outlines.append(points[:, :2] if np.all(hit) else None)
    return outlines


def footprint_points_m(camera: Camera, profile: DescentProfile, per_side: int = 8) -> np.ndarray | None:
    """All images' outline points stacked, (K * 4 * per_side, 2); None when any image sees sky."""
    outlines = footprint_outlines(camera, profile, per_side)
    seen = [outline for outline in outlines if outline is not None]
    return np.concatenate(seen) if len(seen) == len(outlines) else None


def _turn(points_en: np.ndarray, heading_rad: float) -> np.ndarray:
    cos_h, sin_h = math.cos(heading_rad), math.sin(heading_rad)
    return points_en @ np.array([[cos_h, sin_h], [-sin_h, cos_h]])


def even_points(count: int, seed_sequence: np.random.SeedSequence) -> np.ndarray:
    """The first ``count`` points of a scrambled 3-D Halton sequence in [0, 1)^3, shape (count, 3).

    Prefix-stable: ``even_points(n)`` is the first ``n`` rows of ``even_points(N)`` for ``n <= N``, and
    every prefix is low-discrepancy (its points fill the unit cube evenly, with no clusters)."""
    return scrambled_halton(count, 3, seed_sequence)


def case_id_of(class_index: int, case_in_class: int) -> int:
    """The case id of case ``case_in_class`` of class ``class_index`` (stable whatever the case counts)."""
    if not 0 <= case_in_class < CASE_ID_STRIDE:
        raise ValueError(f"case index {case_in_class} outside [0, {CASE_ID_STRIDE})")
    return class_index * CASE_ID_STRIDE + case_in_class


def plan_class(camera: Camera, profiles: list[DescentProfile], spec: ClassPlanInput, seed: int) -> pd.DataFrame:
    """Plan the cases of one class. Returns one row per case (see :data:`PLAN_COLUMNS`); the first ``n``
    rows do not depend on ``spec.cases`` (see the module docstring).

    Vectorised over the cases of each trajectory (:func:`place_many`): 10^6 cases, the documented
    maximum of a class, plan in seconds and a few hundred MB (columns, never one record per case)."""
    streams = np.random.SeedSequence([seed, spec.class_index, PLAN_STREAM]).spawn(2)
    count = spec.cases
    order = np.random.default_rng(streams[0]).permutation(len(profiles))
    points = even_points(count, streams[1])
    unit = points[:, :2]                       # Halton bases 2 and 3: the strip's (u, v)
    headings = 2.0 * math.pi * points[:, 2]    # base 5
    profile_index = order[np.arange(count) % len(profiles)] if count else np.zeros(0, dtype=np.int64)
    heading_rad = np.empty(count)
    offset_m = np.empty((count, 2))
    inside = np.zeros(count, dtype=bool)
    for index in np.unique(profile_index):
        members = np.flatnonzero(profile_index == index)
        outline = footprint_points_m(camera, profiles[int(index)])
        heading_rad[members], offset_m[members], inside[members] = place_many(outline, headings[members],
                                                                              unit[members], spec)
    names = np.array([profile.name for profile in profiles], dtype=object)
    columns = {
        "case_id": spec.class_index * CASE_ID_STRIDE + np.arange(count, dtype=np.int64),
        "class_name": np.full(count, spec.class_name, dtype=object), "class_index": np.full(count, spec.class_index),
        "case_in_class": np.arange(count, dtype=np.int64), "ellipse_fraction": np.full(count, spec.ellipse_fraction),
        "terrain_name": np.full(count, spec.terrain_name, dtype=object),
        "profile_index": profile_index.astype(np.int64), "profile_name": names[profile_index],
        "heading_rad": heading_rad, "offset_east_m": offset_m[:, 0], "offset_north_m": offset_m[:, 1],
        "footprint_inside": inside,
    }
    if count:
        case_id_of(spec.class_index, count - 1)            # the largest index must fit the id stride
    return pd.DataFrame(columns, columns=PLAN_COLUMNS)


PLAN_COLUMNS = ["case_id", "class_name", "class_index", "case_in_class", "ellipse_fraction", "terrain_name",
                "profile_index", "profile_name", "heading_rad", "offset_east_m", "offset_north_m",
                "footprint_inside"]


PLACE_CHUNK = 8192   # cases per vectorised block: (chunk, outline points) arrays of about 6 MB
OVERFLOW_TIE_M = 1e-6  # overflows closer than this are a tie (a heading and its opposite give the same box)


def _turned_bounds(outline: np.ndarray, heading_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding boxes of ``outline`` (P, 2) turned by each heading (as :func:`_turn`): low and high
    corners, each (n, 2)."""
    cos_h, sin_h = np.cos(heading_rad)[:, None], np.sin(heading_rad)[:, None]
    east = outline[None, :, 0] * cos_h - outline[None, :, 1] * sin_h
    north = outline[None, :, 0] * sin_h + outline[None, :, 1] * cos_h
    return (np.stack([east.min(axis=1), north.min(axis=1)], axis=1),
            np.stack([east.max(axis=1), north.max(axis=1)], axis=1))


def place_many(outline: np.ndarray | None, headings: np.ndarray, units: np.ndarray,
               spec: ClassPlanInput) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Place many cases of one trajectory (vectorised over the cases, in blocks).

    Each case tries headings in the order wanted, +10, -10, +20, -20, ... 180 deg; the first at which the
    footprints fit the strip (margins included) is kept and the case's unit point is mapped onto the
    rectangle of feasible offsets there. A case that fits at no heading keeps the least overflowing one
    (ties within :data:`OVERFLOW_TIE_M`: the earlier in that order), offset to the middle of the feasible
    range on each axis, and is flagged ``inside = False``; an outline that sees sky places the nadir
    point evenly over the strip, flagged.

    Parameters
    ----------
    outline : (P, 2) array or None
        The trajectory's footprint points (m, east/north), None when an image sees sky.
    headings : (n,) array
        Wanted headings (rad).
    units : (n, 2) array
        Points of the unit square mapped onto each case's feasible offsets.

    Returns
    -------
    heading_rad (n,), offset_m (n, 2), inside (n,) bool
        Heading (rad), offset of the trajectory (m, east/north) and whether every footprint is inside.
    """
    west, east, south, north = spec.terrain_extent_m
    count = len(headings)
    if outline is None:     # sky in view: place the nadir point evenly, flag it
        offsets = np.column_stack([west + units[:, 0] * (east - west), south + units[:, 1] * (north - south)])
        return np.asarray(headings, dtype=float).copy(), offsets, np.zeros(count, dtype=bool)
    heading_out, offset_out, inside = np.empty(count), np.empty((count, 2)), np.zeros(count, dtype=bool)
    for start in range(0, count, PLACE_CHUNK):
        block = slice(start, min(start + PLACE_CHUNK, count))
        heading_out[block], offset_out[block], inside[block] = _place_block(outline, headings[block], units[block],
                                                                            spec)
    return heading_out, offset_out, inside


def _place_block(outline: np.ndarray, headings: np.ndarray, units: np.ndarray, spec: ClassPlanInput):
    west, east, south, north = spec.terrain_extent_m
    corner_low = np.array([west + spec.margin_m, south + spec.margin_m])
    corner_high = np.array([east - spec.margin_m, north - spec.margin_m])
    count = len(headings)
    heading_out, offset_out = np.empty(count), np.empty((count, 2))
    best_overflow = np.full(count, np.inf)
    best_heading, best_low, best_high = headings.astype(float), np.full((count, 2), np.nan), np.full((count, 2), np.nan)
    pending = np.arange(count)
    inside = np.zeros(count, dtype=bool)
    steps = int(math.ceil(math.pi / HEADING_SEARCH_STEP_RAD))
    for step in range(steps + 1):
        for sign in ((1,) if step in (0, steps) else (1, -1)):
            if pending.size == 0:
                break
            candidate = np.mod(headings[pending] + sign * step * HEADING_SEARCH_STEP_RAD, 2.0 * math.pi)
            points_low, points_high = _turned_bounds(outline, candidate)
            low, high = corner_low - points_low, corner_high - points_high
            fits = np.all(high >= low, axis=1)
            placed = pending[fits]
            heading_out[placed] = candidate[fits]
            offset_out[placed] = low[fits] + units[placed] * (high[fits] - low[fits])
            inside[placed] = True
            overflow = np.sum(np.maximum(low - high, 0.0), axis=1)
            better = ~fits & (overflow < best_overflow[pending] - OVERFLOW_TIE_M)
            chosen = pending[better]
            best_overflow[chosen], best_heading[chosen] = overflow[better], candidate[better]
            best_low[chosen], best_high[chosen] = low[better], high[better]
            pending = pending[~fits]
    if pending.size:        # fits at no heading: the least overflowing one, flagged
        low, high = best_low[pending], best_high[pending]
        offset = np.where(high >= low, low + units[pending] * (high - low), 0.5 * (low + high))
        finite = np.all(np.isfinite(offset), axis=1)
        centre = np.array([(west + east) / 2.0, (south + north) / 2.0])
        heading_out[pending] = best_heading[pending]
        offset_out[pending] = np.where(finite[:, None], offset, centre)
    return heading_out, offset_out, inside
