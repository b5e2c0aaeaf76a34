"""Where a class's cases look: a 2-D histogram of footprint centres over the terrain strip.

The footprint map (paper Fig. 5) draws the outlines of the first cases only; with up to 10^6 cases in a
class (the documented maximum) drawing, or even building, every placed trajectory would take minutes and
gigabytes. The coverage of *all* cases is shown instead as a density: each case's footprint centre (the
mean of its three images' ground outline points, :func:`campaign.plan.placement.footprint_points_m`)
turned by its heading and moved by its offset, exactly as the case's trajectory is placed, binned on the
strip. One ground projection per trajectory of the set, then array arithmetic per case: 10^6 cases in
about a second and tens of MB.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from campaign.plan.placement import footprint_points_m
from flight_interface.camera import Camera
from simulator.scene.descent_profile import DescentProfile

DENSITY_BINS_ACROSS = 48   # histogram bins along the strip's shorter side (the longer side keeps square bins)


@dataclass(frozen=True)
class FootprintDensity:
    """Footprint centres of a class's cases binned on its terrain strip.

    Attributes
    ----------
    counts : (rows, cols) int array
        Cases whose footprint centre falls in each bin; row 0 is the northern edge (image order).
    extent_m : (west, east, south, north)
        The strip (m) the bins cover.
    cases : int
        Cases planned (also those whose centre is off the strip or that see sky, which are not binned).
    """

    counts: np.ndarray
    extent_m: tuple[float, float, float, float]
    cases: int

    @property
    def binned(self) -> int:
        return int(self.counts.sum())


def footprint_centres_m(camera: Camera, profiles: list[DescentProfile], plan: pd.DataFrame) -> np.ndarray:
    """Each planned case's footprint centre on the ground (m, east/north), shape (cases, 2); NaN for a
    case whose trajectory sees sky (no footprint).

    ``plan`` needs the columns ``profile_index``, ``heading_rad``, ``offset_east_m`` and ``offset_north_m``."""
    index = plan["profile_index"].to_numpy(dtype=np.int64)
    local = np.full((len(profiles), 2), np.nan)
    for used in np.unique(index):
        points = footprint_points_m(camera, profiles[int(used)])
        if points is not None:
            local[used] = points.mean(axis=0)
    heading = plan["heading_rad"].to_numpy(dtype=float)
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    east, north = local[index, 0], local[index, 1]
    return np.column_stack([east * cos_h - north * sin_h + plan["offset_east_m"].to_numpy(dtype=float),
                            east * sin_h + north * cos_h + plan["offset_north_m"].to_numpy(dtype=float)])


def footprint_density(camera: Camera, profiles: list[DescentProfile], plan: pd.DataFrame,
                      extent_m: tuple[float, float, float, float],
                      bins_across: int = DENSITY_BINS_ACROSS) -> FootprintDensity:
    """The 2-D histogram of :func:`footprint_centres_m` over the strip ``extent_m`` (west, east, south,
    north; m), with square bins, ``bins_across`` along the shorter side."""
    west, east, south, north = (float(value) for value in extent_m)
    width, height = max(east - west, 1e-9), max(north - south, 1e-9)
    size = min(width, height) / bins_across
    cols, rows = max(1, int(round(width / size))), max(1, int(round(height / size)))
    centres = footprint_centres_m(camera, profiles, plan)
    finite = np.all(np.isfinite(centres), axis=1)
    counts, _, _ = np.histogram2d(centres[finite, 1], centres[finite, 0], bins=(rows, cols),
                                  range=((south, north), (west, east)))
    return FootprintDensity(counts=counts[::-1].astype(np.int64), extent_m=(west, east, south, north),
                            cases=len(plan))
