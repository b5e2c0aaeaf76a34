"""PNG views of every appearance-class terrain of a site, for people to look at.

:func:`write_site_mosaics` (command line: :mod:`sitedata.terrain.write_mosaics`) writes, per class,
``<site>_<class>.png`` (left: the whole strip reduced 4x; right: a full-resolution detail; each stretched
linearly between its 0.5 and 99.5 percentile I/F, with a 1 km scale bar) and ``<site>_mosaic.png`` (all
classes' strips side by side on one common I/F stretch, so that their brightness and contrast compare
directly), and returns mean I/F and RMS contrast per class.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sitedata.sites import load_class_terrain, load_site

OVERVIEW_REDUCTION = 4
DETAIL_ROWS = 1000


def to_uint8(reflectance_if: np.ndarray, low_if: float, high_if: float) -> np.ndarray:
    """Linear stretch of I/F between ``low_if`` and ``high_if`` to 0..255."""
    scale = 255.0 / max(high_if - low_if, 1e-9)
    return np.clip((reflectance_if - low_if) * scale, 0, 255).astype(np.uint8)


def _label(image: np.ndarray, lines: list[str]) -> np.ndarray:
    header = np.full((22 * len(lines) + 8, image.shape[1]), 255, np.uint8)
    for i, line in enumerate(lines):
        cv2.putText(header, line, (6, 20 + 22 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.55, 0, 1, cv2.LINE_AA)
    return np.vstack([header, image])


def _scale_bar(image: np.ndarray, metres_per_pixel: float, reduction: int = 1) -> np.ndarray:
    length = int(round(1000.0 / (metres_per_pixel * reduction)))
    out = image.copy()
    if length + 20 < out.shape[1]:
        y = out.shape[0] - 14
        cv2.rectangle(out, (10, y - 4), (10 + length, y + 4), 255, -1)
        cv2.rectangle(out, (10, y - 4), (10 + length, y + 4), 0, 1)
        cv2.putText(out, "1 km", (14 + length, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 255, 1, cv2.LINE_AA)
    return out


def _reduce(image: np.ndarray, reduction: int) -> np.ndarray:
    rows, cols = image.shape
    return cv2.resize(image, (max(1, cols // reduction), max(1, rows // reduction)), interpolation=cv2.INTER_AREA)


def class_view(reflectance_if: np.ndarray, metres_per_pixel: float, title: str) -> np.ndarray:
    """Overview (whole strip, reduced) beside a full-resolution detail, uint8 with a title."""
    low, high = np.percentile(reflectance_if, [0.5, 99.5])
    overview = _scale_bar(to_uint8(_reduce(reflectance_if, OVERVIEW_REDUCTION), low, high),
                          metres_per_pixel, OVERVIEW_REDUCTION)
    start = max(0, reflectance_if.shape[0] // 2 - DETAIL_ROWS // 2)
    detail = _scale_bar(to_uint8(reflectance_if[start:start + DETAIL_ROWS], low, high), metres_per_pixel)
    height = max(overview.shape[0], detail.shape[0])
    def pad(im):
        return np.pad(im, ((0, height - im.shape[0]), (0, 10)), constant_values=255)
    return _label(np.hstack([pad(overview), pad(detail)]),
                  [title, f"left: whole strip (1/{OVERVIEW_REDUCTION}); right: full-resolution detail "
                          f"(rows {start}-{start + DETAIL_ROWS}); I/F {low:.3f}-{high:.3f}"])


def write_site_mosaics(site_path: str | Path, out_dir: str | Path, cache: bool = True) -> list[dict]:
    """Write the PNGs of every class of a site; return per-class statistics (mean I/F, RMS contrast)."""
    site = load_site(site_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = site.name.lower().replace(" ", "_")
    terrains, rows = [], []
    for site_class in site.classes:
        terrain = load_class_terrain(site_class.terrain, cache=cache)
        image = terrain.reflectance_if
        mean_if = float(image.mean())
        stats = {"class": site_class.name, "mean_if": mean_if, "rms_contrast": float(image.std()) / mean_if,
                 "rows": image.shape[0], "cols": image.shape[1], "metres_per_pixel": terrain.metres_per_pixel}
        title = (f"{site.name} {site_class.name} ({terrain.name}): {image.shape[1]} x {image.shape[0]} px at "
                 f"{terrain.metres_per_pixel:g} m, mean I/F {mean_if:.3f}, RMS contrast {stats['rms_contrast']:.3f}")
        path = out_dir / f"{stem}_{site_class.name}.png"
        cv2.imwrite(str(path), class_view(image, terrain.metres_per_pixel, title))
        stats["png"] = str(path)
        terrains.append((site_class.name, terrain))
        rows.append(stats)
    low, high = np.percentile(np.concatenate([t.reflectance_if[::7, ::7].ravel() for _, t in terrains]), [0.5, 99.5])
    strips = []
    for name, terrain in terrains:
        strip = _scale_bar(to_uint8(_reduce(terrain.reflectance_if, OVERVIEW_REDUCTION), low, high),
                           terrain.metres_per_pixel, OVERVIEW_REDUCTION)
        strips.append(_label(strip, [name]))
    height = max(s.shape[0] for s in strips)
    mosaic = np.hstack([np.pad(s, ((0, height - s.shape[0]), (0, 12)), constant_values=255) for s in strips])
    mosaic = _label(mosaic, [f"{site.name}: all classes, common stretch I/F {low:.3f}-{high:.3f}"])
    cv2.imwrite(str(out_dir / f"{stem}_mosaic.png"), mosaic)
    return rows


if __name__ == "__main__":          # the old path of `python -m sitedata.terrain.write_mosaics`
    import runpy

    runpy.run_module("sitedata.terrain.write_mosaics", run_name="__main__", alter_sys=True)
