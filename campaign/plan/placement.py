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

``(u, v)`` and the heading fraction are point ``k`` of a scrambled 3-D Halton sequence (seeded by the
campaign seed and the class): a low-discrepancy sequence covers the headings and the strip evenly for
*every* prefix, so the plan does not depend on the number of cases. Case ``k`` is the same whether the
class has 10 or 1000 cases: a quick look (``--cases-scale 0.1``) is the first tenth of the full run,
and a later full run reuses it. Case identity is (class, k): ``case_id = class_index *``
:data:`CASE_ID_STRIDE` ``+ k``.

A case whose footprints cannot fit at any heading is still planned (never dropped) with
``footprint_inside = False``; the simulator then renders the outside as "no texture" like the paper's
Fig. 10.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import qmc

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
    return None if any(outline is None for outline in outlines) else np.concatenate(outlines)


def _turn(points_en: np.ndarray, heading_rad: float) -> np.ndarray:
    cos_h, sin_h = math.cos(heading_rad), math.sin(heading_rad)
    return points_en @ np.array([[cos_h, sin_h], [-sin_h, cos_h]])


def _feasible_offsets(points_en: np.ndarray, extent_m, margin_m: float):
    west, east, south, north = extent_m
    low = np.array([west + margin_m - points_en[:, 0].min(), south + margin_m - points_en[:, 1].min()])
    high = np.array([east - margin_m - points_en[:, 0].max(), north - margin_m - points_en[:, 1].max()])
    return low, high


def even_points(count: int, seed_sequence: np.random.SeedSequence) -> np.ndarray:
    """The first ``count`` points of a scrambled 3-D Halton sequence in [0, 1)^3, shape (count, 3).

    Prefix-stable: ``even_points(n)`` is the first ``n`` rows of ``even_points(N)`` for ``n <= N``, and
    every prefix is low-discrepancy (its points fill the unit cube evenly, with no clusters)."""
    sequence = qmc.Halton(d=3, scramble=True, rng=np.random.default_rng(seed_sequence))
    return sequence.random(count) if count > 0 else np.zeros((0, 3))


def case_id_of(class_index: int, case_in_class: int) -> int:
    """The case id of case ``case_in_class`` of class ``class_index`` (stable whatever the case counts)."""
    if not 0 <= case_in_class < CASE_ID_STRIDE:
        raise ValueError(f"case index {case_in_class} outside [0, {CASE_ID_STRIDE})")
    return class_index * CASE_ID_STRIDE + case_in_class


def plan_class(camera: Camera, profiles: list[DescentProfile], spec: ClassPlanInput, seed: int) -> pd.DataFrame:
    """Plan the cases of one class. Returns one row per case (see :data:`PLAN_COLUMNS`); the first ``n``
    rows do not depend on ``spec.cases`` (see the module docstring)."""
    streams = np.random.SeedSequence([seed, spec.class_index, PLAN_STREAM]).spawn(2)
    count = spec.cases
    order = np.random.default_rng(streams[0]).permutation(len(profiles))
    points = even_points(count, streams[1])
    unit = points[:, :2]                       # Halton bases 2 and 3: the strip's (u, v)
    headings = 2.0 * math.pi * points[:, 2]    # base 5
    outline_cache: dict[int, np.ndarray | None] = {}
    rows = []
    for k in range(count):
        profile_index = int(order[k % len(profiles)])
        if profile_index not in outline_cache:
            outline_cache[profile_index] = footprint_points_m(camera, profiles[profile_index])
        outline = outline_cache[profile_index]
        heading, offset, inside = _place(outline, headings[k], unit[k], spec)
        rows.append({
            "case_id": case_id_of(spec.class_index, k), "class_name": spec.class_name,
            "class_index": spec.class_index,
            "case_in_class": k, "ellipse_fraction": spec.ellipse_fraction, "terrain_name": spec.terrain_name,
            "profile_index": profile_index, "profile_name": profiles[profile_index].name,
            "heading_rad": float(heading), "offset_east_m": float(offset[0]), "offset_north_m": float(offset[1]),
            "footprint_inside": bool(inside),
        })
    return pd.DataFrame(rows, columns=PLAN_COLUMNS)


PLAN_COLUMNS = ["case_id", "class_name", "class_index", "case_in_class", "ellipse_fraction", "terrain_name",
                "profile_index", "profile_name", "heading_rad", "offset_east_m", "offset_north_m",
                "footprint_inside"]


def _place(outline: np.ndarray | None, heading: float, unit: np.ndarray, spec: ClassPlanInput):
    west, east, south, north = spec.terrain_extent_m
    centre = np.array([(west + east) / 2.0, (south + north) / 2.0])
    if outline is None:  # sky in view: place the nadir point evenly, flag it
        return heading, np.array([west + unit[0] * (east - west), south + unit[1] * (north - south)]), False
    steps = int(math.ceil(math.pi / HEADING_SEARCH_STEP_RAD))
    best = None
    for step in range(steps + 1):
        for sign in ((1,) if step in (0, steps) else (1, -1)):
            candidate = (heading + sign * step * HEADING_SEARCH_STEP_RAD) % (2.0 * math.pi)
            low, high = _feasible_offsets(_turn(outline, candidate), spec.terrain_extent_m, spec.margin_m)
            if np.all(high >= low):
                return candidate, low + unit * (high - low), True
            overflow = float(np.sum(np.maximum(low - high, 0.0)))
            if best is None or overflow < best[0]:
                best = (overflow, candidate, low, high)
    _, candidate, low, high = best
    middle = 0.5 * (low + high)
    offset = np.where(high >= low, low + unit * (high - low), middle)
    return candidate, offset if np.all(np.isfinite(offset)) else centre, False
