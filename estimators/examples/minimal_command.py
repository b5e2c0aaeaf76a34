"""A minimal ``kind = "command"`` estimator.

A stand-alone program that reads the case's files and writes its answer as JSON. Copy it (numpy and the standard
library only), or write the same in any language.

    [[estimators]]
    name = "imu_only_command"
    kind = "command"
    argv = ["{python}", "{config_dir}/minimal_command.py", "{images}", "--measurements", "{measurements}",
            "--camera", "{camera}", "--flat-field", "{flat_field}", "--parameters", "{parameters}",
            "--output", "{output}"]
    image_format = "npy"          # or "png" (16-bit grey, the default) or "raw" (little-endian uint16)
    flat_field_format = "npy"
    timeout_s = 60

It computes what :mod:`estimators.examples.minimal_python` computes (the IMU's horizontal velocity at the
last image, valid when every image shows lit ground and the sun is up). Exit status 0 after writing
``--output``; anything else (here: 2 with one line on stderr for input it cannot use) is recorded as this
estimator's failed row for the case, with the last stderr line as the error.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tomllib

import numpy as np


def read_image(path: str) -> np.ndarray:
    """One image file as the uint16 DN array it holds.

    Parameters
    ----------
    path : str
        ``.npy`` (image_format = "npy"), 16-bit grey ``.png`` (the default image_format) or headerless
        little-endian uint16 ``.raw``.

    Returns
    -------
    ndarray, uint16
        The image (DN); a ``.raw`` file is flat, shape (n,).
    """
    if path.endswith(".npy"):
        return np.load(path)
    if path.endswith(".png"):
        from PIL import Image  # lazy: only PNG needs Pillow; npy and raw need numpy alone
        with Image.open(path) as image:
            return np.asarray(image)
    return np.fromfile(path, dtype="<u2")


def main(argv: list[str] | None = None) -> int:
    """Read the case's files, write the answer.

    Parameters
    ----------
    argv : list of str or None, optional
        The arguments (``--help`` lists them); None: ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit status: 0 when an answer was written, 2 for an image of the wrong shape.
    """
    parser = argparse.ArgumentParser(description="minimal command estimator")
    parser.add_argument("images", nargs="+", help="image files in time order ({images})")
    parser.add_argument("--measurements", required=True, help="measurements JSON ({measurements})")
    parser.add_argument("--camera", required=True, help="camera TOML ({camera})")
    parser.add_argument("--flat-field", default="none", help="flat-field file or 'none' ({flat_field})")
    parser.add_argument("--parameters", help="the entry's parameters as JSON ({parameters})")
    parser.add_argument("--output", required=True, help="where to write the answer ({output})")
    args = parser.parse_args(argv)

    parameters = json.load(open(args.parameters)) if args.parameters else {}
    bias_sigma_mps = float(parameters.get("imu_bias_sigma_mps", 2.0))
    min_signal_dn = float(parameters.get("min_signal_dn", 50.0))
    with open(args.camera, "rb") as handle:
        camera = tomllib.load(handle)
    offset_dn = float(camera["electronics"].get("adc_offset_dn", 0.0))
    rows = camera["detector"]["height_px"] // camera["detector"].get("binning_rows", 1)
    columns = camera["detector"]["width_px"]
    flat = None if args.flat_field == "none" else np.load(args.flat_field)   # float32 (rows, columns)
    with open(args.measurements) as handle:
        measurements = json.load(handle)        # schema: file_formats/measurements_json.py

    features, signal_dn = [], []
    for path in args.images:
        image = read_image(path)                # uint16 DN as read out
        image = image.reshape(rows, columns) if image.ndim == 1 and image.size == rows * columns else image
        if image.shape != (rows, columns):
            print(f"{path}: image shape {image.shape}; expected ({rows}, {columns})", file=sys.stderr)
            return 2
        signal = image.astype(np.float64) - offset_dn
        if flat is not None:
            signal /= np.maximum(flat, 1e-3)
        signal_dn.append(float(signal.mean()))
        features.append({"brightness_dn": signal_dn[-1] + offset_dn, "contrast_dn": float(signal.std()), "status": "ok"})

    east_mps, north_mps = measurements["images"][-1]["imu_velocity_mps"][:2]    # world x east, y north
    answer = {"velocity_east_mps": east_mps, "velocity_north_mps": north_mps, "features": features}
    if measurements["sun_direction_world"][2] <= 0.0:
        answer.update(valid=False, reason="sun_below_horizon")
    elif min(signal_dn) < min_signal_dn:
        answer.update(valid=False, reason="no_signal")
    else:
        answer.update(valid=True, reason="ok", velocity_uncertainty_mps=math.sqrt(2.0) * bias_sigma_mps)
    with open(args.output, "w") as handle:
        json.dump(answer, handle)
    return 0


if __name__ == "__main__":
    sys.exit(main())
