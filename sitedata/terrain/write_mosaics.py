"""Write PNG views of every appearance-class terrain of a site, for people to look at.

    python -m sitedata.terrain.write_mosaics --site sitedata/gusev.toml --out mosaics/ [--no-cache]

writes, per class, ``<site>_<class>.png`` (left: the whole strip reduced 4x; right: a full-resolution
detail; each stretched linearly between its 0.5 and 99.5 percentile I/F, with a 1 km scale bar) and
``<site>_mosaic.png`` (all classes' strips side by side on one common I/F stretch), and prints mean I/F
and RMS contrast per class (:func:`sitedata.terrain.mosaic.write_site_mosaics`). ``python -m
sitedata.terrain.mosaic`` runs the same.
"""
from __future__ import annotations

import sys

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from sitedata.terrain.mosaic import write_site_mosaics


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m sitedata.terrain.write_mosaics", description=__doc__.split("\n\n")[0])
    parser.add_argument("--site", required=True, action="append", help="site TOML (repeatable)")
    parser.add_argument("--out", required=True, help="output directory for the PNGs")
    parser.add_argument("--no-cache", action="store_true", help="regenerate synthetic terrain without the disk cache")
    args = parser.parse_args(argv)
    try:
        for site_path in args.site:
            for row in write_site_mosaics(site_path, args.out, cache=not args.no_cache):
                print(f"{row['class']:>14s}  {row['cols']} x {row['rows']} px at {row['metres_per_pixel']:g} m  "
                      f"mean I/F {row['mean_if']:.4f}  RMS contrast {row['rms_contrast']:.4f}  -> {row['png']}")
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    return 0


if __name__ == "__main__":
    sys.exit(main())
