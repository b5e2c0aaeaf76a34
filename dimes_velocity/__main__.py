"""Command line: run the reference DIMES estimator on image files and a measurements file.

Usage::

    python -m dimes_velocity IMAGE1 IMAGE2 IMAGE3 MEASUREMENTS.json --camera sitedata/cameras/mer_a.toml
        [--config campaign.toml]   # estimator parameters from its [estimator] table
        [--bits 8|12|16]           # significant bits of the stored values (top bits of the camera DN)
        [--dn-scale S] [--dn-offset O]   # or DN = S x value + O
        [--channel r|g|b | --luminance]  # for RGB/RGBA images
        [--flat-field FILE|none]   # measured flat field (.npy, TIFF, FITS); default: <camera stem>.flat.*
                                   # beside the camera TOML if there is one, else the design falloff only
        [--big-endian]             # raw 16-bit images are big-endian
        [--summary]                # print only velocity, valid, reason, uncertainty and bias (no inputs list)

Images are PNG, TIFF, .npy, raw, PDS3, VICAR or ISIS3, binned (256 x 1024 for MER) or full frame
(1024 x 1024, binned here as on chip); the rules (shapes, bit depth, DN scale) are in
:mod:`file_formats.descent_images`, the measurements schema in :mod:`file_formats.measurements_json`. The
result (see :class:`dimes_velocity.result.VelocityEstimate`) is printed as JSON with an ``inputs``
list saying how each file was read (``--summary``: the summary keys only). Bad input prints one line naming the file and what to add or
change to stderr and exits with status 2. Legal inputs the estimator cannot trust (e.g. a sun at or
below the horizon) are answered like in flight: ``"valid": false`` with a reason code, exit status 0.
"""
from __future__ import annotations

import json
import sys

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from config_tables.toml_file import load_toml
from dimes_velocity.config import EstimatorConfig, estimator_config_from_data
from dimes_velocity.estimator import DimesEstimator
from file_formats.descent_images import ImageDeclaration, InputFileError, read_descent_image
from file_formats.flat_field_files import flat_field_next_to, load_flat_field
from file_formats.measurements_json import load_measurements
from flight_interface.calibration import CalibrationError
from flight_interface.camera import load_camera
from flight_interface.measurements import MeasurementError

PROG = "python -m dimes_velocity"
#: what ``--summary`` prints (nothing else: no pairs, features, timings or inputs list)
SUMMARY_KEYS = ("velocity_east_mps", "velocity_north_mps", "valid", "reason", "velocity_uncertainty_mps",
                "imu_bias_east_mps", "imu_bias_north_mps")


def build_parser() -> OneLineParser:
    """The command line of ``python -m dimes_velocity``.

    Returns
    -------
    OneLineParser
        The parser (usage errors: one line, exit status 2).
    """
    parser = OneLineParser(prog=PROG, description="Reference DIMES horizontal velocity estimator.")
    parser.add_argument("files", nargs="+", metavar="FILE", help="images in time order, then the measurements JSON")
    parser.add_argument("--camera", required=True, help="camera TOML (e.g. sitedata/cameras/mer_a.toml)")
    parser.add_argument("--config", help="TOML file whose [estimator] table sets estimator parameters")
    parser.add_argument("--bits", type=int, choices=(8, 12, 16),
                        help="significant bits of the stored values: the top bits of the camera's DN")
    parser.add_argument("--dn-scale", type=float, help="DN = scale x value + offset")
    parser.add_argument("--dn-offset", type=float, help="added after scaling (default 0)")
    colour = parser.add_mutually_exclusive_group()
    colour.add_argument("--channel", choices=("r", "g", "b", "0", "1", "2"), help="channel of an RGB/RGBA image")
    colour.add_argument("--luminance", action="store_true", help="Rec. 709 luminance of an RGB/RGBA image")
    parser.add_argument("--flat-field", metavar="FILE",
                        help="flat-field calibration file (.npy, .tif, .fits) or 'none'; default: "
                             "<camera stem>.flat.{npy,tif,tiff,fits} beside the camera TOML when present")
    parser.add_argument("--big-endian", action="store_true", help="raw 16-bit images are big-endian")
    parser.add_argument("--summary", action="store_true",
                        help="print only the velocity, valid flag, reason, uncertainty and bias")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Estimate the velocity of one descent from image files and print it as JSON.

    Parameters
    ----------
    argv : list of str or None, optional
        The arguments (``--help`` lists them); None: ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit status: 0 when a result (valid or not) was printed, 2 for a usage or input error (one line
        on stderr).
    """
    args = build_parser().parse_args(argv)
    if len(args.files) < 3:
        print(f"{PROG}: error: give at least two images and the measurements JSON", file=sys.stderr)
        return USAGE_ERROR
    *image_paths, measurements_path = args.files
    try:
        declaration = ImageDeclaration(bits=args.bits, dn_scale=args.dn_scale, dn_offset=args.dn_offset,
                                       channel=args.channel, luminance=args.luminance, big_endian=args.big_endian)
        camera = load_camera(args.camera)
        config = EstimatorConfig()
        if args.config:
            data = load_toml(args.config)
            if "estimator" not in data:
                raise ConfigError(f"{args.config}: estimator is missing (an [estimator] table)")
            config = estimator_config_from_data(data["estimator"], args.config)
        measurements = load_measurements(measurements_path)
        if len(measurements.images) != len(image_paths):
            raise InputFileError(f"{measurements_path}: images has {len(measurements.images)} entries "
                                 f"for {len(image_paths)} image files")
        files = [read_descent_image(path, camera, declaration) for path in image_paths]
        flat_path = flat_field_next_to(args.camera) if args.flat_field is None else (
            None if args.flat_field.lower() == "none" else args.flat_field)
        flat_field = None if flat_path is None else load_flat_field(flat_path, camera.binned_shape)
        result = DimesEstimator(camera, config, flat_field).estimate([f.dn for f in files], measurements)
    except (ConfigError, InputFileError, MeasurementError, CalibrationError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    output = result.to_dict()
    if args.summary:
        output = {key: output[key] for key in SUMMARY_KEYS}
    else:
        output["inputs"] = [f.describe() for f in files]
    print(json.dumps(output, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
