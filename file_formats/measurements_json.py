"""The measurements file: what the flight system measured at each descent image, as JSON (schema below).

Images are read by :mod:`file_formats.descent_images`.

Measurements JSON schema
------------------------
::

    {
      "sun_direction_world": [east, north, up],        # toward the sun, any non-zero length
      "images": [                                       # one object per image, in time order
        {
          "time_s": 0.0,                                # start of exposure (s)
          "attitude_quat": [w, x, y, z],                # lander body-to-world, measured
          "radar_altitude_m": 2000.0,                   # measured altitude above ground (m)
          "imu_velocity_mps": [east, north, up],        # IMU-propagated velocity (m/s), biased
          "angular_rate_radps": [x, y, z],              # optional, body frame (default 0)
          "heat_shield_offset_m": [east, north, up],    # optional, predicted heat shield - lander (m)
          "imu_position_m": [east, north, up]           # optional, IMU-propagated position (m)
        },
        ...
      ]
    }

Frames: world x east, y north, z up; attitude as in :mod:`flight_interface.frames`. Unknown keys are
errors (a misspelt optional field must not be silently ignored). The record must be consistent
(:func:`flight_interface.measurements.validate_measurements`): times strictly increasing, attitude
quaternions of unit norm (within 1e-3), ``imu_position_m`` on every image or none, and when given its
change between images within 5 m/s + |velocity change| of the trapezoid of ``imu_velocity_mps``.

"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from file_formats.errors import InputFileError
from flight_interface.measurements import DescentMeasurements, ImageMeasurement, MeasurementError, validate_measurements

_REQUIRED = ("time_s", "attitude_quat", "radar_altitude_m", "imu_velocity_mps")
_OPTIONAL = ("angular_rate_radps", "heat_shield_offset_m", "imu_position_m")

def measurements_from_dict(data: dict, source: str = "<measurements>") -> DescentMeasurements:
    """Build and validate :class:`DescentMeasurements` from the JSON schema above."""
    def fail(field: str, message: str) -> InputFileError:
        return InputFileError(f"{source}: {field} {message}")

    if not isinstance(data, dict):
        raise InputFileError(f"{source}: top level must be an object with 'sun_direction_world' and 'images'")
    for key in data:
        if key not in ("sun_direction_world", "images"):
            raise fail(key, "is not a measurements field; allowed: sun_direction_world, images")
    for key in ("sun_direction_world", "images"):
        if key not in data:
            raise fail(key, "is missing")
    if not isinstance(data["images"], list):
        raise fail("images", "must be a list of image objects")
    records = []
    for k, item in enumerate(data["images"]):
        prefix = f"images[{k}]"
        if not isinstance(item, dict):
            raise fail(prefix, "must be an object")
        for key in item:
            if key not in _REQUIRED + _OPTIONAL:
                raise fail(f"{prefix}.{key}", f"is not an image field; allowed: {', '.join(_REQUIRED + _OPTIONAL)}")
        for key in _REQUIRED:
            if key not in item:
                raise fail(f"{prefix}.{key}", "is missing")
        for key in ("time_s", "radar_altitude_m"):
            if isinstance(item[key], bool) or not isinstance(item[key], (int, float)):
                raise fail(f"{prefix}.{key}", f"must be a number; got {item[key]!r}")
        records.append(ImageMeasurement(
            time_s=float(item["time_s"]), attitude_quat=_numbers(item["attitude_quat"], 4, f"{prefix}.attitude_quat", fail),
            angular_rate_radps=_numbers(item.get("angular_rate_radps", [0.0, 0.0, 0.0]), 3, f"{prefix}.angular_rate_radps", fail),
            radar_altitude_m=float(item["radar_altitude_m"]),
            imu_velocity_mps=_numbers(item["imu_velocity_mps"], 3, f"{prefix}.imu_velocity_mps", fail),
            heat_shield_offset_m=(None if item.get("heat_shield_offset_m") is None else
                                  _numbers(item["heat_shield_offset_m"], 3, f"{prefix}.heat_shield_offset_m", fail)),
            imu_position_m=(None if item.get("imu_position_m") is None else
                            _numbers(item["imu_position_m"], 3, f"{prefix}.imu_position_m", fail)),
        ))
    measurements = DescentMeasurements(
        images=tuple(records),
        sun_direction_world=_numbers(data["sun_direction_world"], 3, "sun_direction_world", fail))
    try:
        validate_measurements(measurements)
    except MeasurementError as exc:
        raise InputFileError(f"{source}: {exc}") from None
    return measurements


def _numbers(value, length: int, field: str, fail) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != length
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
        raise fail(field, f"must be a list of {length} numbers; got {value!r}")
    return np.asarray(value, dtype=float)


def load_measurements(path: str | Path) -> DescentMeasurements:
    """Read a measurements JSON file (schema in the module docstring)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputFileError(f"{path}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: invalid JSON: {exc}") from None
    return measurements_from_dict(data, str(path))


def measurements_to_dict(measurements: DescentMeasurements) -> dict:
    """The JSON form of :class:`DescentMeasurements` (inverse of :func:`measurements_from_dict`)."""
    images = []
    for image in measurements.images:
        record = {"time_s": float(image.time_s), "attitude_quat": [float(v) for v in image.attitude_quat],
                  "radar_altitude_m": float(image.radar_altitude_m),
                  "imu_velocity_mps": [float(v) for v in image.imu_velocity_mps],
                  "angular_rate_radps": [float(v) for v in image.angular_rate_radps]}
        if image.heat_shield_offset_m is not None:
            record["heat_shield_offset_m"] = [float(v) for v in image.heat_shield_offset_m]
        if image.imu_position_m is not None:
            record["imu_position_m"] = [float(v) for v in image.imu_position_m]
        images.append(record)
    return {"sun_direction_world": [float(v) for v in measurements.sun_direction_world], "images": images}


def json_ready(value: Any) -> Any:
    """``value`` as JSON can hold it (the side files next to the measurements, e.g. ``truth.json``): numpy
    arrays and scalars as Python lists and numbers, tuples as lists, dict keys as strings, and non-finite
    floats as null (JSON has no NaN or infinity)."""
    if isinstance(value, np.ndarray):
        return [json_ready(item) for item in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [json_ready(item) for item in value]
    if isinstance(value, dict):
        return {str(key): json_ready(item) for key, item in value.items()}
    if isinstance(value, np.generic):
        value = value.item()
    return None if isinstance(value, float) and not math.isfinite(value) else value
