"""``python -m campaign.realism.measure_terrains SOURCE... [--csv FILE] [--site SITE.toml]``: measure terrains.

A SOURCE is

* a site TOML (``sitedata/gusev.toml``): every appearance class, with the site's camera and sun;
* a synthetic preset name (``gcp``): the class strip of the shipped site file that uses it (its seed
  and overrides, camera and sun);
* an image file, optionally with a side-car: ``FILE`` or ``FILE:SIDECAR.toml`` (readers of
  :mod:`file_formats.planetary`); measured with the camera and sun of ``--site`` (default Gusev).

The table (one row per terrain, :class:`campaign.realism.terrain_stats.TerrainStatistics`) is printed on
stdout; it is written as CSV only when asked (``--csv FILE``): the command writes no file of its own
accord (synthetic strips go to the terrain cache, ``$MOC2DIMES_CACHE``). Bad input: one line naming the
source and what is wrong, exit code 2, nothing written.
"""
from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import ndimage

from campaign.configuration.paths import check_path_text
from campaign.realism.terrain_stats import (
    TerrainStatistics,
    descent_sampling,
    nadir_photometric_ratio,
    terrain_statistics,
)
from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from config_tables.toml_file import load_toml
from dimes_velocity.config import EstimatorConfig, estimator_config_from_data
from file_formats.planetary import load_orbital_image
from flight_interface.camera import load_camera
from sitedata import SITEDATA_DIR
from sitedata.sites import Site, load_class_terrain, load_site
from sitedata.terrain.synthetic_classes import CLASS_PRESETS

SITEDATA = SITEDATA_DIR
SHIPPED_SITES = (SITEDATA / "gusev.toml", SITEDATA / "meridiani.toml")
DEFAULT_SITE = SHIPPED_SITES[0]


def _estimator_config(site_path: Path) -> EstimatorConfig:
    """The site file's ``[estimator]`` table (defaults without one)."""
    data = load_toml(site_path)
    return estimator_config_from_data(data["estimator"], str(site_path)) if "estimator" in data else EstimatorConfig()


def _sampling(site: Site, site_path: Path, terrain=None):
    """The descent sampling of a site's camera and sun (photometric ratio from the terrain's MOC angles)."""
    ratio = 1.0
    if terrain is not None:
        ratio = nadir_photometric_ratio(site.sun_elevation_rad, terrain.moc_incidence_rad,
                                        terrain.moc_emission_rad, terrain.moc_phase_rad)
    return descent_sampling(load_camera(site.camera_path), site.heliocentric_distance_au,
                            _estimator_config(site_path), photometric_ratio=ratio)


def measure_site(site_path: Path, only_preset: str | None = None, cache: bool = True) -> list[tuple[str, TerrainStatistics]]:
    """Statistics of every class of a site (or only the classes built from ``only_preset``)."""
    site = load_site(site_path)
    rows = []
    for entry in site.classes:
        if only_preset is not None and (entry.terrain.kind != "synthetic" or entry.terrain.preset != only_preset):
            continue
        terrain = load_class_terrain(entry.terrain, cache=cache)
        stats = terrain_statistics(terrain.reflectance_if, terrain.metres_per_pixel, _sampling(site, site_path, terrain))
        rows.append((f"{site.name}:{entry.name} ({terrain.name})", stats))
    return rows


def measure_file(spec: str, site_path: Path) -> tuple[str, TerrainStatistics]:
    """Statistics of ``FILE`` or ``FILE:SIDECAR.toml`` with the camera and sun of ``site_path``."""

    path, sidecar = spec, None
    if ":" in spec and spec.rsplit(":", 1)[1].lower().endswith(".toml"):
        path, sidecar = spec.rsplit(":", 1)
    image = load_orbital_image(path, sidecar)
    pixels = image.pixels.astype(np.float64)
    if not image.valid.all():
        nearest = ndimage.distance_transform_edt(~image.valid, return_distances=False, return_indices=True)
        pixels = pixels[tuple(nearest)]
    if image.dn_to_if_scale is not None:
        pixels = pixels * image.dn_to_if_scale + (image.dn_to_if_offset or 0.0)
        radiometry = "I/F"
    else:
        radiometry = f"uncalibrated {image.file_format}"
    site = load_site(site_path)
    ratio = 1.0
    angles = (None if image.incidence_rad is None or image.emission_rad is None or image.phase_rad is None
              else (image.incidence_rad, image.emission_rad, image.phase_rad))
    if angles is not None:
        ratio = nadir_photometric_ratio(site.sun_elevation_rad, *angles)
    sampling = descent_sampling(load_camera(site.camera_path), site.heliocentric_distance_au,
                                _estimator_config(site_path), photometric_ratio=ratio)
    stats = terrain_statistics(pixels, image.metres_per_pixel, sampling, radiometry)
    if radiometry == "I/F" and angles is None:
        stats = dataclasses.replace(stats, notes="; ".join(filter(None, [
            stats.notes, "orbital photometric angles unknown: descent/orbital I/F ratio taken as 1 for the noise"])))
    name = Path(path).name + (f" + {Path(sidecar).name}" if sidecar else "")
    return name, stats


def measure(source: str, site_path: Path, cache: bool = True) -> list[tuple[str, TerrainStatistics]]:
    """Dispatch one SOURCE (site TOML, preset name, or image file) to its measurement."""
    if source in CLASS_PRESETS:
        for shipped in SHIPPED_SITES:
            rows = measure_site(shipped, only_preset=source, cache=cache)
            if rows:
                return rows
        raise ConfigError(f"{source}: no shipped site file uses this preset")
    image_part = source
    if ":" in source and source.rsplit(":", 1)[1].lower().endswith(".toml"):
        image_part = source.rsplit(":", 1)[0]
    elif source.lower().endswith(".toml"):
        if not Path(source).is_file():
            raise ConfigError(f"{source}: no such site file")
        return measure_site(Path(source), cache=cache)
    if not Path(image_part).is_file():
        raise ConfigError(f"{source}: no such file, and not a synthetic preset; presets: {', '.join(CLASS_PRESETS)}")
    return [measure_file(source, site_path)]


COLUMNS = ("source",) + tuple(field.name for field in dataclasses.fields(TerrainStatistics))


def to_frame(rows: list[tuple[str, TerrainStatistics]]) -> pd.DataFrame:
    return pd.DataFrame([{"source": name, **dataclasses.asdict(stats)} for name, stats in rows], columns=COLUMNS)


def format_table(frame: pd.DataFrame) -> str:
    """Fixed-width text table (NaN as "-"); notes listed below it."""
    def num(value, fmt):
        return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, fmt)

    header = (f"{'source':44s} {'size':>16s} {'mean I/F':>8s} {'contrast 1 km [p10-p90]':>24s} "
              f"{'contrast 2 km [p10-p90]':>24s} {'PSD slope':>9s} {'untrk 1km':>9s} {'untrk 2km':>9s} {'craters/km2':>11s}")
    lines = [header, "-" * len(header)]
    notes = []
    for row in frame.itertuples(index=False):
        size = f"{row.cols}x{row.rows}@{num(row.metres_per_pixel, '.2f')}m"
        c1 = f"{num(row.contrast_1km, '.3f')} [{num(row.contrast_1km_p10, '.3f')}-{num(row.contrast_1km_p90, '.3f')}]"
        c2 = f"{num(row.contrast_2km, '.3f')} [{num(row.contrast_2km_p10, '.3f')}-{num(row.contrast_2km_p90, '.3f')}]"
        lines.append(f"{row.source[:44]:44s} {size:>16s} {num(row.mean_if, '.4f'):>8s} {c1:>24s} {c2:>24s} "
                     f"{num(row.psd_slope, '.2f'):>9s} {num(row.untrackable_1km, '.3f'):>9s} "
                     f"{num(row.untrackable_2km, '.3f'):>9s} {num(row.crater_density_per_km2, '.1f'):>11s}")
        if row.notes:
            notes.append(f"  {row.source}: {row.notes}")
    return "\n".join(lines + (["notes:"] + notes if notes else []))


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m campaign.realism.measure_terrains", description=__doc__.splitlines()[0])
    parser.add_argument("sources", nargs="+", metavar="SOURCE", help="site TOML, preset name, or FILE[:SIDECAR.toml]")
    parser.add_argument("--csv", help="also write the table as CSV to this file (default: print only)")
    parser.add_argument("--site", default=str(DEFAULT_SITE), help="site TOML whose camera and sun measure image files")
    parser.add_argument("--no-cache", action="store_true", help="regenerate synthetic terrain without the disk cache")
    args = parser.parse_args(argv)
    if args.csv is not None:
        try:
            check_path_text(args.csv, "--csv")
        except ConfigError as exc:
            print(f"{parser.prog}: error: {exc}", file=sys.stderr)
            return USAGE_ERROR
    rows = []
    try:
        for source in args.sources:
            rows.extend(measure(source, Path(args.site), cache=not args.no_cache))
    except (ConfigError, ValueError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    frame = to_frame(rows)
    print(format_table(frame))
    if args.csv is None:
        return 0
    try:
        frame.to_csv(args.csv, index=False)
    except OSError as exc:
        print(f"{parser.prog}: error: --csv {args.csv}: cannot be written ({exc.strerror or exc})", file=sys.stderr)
        return USAGE_ERROR
    print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
