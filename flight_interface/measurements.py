"""What the flight system measured when each descent image was taken.

The estimator's inputs besides the images. Frames as in :mod:`flight_interface.frames`: world x east, y north, z
up; attitude is the lander body-to-world quaternion ``(w, x, y, z)``.
"""
from __future__ import annotations

import math
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


#: Largest departure of an attitude quaternion's norm from 1. Flight software writes normalized
#: quaternions (norm error ~1e-15); four components rounded to 4 decimals stay within ~2e-4. A norm
#: off by more than 0.1 % is not a rounding of a unit quaternion but another quantity (a rotation
#: vector, a scaled or truncated record), so it is refused rather than silently normalized.
QUATERNION_NORM_TOLERANCE = 1e-3

#: IMU position/velocity consistency (m/s): the fixed part of the allowed disagreement between the
#: IMU position change between two images, divided by their time difference, and the trapezoid of the
#: two IMU velocities, ``|(p_k+1 - p_k) / dt - (v_k + v_k+1) / 2|`` (3-D). A real IMU integrates both
#: from the same biased velocity at its own rate, so a constant bias cancels and the disagreement is
#: (a) the trapezoid's error for non-constant acceleration, bounded by how far the velocity leaves
#: the straight line between the two samples: a lander swinging on its bridle (~20 m, swing <= 10 deg)
#: moves at most ~sqrt(g_mars L) * 0.17 ~ 1.5 m/s each way, so <= ~3 m/s; (b) accelerometer bias
#: drift: 1 mg over a 4 s image interval is 0.04 m/s; (c) timing skew between the IMU and camera
#: stamps: 10 ms at 2 m/s^2 is 0.02 m/s. 5 m/s covers all of them with margin. To it is added the
#: velocity change between the two images ``|v_k+1 - v_k|``: whatever the velocity does between two
#: samples, the mean velocity of a monotonic change lies between them (within |dv|/2 of the
#: trapezoid), and a velocity random walk's bridge (sigma ~ sigma_rw sqrt(dt/12)) is a fraction of the
#: walk's own increment. A ~24 m/s disagreement with steady velocities (positions moving, velocities
#: 0) is a contradiction the estimator must not answer from.
IMU_CONSISTENCY_MPS = 5.0

#: Largest horizontal acceleration of a lander under its parachute (m/s^2), as the mean over an image
#: interval ``|v_h,k+1 - v_h,k| / dt`` of the IMU velocities (the constant IMU bias cancels in the
#: difference). Source: the lander hangs on a 20 m bridle below a parachute at terminal descent (~72 m/s),
#: so its horizontal acceleration is (a) the pendulum's, ``g_mars sin(swing)``, at most 3.71 sin 30 deg
#: = 1.86 m/s^2 at the EDL trajectory sets' off-nadir envelope (30 deg), plus (b) the parachute drag's
#: horizontal part in a gust, the weight times the relative horizontal wind over the descent speed,
#: 3.71 x 10 / 72 = 0.52 m/s^2 for a 10 m/s relative gust (3 sigma of the sets' 3 m/s per-axis gusts):
#: 2.4 m/s^2. Measured on the 700 profiles of ``sitedata/trajectories/{gusev,meridiani}.parquet``: at
#: most 1.68 m/s^2 instantaneous (Gusev; Meridiani 1.18) and 1.42 m/s^2 as the mean over an image
#: interval (Meridiani 1.00). 2.5 m/s^2 is 1.76x the largest interval mean.
MAX_HORIZONTAL_ACCELERATION_MPS2 = 2.5

#: Largest change of that interval-mean horizontal acceleration between consecutive image intervals
#: (m/s^2): ``|a_k+1,k+2 - a_k,k+1|``. A swing reversing between the two intervals changes the mean
#: acceleration by at most twice (a) above, 3.7 m/s^2; measured at most 2.13 m/s^2 (Gusev; Meridiani 1.28)
#: on the trajectory sets. 3.5 m/s^2 is 1.64x the largest measured. A middle IMU velocity sample off by
#: J m/s and back changes it by ~2 J / dt (~5.3 m/s^2 for J = 10 m/s over 3.75 s).
MAX_HORIZONTAL_ACCELERATION_CHANGE_MPS2 = 3.5

#: Allowance for IMU velocity noise between two samples in the acceleration checks (m/s): the IMU's
#: bias is constant and cancels; what remains is the velocity random walk (the campaigns' default 0;
#: 0.05 m/s/sqrt(s) over 4 s is 0.1 m/s, 2.5 sigma at 0.25 m/s) and stamp timing (10 ms at 2.5 m/s^2:
#: 0.025 m/s).
IMU_VELOCITY_DIFFERENCE_ALLOWANCE_MPS = 0.25

#: Radar altitude noise (fraction of the altitude, 1 sigma): the radar's measured performance, 0.03 %
#: (paper section 5; the sensor model's default).
RADAR_ALTITUDE_SIGMA_FRACTION = 3e-4

#: How many sigma of the radar noise the radar/IMU vertical check allows.
RADAR_NOISE_SIGMAS = 5.0

#: Fixed part of the allowed disagreement (m/s) between the radar's descent rate
#: ``-(h_k+1 - h_k) / dt`` and the IMU's mean vertical speed ``-(vz_k + vz_k+1) / 2``: an IMU vertical
#: velocity bias (the campaigns draw 0; 3 sigma of a bias as large as the horizontal one, 2 m/s, is
#: 6 m/s) and the trapezoid's error for a changing descent rate (at most 0.49 m/s on the trajectory
#: sets). A radar 25 % high at 72 m/s descent is 18 m/s off; a radar scale error above ~9 % is refused.
RADAR_IMU_VERTICAL_ALLOWANCE_MPS = 6.0


class MeasurementError(ValueError):
    """Illegal or self-contradictory measurements.

    Wrong shape, not finite, out of range, fields that disagree with each other; the message names the field and
    the disagreement.
    """


def _vector(value, length: int, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float) if value is not None else None
    if array is None or array.shape != (length,):
        raise MeasurementError(f"{name} must be {length} numbers; got {value!r}")
    if not all(map(math.isfinite, array.tolist())):        # np.isfinite on a few numbers, without its overhead
        raise MeasurementError(f"{name} must be finite; got {value!r}")
    return array


def validate_measurements(measurements: DescentMeasurements, image_count: int | None = None) -> None:
    """Raise :class:`MeasurementError` if the measurements cannot be used or contradict each other.

    The message names the field.

    Checks: at least two images (``image_count`` of them if given), strictly increasing times, unit
    attitude quaternions (norm within :data:`QUATERNION_NORM_TOLERANCE` of 1), finite 3-vectors, radar
    altitude > 0, sun direction non-zero; ``imu_position_m`` given for every image or for none, and
    when given, consistent with ``imu_velocity_mps`` and ``time_s`` (:data:`IMU_CONSISTENCY_MPS`).
    The record's physics: horizontal IMU velocity changes within what a lander under a parachute can do
    (:data:`MAX_HORIZONTAL_ACCELERATION_MPS2` per interval, :data:`MAX_HORIZONTAL_ACCELERATION_CHANGE_MPS2`
    between intervals), the radar's altitude differences against the IMU's vertical velocity
    (:data:`RADAR_IMU_VERTICAL_ALLOWANCE_MPS` + :data:`RADAR_NOISE_SIGMAS` sigma of the radar noise).
    An attitude pointing the camera far from nadir (or at the sky) is not refused here: the campaign's
    sensor models at the largest allowed attitude-error sigmas produce such records, and the estimator
    answers them invalid (``bad_attitude``), never valid.

    Parameters
    ----------
    measurements : DescentMeasurements
        The record to check.
    image_count : int or None, optional
        Number of images the record must describe; None: any number >= 2.

    Raises
    ------
    MeasurementError
        The first problem found, naming the field.
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
        if not math.isfinite(time_s) or time_s <= previous:
            raise MeasurementError(f"{prefix}time_s = {image.time_s!r} must be finite and later than the previous image")
        previous = time_s
        quaternion = _vector(image.attitude_quat, 4, prefix + "attitude_quat")
        norm = float(np.linalg.norm(quaternion))
        if not abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE:
            raise MeasurementError(f"{prefix}attitude_quat = {image.attitude_quat!r} must be a unit quaternion (w, x, y, z); "
                                   f"norm {norm:.6g}, allowed 1 +- {QUATERNION_NORM_TOLERANCE:g}")
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
    _check_imu_positions(images)
    _check_horizontal_acceleration(images)
    _check_radar_against_imu(images)
    sun = _vector(measurements.sun_direction_world, 3, "sun_direction_world")
    if np.linalg.norm(sun) < 1e-9:
        raise MeasurementError("sun_direction_world must be a non-zero vector")


def _check_imu_positions(images: tuple[ImageMeasurement, ...]) -> None:
    """IMU positions for every image or none; when given, consistent with the velocities and times."""
    given = [image.imu_position_m is not None for image in images]
    if not any(given):
        return
    if not all(given):
        raise MeasurementError(f"imu_position_m: given for {sum(given)} of {len(images)} images; "
                               f"give it for every image or for none")
    for k in range(len(images) - 1):
        first, second = images[k], images[k + 1]
        dt = float(second.time_s) - float(first.time_s)
        position_rate = (np.asarray(second.imu_position_m, dtype=float) - np.asarray(first.imu_position_m, dtype=float)) / dt
        v0 = np.asarray(first.imu_velocity_mps, dtype=float)
        v1 = np.asarray(second.imu_velocity_mps, dtype=float)
        disagreement = float(np.linalg.norm(position_rate - 0.5 * (v0 + v1)))
        tolerance = IMU_CONSISTENCY_MPS + float(np.linalg.norm(v1 - v0))
        if not disagreement <= tolerance:
            raise MeasurementError(
                f"images[{k}..{k + 1}]: imu_position_m and imu_velocity_mps disagree: the positions move at "
                f"{np.linalg.norm(position_rate):.3g} m/s, {disagreement:.3g} m/s from the mean IMU velocity "
                f"{np.linalg.norm(0.5 * (v0 + v1)):.3g} m/s over {dt:.3g} s; allowed {tolerance:.3g} m/s")



def _horizontal_accelerations(images: tuple[ImageMeasurement, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Interval-mean horizontal accelerations (m/s^2, shape (n - 1, 2)) and interval lengths (s, n - 1)."""
    times = np.array([float(image.time_s) for image in images])
    velocities = np.array([np.asarray(image.imu_velocity_mps, dtype=float)[:2] for image in images])
    intervals = np.diff(times)
    return np.diff(velocities, axis=0) / intervals[:, None], intervals


def _check_horizontal_acceleration(images: tuple[ImageMeasurement, ...]) -> None:
    """Refuse IMU horizontal velocities changing faster than a lander under a parachute can.

    Bounds: :data:`MAX_HORIZONTAL_ACCELERATION_MPS2`, :data:`MAX_HORIZONTAL_ACCELERATION_CHANGE_MPS2`.
    """
    accelerations, intervals = _horizontal_accelerations(images)
    for k, (acceleration, dt) in enumerate(zip(accelerations, intervals)):
        change = float(np.linalg.norm(acceleration)) * dt
        allowed = MAX_HORIZONTAL_ACCELERATION_MPS2 * dt + IMU_VELOCITY_DIFFERENCE_ALLOWANCE_MPS
        if not change <= allowed:
            raise MeasurementError(
                f"images[{k}..{k + 1}].imu_velocity_mps: the horizontal velocity changes by {change:.3g} m/s in "
                f"{dt:.3g} s ({change / dt:.3g} m/s^2); a lander under a parachute allows {allowed:.3g} m/s "
                f"({MAX_HORIZONTAL_ACCELERATION_MPS2:g} m/s^2)")
    for k in range(len(accelerations) - 1):
        mean_dt = 0.5 * (intervals[k] + intervals[k + 1])
        jerk = float(np.linalg.norm(accelerations[k + 1] - accelerations[k]))
        allowed = MAX_HORIZONTAL_ACCELERATION_CHANGE_MPS2 + 2.0 * IMU_VELOCITY_DIFFERENCE_ALLOWANCE_MPS / mean_dt
        if not jerk <= allowed:
            raise MeasurementError(
                f"images[{k}..{k + 2}].imu_velocity_mps: the horizontal acceleration changes by {jerk:.3g} m/s^2 "
                f"between the two intervals ({np.linalg.norm(accelerations[k]):.3g} then "
                f"{np.linalg.norm(accelerations[k + 1]):.3g} m/s^2); a lander under a parachute allows "
                f"{allowed:.3g} m/s^2")


def _check_radar_against_imu(images: tuple[ImageMeasurement, ...]) -> None:
    """Refuse a radar descent rate between two images far from the IMU's mean vertical velocity.

    Allowed: :data:`RADAR_IMU_VERTICAL_ALLOWANCE_MPS` + :data:`RADAR_NOISE_SIGMAS` sigma of the radar noise.
    """
    for k in range(len(images) - 1):
        first, second = images[k], images[k + 1]
        dt = float(second.time_s) - float(first.time_s)
        h0, h1 = float(first.radar_altitude_m), float(second.radar_altitude_m)
        radar_rate = (h1 - h0) / dt
        imu_rate = 0.5 * (float(np.asarray(first.imu_velocity_mps, dtype=float)[2])
                          + float(np.asarray(second.imu_velocity_mps, dtype=float)[2]))
        noise = RADAR_NOISE_SIGMAS * RADAR_ALTITUDE_SIGMA_FRACTION * float(np.hypot(h0, h1)) / dt
        allowed = RADAR_IMU_VERTICAL_ALLOWANCE_MPS + noise
        if not abs(radar_rate - imu_rate) <= allowed:
            raise MeasurementError(
                f"images[{k}..{k + 1}]: radar_altitude_m and imu_velocity_mps disagree: the radar altitude goes "
                f"{h0:.6g} -> {h1:.6g} m in {dt:.3g} s ({radar_rate:.3g} m/s), the IMU's mean vertical velocity is "
                f"{imu_rate:.3g} m/s; allowed {allowed:.3g} m/s")
