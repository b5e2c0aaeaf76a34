"""Command line: run the reference DIMES estimator on image files and a measurements file.

Usage::

    python -m dimes_velocity IMAGE1 IMAGE2 IMAGE3 MEASUREMENTS.json --camera sitedata/cameras/mer_a.toml
        [--config campaign.toml]   # estimator parameters from its [estimator] table
        [--flat-field FILE|none]   # measured flat field (.npy, TIFF, FITS); default: <camera stem>.flat.*
                                   # beside the camera TOML if there is one, else the design falloff only
        [--big-endian]             # raw images are big-endian uint16
        [--summary]                # print only velocity, valid, reason and bias

Images are 16-bit PNG, .npy or raw uint16 (rows binned on chip: 256 x 1024 for MER); the
measurements schema is documented in :mod:`dimes_velocity.files`. The result (see
:class:`dimes_velocity.result.VelocityEstimate`) is printed as JSON. Bad input prints one line
naming the file and field to stderr and exits with status 2.
"""
from __future__ import annotations

import argparse
import json
import sys

from flight_interface.calibration import CalibrationError, flat_field_next_to, load_flat_field
from flight_interface.camera import load_camera
from flight_interface.tomlfields import ConfigError, Table, load_toml

from .config import EstimatorConfig, config_from_table
from .estimator import DimesEstimator
from .files import InputFileError, load_image, load_measurements
from flight_interface.measurements import MeasurementError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dimes_velocity",
                                     description="Reference DIMES horizontal velocity estimator.")
    parser.add_argument("files", nargs="+", metavar="FILE", help="images in time order, then the measurements JSON")
    parser.add_argument("--camera", required=True, help="camera TOML (e.g. sitedata/cameras/mer_a.toml)")
    parser.add_argument("--config", help="TOML file whose [estimator] table sets estimator parameters")
    parser.add_argument("--flat-field", metavar="FILE",
                        help="flat-field calibration file (.npy, .tif, .fits) or 'none'; default: "
                             "<camera stem>.flat.{npy,tif,tiff,fits} beside the camera TOML when present")
    parser.add_argument("--big-endian", action="store_true", help="raw images are big-endian uint16")
    parser.add_argument("--summary", action="store_true", help="print only the velocity, valid flag, reason and bias")
    args = parser.parse_args(argv)
    if len(args.files) < 3:
        print("error: give at least two images and the measurements JSON", file=sys.stderr)
        return 2
    *image_paths, measurements_path = args.files
    try:
        camera = load_camera(args.camera)
        config = EstimatorConfig()
        if args.config:
            root = Table(load_toml(args.config), args.config)
            config = config_from_table(root.table("estimator"))
        measurements = load_measurements(measurements_path)
        if len(measurements.images) != len(image_paths):
            raise InputFileError(f"{measurements_path}: images has {len(measurements.images)} entries "
                                 f"for {len(image_paths)} image files")
        shape = (camera.height_px // camera.binning_rows, camera.width_px)
        images = [load_image(path, shape, args.big_endian) for path in image_paths]
        flat_path = flat_field_next_to(args.camera) if args.flat_field is None else (
            None if args.flat_field.lower() == "none" else args.flat_field)
        flat_field = None if flat_path is None else load_flat_field(flat_path, camera.binned_shape)
        result = DimesEstimator(camera, config, flat_field).estimate(images, measurements)
    except (ConfigError, InputFileError, MeasurementError, CalibrationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    output = result.to_dict()
    if args.summary:
        output = {key: output[key] for key in ("velocity_east_mps", "velocity_north_mps", "valid", "reason",
                                               "imu_bias_east_mps", "imu_bias_north_mps")}
    print(json.dumps(output, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
