"""Inspect orbital image files: ``python -m file_formats.planetary.inspect_files FILE [FILE ...] [--sidecar S.toml]``.

Prints the detected format, size, valid fraction, pixel range and what is known or missing for
use as terrain (metres per pixel, photometric angles, DN-to-I/F), so a side-car can be written.
A file that cannot be read (or a bad side-car) prints one line naming the file and the reason on
stderr; the exit status is then 2 (bad input), as for every command of the project.
"""
from __future__ import annotations

import math
import sys

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from file_formats.planetary.orbital_file import load_orbital_image


def describe(path: str, sidecar: str | None) -> str:
    image = load_orbital_image(path, sidecar)
    values = image.pixels[image.valid]
    lines = [f"{path}: {image.file_format}, {image.shape[0]} rows x {image.shape[1]} cols, band "
             f"{image.band_index + 1} of {image.band_count}, {100 * image.valid.mean():.2f} % valid"]
    if values.size:
        lines.append(f"  pixel values {values.min():.6g} .. {values.max():.6g}, mean {values.mean():.6g}")

    def known(value, unit=""):
        return "unknown (side-car needed)" if value is None else f"{value:.6g}{unit}"

    lines.append(f"  metres_per_pixel  {known(image.metres_per_pixel, ' m')}")
    for name in ("incidence", "emission", "phase"):
        angle = getattr(image, f"{name}_rad")
        lines.append(f"  {name + '_deg':17s} {known(None if angle is None else math.degrees(angle), ' deg')}")
    lines.append(f"  dn_to_if          scale {known(image.dn_to_if_scale)}, offset {known(image.dn_to_if_offset)}")
    lines.extend(f"  note: {note}" for note in image.notes)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m file_formats.planetary.inspect_files", description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--sidecar", default=None, help="side-car TOML applied to every file")
    args = parser.parse_args(argv)
    status = 0
    for path in args.files:
        try:
            print(describe(path, args.sidecar))
        except ConfigError as exc:
            print(f"{parser.prog}: error: {exc}", file=sys.stderr)
            status = USAGE_ERROR
    return status


if __name__ == "__main__":
    sys.exit(main())
