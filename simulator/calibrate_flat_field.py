"""Simulate a ground flat-field calibration of a camera and write the flat field.

The file is one ``python -m dimes_velocity --flat-field`` reads::

    python -m simulator.calibrate_flat_field CAMERA.toml --out mer_a.flat.fits [--frames 16] [--seed 1]

(``python -m simulator.calibration`` runs the same.) The calibration itself is :mod:`simulator.calibration`.
"""
from __future__ import annotations

import sys

import numpy as np

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from file_formats.flat_field_files import save_flat_field
from flight_interface.calibration import CalibrationError
from flight_interface.camera import load_camera
from simulator.calibration import DEFAULT_FLAT_FRAMES, simulate_flat_field


def main(argv: list[str] | None = None) -> int:
    """Command line: simulate a ground flat-field calibration and write the flat field.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 written, 2 bad input.
    """
    parser = OneLineParser(prog="python -m simulator.calibrate_flat_field",
                           description="Simulate a ground flat-field calibration; write the flat field.")
    parser.add_argument("camera", help="camera TOML")
    parser.add_argument("--out", required=True, help="output file: .npy, .tif or .fits")
    parser.add_argument("--frames", type=int, default=DEFAULT_FLAT_FRAMES, help="flat (and dark) exposures")
    parser.add_argument("--seed", type=int, default=1, help="noise seed")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error(f"--frames {args.frames}: allowed: >= 1")
    try:
        camera = load_camera(args.camera)
        flat = simulate_flat_field(camera, args.frames, np.random.default_rng(args.seed))
        path = save_flat_field(args.out, flat)
    except (ConfigError, CalibrationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    print(f"wrote {path}: flat field {flat.shape[0]} x {flat.shape[1]} from {args.frames} flat and "
          f"{args.frames} dark exposures; response {float(flat.min()):.3f} .. {float(flat.max()):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
