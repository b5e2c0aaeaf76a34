"""Run a Python estimator callable on files, in its own process: the ``isolate = true`` way in.

    python -m estimators.run_python package.module:function --measurements M.json --camera CAMERA.toml
        --flat-field FILE|none --parameters P.json --output RESULT.json IMAGE1 IMAGE2 IMAGE3

Reads the images (PNG, .npy or raw uint16), measurements, camera and flat field, calls the function
with :class:`estimators.contract.EstimatorInputs` (read-only, as in a campaign) and writes its output
JSON. The campaign runs this as an external command (:mod:`estimators.command`), so a callable that
hangs or crashes the interpreter costs only its own result. Exit status 2 for unusable input files, 1 for a result that
breaks the contract (one line on stderr); an exception in the callable prints its traceback (exit 1).
"""
from __future__ import annotations

import importlib
import json
import sys

import numpy as np

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from estimators.camera_view import load_design_camera
from estimators.contract import ContractViolation, EstimatorInputs, output_to_dict, read_only_inputs, validate_output
from file_formats.descent_images import InputFileError, load_image
from file_formats.flat_field_files import load_flat_field
from file_formats.measurements_json import load_measurements
from flight_interface.calibration import CalibrationError, CalibrationProducts


def main(argv: list[str] | None = None) -> int:
    """Run ``callable`` on a case's files and write its answer to ``--output`` (JSON).

    Parameters
    ----------
    argv : list of str or None, optional
        The arguments; None: ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit status: 0 when an answer (valid or not) was written, 2 when an input file cannot be read,
        1 for an answer that breaks the contract (message on stderr); the callable's own exception
        propagates.
    """
    parser = OneLineParser(prog="python -m estimators.run_python")
    parser.add_argument("callable", help="package.module:function")
    parser.add_argument("images", nargs="+")
    parser.add_argument("--measurements", required=True)
    parser.add_argument("--camera", required=True)
    parser.add_argument("--flat-field", default="none")
    parser.add_argument("--parameters")
    parser.add_argument("--output", required=True)
    args = parser.parse_args(argv)
    try:
        camera = load_design_camera(args.camera)
        images = tuple(load_image(path, camera) for path in args.images)
        measurements = load_measurements(args.measurements)
        flat = None if args.flat_field == "none" else load_flat_field(args.flat_field, camera.binned_shape)
        parameters = json.loads(open(args.parameters).read()) if args.parameters else {}
    except (ConfigError, InputFileError, CalibrationError, OSError, json.JSONDecodeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    module_name, function_name = args.callable.split(":")
    function = getattr(importlib.import_module(module_name), function_name)
    inputs = EstimatorInputs(images=images, image_times_s=np.array([m.time_s for m in measurements.images]),
                             measurements=measurements, camera=camera,
                             calibration=CalibrationProducts(flat, args.flat_field if flat is not None else "none"),
                             parameters=parameters)
    try:
        output = validate_output(function(read_only_inputs(inputs)))
    except ContractViolation as exc:
        print(f"contract violation: {exc}", file=sys.stderr)
        return 1
    with open(args.output, "w") as handle:
        json.dump(output_to_dict(output), handle)
    return 0


if __name__ == "__main__":
    sys.exit(main())
