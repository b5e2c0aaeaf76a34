"""What the flight system measured when each descent image was taken (the estimator's inputs
besides the images). Frames as in :mod:`flight_interface.frames`: world x east, y north, z up;
attitude is the lander body-to-world quaternion ``(w, x, y, z)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImageMeasurement:
    """Sensor readings at one descent image.

    Attributes
    ----------
    time_s : float
        Start of the image's exposure (s, mission clock of the profile).
    attitude_quat : ndarray, shape (4,)
        Measured lander body-to-world attitude (with bias, random and alignment errors).
    angular_rate_radps : ndarray, shape (3,)
        Measured body-frame angular rate (rad/s).
    radar_altitude_m : float
        Measured altitude of the lander above the ground plane (m).
    imu_velocity_mps : ndarray, shape (3,)
        IMU-propagated world velocity (m/s); its horizontal part carries an unknown constant bias.
    heat_shield_offset_m : ndarray, shape (3,), or None
        Predicted position of the heat shield centre relative to the lander (world frame, m), when a
        prediction exists; the estimator then excludes the heat shield's cone from feature tracking.
    imu_position_m : ndarray, shape (3,), or None
        IMU-propagated lander position (world frame, m, any fixed origin), integrated at the IMU rate
        from the same biased velocity. When every image has it, the estimator takes the predicted
        displacement between images from it; otherwise it integrates ``imu_velocity_mps`` between
        the image times by the trapezoidal rule (exact for constant acceleration; a swinging lander
        makes that off by up to ~0.6 m/s equivalent on Gusev profiles).
    """

    time_s: float
    attitude_quat: np.ndarray
    angular_rate_radps: np.ndarray
    radar_altitude_m: float
    imu_velocity_mps: np.ndarray
    heat_shield_offset_m: np.ndarray | None = None
    imu_position_m: np.ndarray | None = None


@dataclass(frozen=True)
class DescentMeasurements:
    """Measurements for a set of descent images (three for DIMES) plus the sun direction.

    Attributes
    ----------
    images : tuple of ImageMeasurement
    sun_direction_world : ndarray, shape (3,)
        Unit vector from the ground toward the sun in the world frame (known from ephemeris).
    """

    images: tuple[ImageMeasurement, ...]
    sun_direction_world: np.ndarray


#: Largest IMU speed accepted (m/s): above Mars entry speed (~6 km/s); beyond it the ground offsets
#: of the predicted positions overflow the estimator's pixel arithmetic.
MAX_SPEED_MPS = 1e4


class MeasurementError(ValueError):
    """Illegal measurements (wrong shape, not finite, out of range); the message names the field."""


def _vector(value, length: int, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float) if value is not None else None
    if array is None or array.shape != (length,):
        raise MeasurementError(f"{name} must be {length} numbers; got {value!r}")
    if not np.all(np.isfinite(array)):
        raise MeasurementError(f"{name} must be finite; got {value!r}")
    return array


def validate_measurements(measurements: DescentMeasurements, image_count: int | None = None) -> None:
    """Raise :class:`MeasurementError` naming the field if the measurements cannot be used.

    Checks: at least two images (``image_count`` of them if given), strictly increasing times,
    unit-normable attitude quaternions, finite 3-vectors, radar altitude > 0, sun direction non-zero.
    """
    images = measurements.images
    if image_count is not None and len(images) != image_count:
        raise MeasurementError(f"images: expected {image_count} image measurements; got {len(images)}")
    if len(images) < 2:
        raise MeasurementError(f"images: at least 2 image measurements are needed; got {len(images)}")
    previous = -np.inf
    for k, image in enumerate(images):
        prefix = f"images[{k}]."
        time_s = float(image.time_s)
        if not np.isfinite(time_s) or time_s <= previous:
            raise MeasurementError(f"{prefix}time_s = {image.time_s!r} must be finite and later than the previous image")
        previous = time_s
        quaternion = _vector(image.attitude_quat, 4, prefix + "attitude_quat")
        if not 0.5 < np.linalg.norm(quaternion) < 2.0:
            raise MeasurementError(f"{prefix}attitude_quat = {image.attitude_quat!r} must be a unit quaternion (w, x, y, z)")
        _vector(image.angular_rate_radps, 3, prefix + "angular_rate_radps")
        velocity = _vector(image.imu_velocity_mps, 3, prefix + "imu_velocity_mps")
        if not np.linalg.norm(velocity) < MAX_SPEED_MPS:
            raise MeasurementError(f"{prefix}imu_velocity_mps = {image.imu_velocity_mps!r} is out of range; "
                                   f"allowed: speed < {MAX_SPEED_MPS:g} m/s")
        altitude = float(image.radar_altitude_m)
        if not (np.isfinite(altitude) and 0.0 < altitude < 1e6):
            raise MeasurementError(f"{prefix}radar_altitude_m = {image.radar_altitude_m!r} is out of range; allowed: > 0 and < 1e6 m")
        if image.heat_shield_offset_m is not None:
            _vector(image.heat_shield_offset_m, 3, prefix + "heat_shield_offset_m")
        if image.imu_position_m is not None:
            _vector(image.imu_position_m, 3, prefix + "imu_position_m")
    sun = _vector(measurements.sun_direction_world, 3, "sun_direction_world")
    if np.linalg.norm(sun) < 1e-9:
        raise MeasurementError("sun_direction_world must be a non-zero vector")
