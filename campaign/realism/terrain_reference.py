"""Real-Mars reference ranges the synthetic appearance classes are calibrated to.

The real images are the MOC NA products in ``../shared/realdata/moc_na`` (NASA/JPL/MSSS):

* ``E0201461.tiny.cub``: radiometrically calibrated I/F (ISIS3, 4.676 m/pixel), Galaxias Fluctus flow
  surface with ridges and a scarp;
* ``M0100115_decompressed.img``: raw 8-bit DN at ~4.5 m/pixel, turned into I/F by the side-car
  ``sitedata/examples/M0100115.sidecar.toml`` (proportional scale, dark offset taken as 0, so its
  contrast is a lower bound; no flat field, so faint column stripes add a little). Windows of it were
  chosen by eye for their kind of ground (rows, cols below).

The MER landing-site MOC images themselves are not available here, and no per-class published MOC
contrast statistics for the Gusev or Meridiani plains were found to cite (the landing-site papers,
e.g. Golombek et al. 2003 JGR 108(E12) 8072 and Kirk et al. 2003 JGR 108(E12) 8088, give albedo,
slopes and haze-calibrated photoclinometry, not image contrast at a descent camera's sample). So each
class is calibrated to the real ground of its *kind* (smooth plains, textured/cratered plains, knobby
terrain) in these images, measured with :func:`campaign.realism.terrain_stats.terrain_statistics` at the
MER-A descent camera's sample at 1 and 2 km.

CTX tiles (``ctx_tiles/``) are stretched for display: a stretch sets std/mean and the dark-feature
depth, so only their PSD slope is used (the slope range below covers MOC and CTX).

:data:`RECORDED_RANGES` are the numbers measured by :func:`measure_reference_ranges` (rounded outward
to 3 decimals / 1 feature per km^2); CI has no real data, so tests check the classes against these
recorded numbers, and a test with the real data re-measures them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from campaign.realism.terrain_stats import (
    ALTITUDES_M,
    DescentSampling,
    crater_density_per_km2,
    psd_slope,
    resample_to_ground_sample,
    tile_contrasts,
)
from file_formats.planetary import load_orbital_image, read_image
from file_formats.planetary.image import fail
from file_formats.planetary.sidecar import refuse_unknown
from sitedata import SITEDATA_DIR

SITEDATA = SITEDATA_DIR
DEFAULT_REALDATA = SITEDATA.parent.parent / "shared" / "realdata"


@dataclass(frozen=True)
class ReferenceRegion:
    """A window of a real image showing one kind of ground (rows/cols: half-open pixel ranges)."""

    kind: str
    path: str                       # relative to the realdata folder
    sidecar: str | None             # relative to sitedata/
    rows: tuple[int, int] | None
    cols: tuple[int, int] | None
    description: str


_M01 = ("moc_na/M0100115_decompressed.img", "examples/M0100115.sidecar.toml")
REFERENCE_REGIONS = (
    ReferenceRegion("smooth_plains", *_M01, (3080, 3520), None, "M01/00115: smooth plains, few small craters"),
    ReferenceRegion("smooth_plains", *_M01, (4250, 4864), (300, 672), "M01/00115: smooth plains east of the lobe"),
    ReferenceRegion("textured_plains", *_M01, (3500, 4250), (336, 672), "M01/00115: plains with subdued ridges, small craters"),
    ReferenceRegion("textured_plains", "moc_na/E0201461.tiny.cub", None, None, None,
                    "E02/01461 (I/F): flow surface, ridges, a scarp"),
    ReferenceRegion("knobby", *_M01, (0, 1050), None, "M01/00115: knobs and mesas on plains"),
)

#: Kind of ground of each appearance class (paper Figs. 7 and 9). heb, an ejecta apron of hummocks,
#: rays and secondaries, is held to textured plains (the real images have no ejecta blanket in I/F).
KIND_OF_CLASS = {"gcp": "smooth_plains", "hbsp": "smooth_plains", "gdcp": "textured_plains",
                 "hdcp": "textured_plains", "heb": "textured_plains", "gkep": "knobby"}

#: Measured by measure_reference_ranges() on ../shared/realdata with the MER-A camera (Gusev sun):
#: footprint-tile contrast (std/mean, 256 x 256 samples at 1 and 2 km, all tiles of the kind's windows,
#: min..max), dark-feature density (30-120 m, >= 5 % deep, per km^2, over 1.67 km windows, min..max),
#: and the 4-64 px PSD slope over every real MOC and CTX image (min..max).
RECORDED_RANGES = {
    "smooth_plains": {"contrast": (0.021, 0.061), "crater_density_per_km2": (3.0, 25.0)},
    "textured_plains": {"contrast": (0.029, 0.119), "crater_density_per_km2": (24.0, 64.0)},
    "knobby": {"contrast": (0.039, 0.333), "crater_density_per_km2": (76.0, 195.0)},
}
RECORDED_PSD_SLOPE_RANGE = (-2.55, -1.42)


def load_region(region: ReferenceRegion, realdata: Path = DEFAULT_REALDATA) -> tuple[np.ndarray, float]:
    """The region's I/F pixels (float32) and metres per pixel."""

    sidecar = SITEDATA / region.sidecar if region.sidecar else None
    image = load_orbital_image(Path(realdata) / region.path, sidecar)
    hint = "the side-car of the region in REFERENCE_REGIONS"
    if image.dn_to_if_scale is None:
        refuse_unknown(image, "the DN-to-I/F calibration", "dn_to_if_scale", hint)
    if image.metres_per_pixel is None:
        refuse_unknown(image, "metres per pixel", "metres_per_pixel", hint)
    pixels = image.pixels * np.float32(image.dn_to_if_scale) + np.float32(image.dn_to_if_offset or 0.0)
    rows = slice(*region.rows) if region.rows else slice(None)
    cols = slice(*region.cols) if region.cols else slice(None)
    return pixels[rows, cols], float(image.metres_per_pixel)


def _read_grey_image(path: Path) -> np.ndarray:
    """An 8-bit greyscale image file as float32 (ReaderError if unreadable)."""
    pixels = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if pixels is None:
        raise fail(path, "cannot be read as an image")
    return pixels.astype(np.float32)


def window_crater_densities(image: np.ndarray, metres_per_pixel: float, window_m: float) -> np.ndarray:
    """Dark-feature density of every ``window_m`` square window (half-window steps; whole image if smaller)."""
    size = int(round(window_m / metres_per_pixel))
    rows, cols = image.shape
    if rows < size or cols < size:
        return np.array([crater_density_per_km2(image, metres_per_pixel)])
    step = size // 2
    return np.array([crater_density_per_km2(image[r:r + size, c:c + size], metres_per_pixel)
                     for r in range(0, rows - size + 1, step) for c in range(0, cols - size + 1, step)])


def measure_reference_ranges(sampling: DescentSampling, realdata: Path = DEFAULT_REALDATA) -> dict:
    """Contrast and dark-feature ranges per kind of ground, measured on the real windows (see module doc)."""
    values: dict[str, dict[str, list[float]]] = {}
    for region in REFERENCE_REGIONS:
        image, mpp = load_region(region, realdata)
        entry = values.setdefault(region.kind, {"contrast": [], "crater_density_per_km2": []})
        for altitude in ALTITUDES_M:
            samples = resample_to_ground_sample(image, mpp, sampling.ground_sample_m(altitude), sampling.binning)
            entry["contrast"].extend(tile_contrasts(samples).tolist())
        footprint_m = 256 * sampling.ground_sample_m(max(ALTITUDES_M))
        entry["crater_density_per_km2"].extend(window_crater_densities(image, mpp, footprint_m).tolist())
    return {kind: {key: (float(min(v)), float(max(v))) for key, v in entry.items()} for kind, entry in values.items()}


def measure_psd_slope_range(realdata: Path = DEFAULT_REALDATA) -> tuple[float, float]:
    """Min and max 4-64 px PSD slope over every real MOC NA image and CTX tile (raw pixels)."""
    realdata = Path(realdata)
    slopes = [psd_slope(read_image(realdata / "moc_na" / name).pixels)
              for name in ("E0201461.tiny.cub", "M0100115_decompressed.img", "M12.VIC")]
    slopes += [psd_slope(_read_grey_image(tile))
               for tile in sorted((realdata / "ctx_tiles").glob("MC11E-*.png"))]
    return float(min(slopes)), float(max(slopes))
