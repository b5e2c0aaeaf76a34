"""Sensor models: what the MER flight system would have measured at each descent image (paper section 5).

From a true :class:`~simulator.scene.descent_profile.DescentProfile`, :func:`measure` draws the inputs the
DIMES estimator gets besides the images (a :class:`~flight_interface.measurements.DescentMeasurements`)
and returns the errors it drew (the truth for the case's result row).

Error models (sigmas per axis; each can be set to 0 = perfect, or ``perfect = true`` for all)
---------------------------------------------------------------------------------------------
* Attitude, ``q_meas_k = exp(b + r_k) * q_true_k * exp(a)`` (rotation vectors, ``exp`` = quaternion
  of a rotation vector):

  - ``b``: absolute attitude-knowledge bias, world frame, constant over the images. The paper's
    "absolute biases (sigma = 1 deg)" is read as the RMS of the total tilt (``attitude_bias_sigma_is =
    "total_tilt"``): sigma 1/sqrt(2) deg on each axis. Read per axis (1 deg on each axis) the bias alone
    would give a horizontal error mean + 3 sigma of 4.0 m/s, above every value of the paper's Tables 1-2
    (3.03-4.06 m/s, matching noise included); docs/estimators.md, "The error statistic", has the arithmetic;
  - ``r_k``: between-image random error (timing accuracy), world frame, sigma 0.05 deg, new per image;
  - ``a``: camera-to-lander alignment error, *body* frame, sigma 0.1 deg, constant. The renderer
    images with the camera file's nominal mounting and the estimator uses the same nominal mounting,
    so a body-frame rotation of the measured attitude is exactly a camera misaligned by ``-a``
    relative to its calibration: a pointing error fixed to the lander, which turns in the world
    frame as the lander swings (unlike ``b``).
* Angular rate (body frame): true rate + white noise per image (default 0.1 deg/s, an assumption:
  the paper gives no number).
* Radar altitude: lander altitude ``z * (1 + e_k)``, ``e_k`` sigma 0.03 % (measured radar
  performance), independent per image.
* IMU velocity (world): true velocity + an unknown constant bias (default sigma 2 m/s per horizontal
  axis, 0 vertical: an assumption, the paper gives none) + an optional random walk accumulated from
  image 1 (default 0). The bias is the same at every image, so velocity *changes* between images are
  the true ones: the IMU propagates consistently and only its initial velocity is unknown.
* Heat-shield prediction (optional, ``heat_shield_prediction = true`` by default): the heat shield's
  position relative to the lander, as the flight system would predict it from the separation
  dynamics, = truth + an error per axis per image (default sigma 10 m, an assumption). Omitted
  (None) when off or when the profile carries no heat shield.

Timing: ``ImageMeasurement.time_s`` is the start of exposure (the profile's image time); the states
are sampled at mid-exposure (``state_time = "mid_exposure"``, the instant the image represents) or at
the start (``"exposure_start"``). Randomness: one ``standard_normal`` draw of fixed size from the
Generator passed in, whatever the sigmas, so switching one sensor to perfect leaves the others'
errors unchanged.
"""
from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import Field, ModelWrapValidatorHandler, model_validator

from config_tables.models import ConfigModel
from flight_interface.frames import (
    quat_conjugate,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalize,
    quat_to_rotation_vector,
)
from flight_interface.measurements import DescentMeasurements, ImageMeasurement
from simulator.scene.descent_profile import DescentProfile

SIGMA_FIELDS = ("attitude_bias_sigma_deg", "attitude_random_sigma_deg", "alignment_sigma_deg",
                "angular_rate_noise_sigma_dps", "radar_altitude_sigma_percent", "imu_velocity_bias_sigma_mps",
                "imu_vertical_velocity_bias_sigma_mps", "imu_velocity_random_walk_mps_per_sqrt_s",
                "heat_shield_prediction_sigma_m")


class SensorConfig(ConfigModel):
    """``[sensors]``: sensor error sigmas.

    Degrees and percent at this edge; the ``*_rad``, ``*_radps`` and ``*_fraction`` properties are SI.
    Defaults: the paper's numbers where it gives them.
    """

    perfect: bool = False
    """Every sensor exact: all sigmas 0 (whatever else is given)."""
    attitude_bias_sigma_deg: float = Field(1.0, ge=0.0, le=30.0)
    """Absolute attitude-knowledge bias, world frame (deg), in the sense of ``attitude_bias_sigma_is``."""
    attitude_bias_sigma_is: Literal["total_tilt", "per_axis", "total_angle"] = "total_tilt"
    """What attitude_bias_sigma_deg is the sigma of: "total_tilt", the RMS tilt angle (each axis
    sigma / sqrt(2)); "per_axis", each axis; "total_angle", the RMS rotation angle (each axis sigma / sqrt(3))."""
    attitude_random_sigma_deg: float = Field(0.05, ge=0.0, le=10.0)
    """Between-image attitude error, world frame, per axis (deg)."""
    alignment_sigma_deg: float = Field(0.1, ge=0.0, le=10.0)
    """Camera-to-lander alignment error, body frame, per axis (deg)."""
    angular_rate_noise_sigma_dps: float = Field(0.1, ge=0.0, le=60.0)
    """Angular rate white noise per image, body frame, per axis (deg/s)."""
    radar_altitude_sigma_percent: float = Field(0.03, ge=0.0, le=10.0)
    """Radar altitude relative error per image (percent)."""
    imu_velocity_bias_sigma_mps: float = Field(2.0, ge=0.0, le=50.0)
    """Constant IMU velocity bias per horizontal axis (m/s)."""
    imu_vertical_velocity_bias_sigma_mps: float = Field(0.0, ge=0.0, le=50.0)
    """Constant IMU vertical velocity bias (m/s)."""
    imu_velocity_random_walk_mps_per_sqrt_s: float = Field(0.0, ge=0.0, le=10.0)
    """IMU velocity random walk from image 1 (m/s per sqrt(s))."""
    state_time: Literal["mid_exposure", "exposure_start"] = "mid_exposure"
    """Instant the measured states refer to."""
    heat_shield_prediction: bool = True
    """Give the estimator a predicted heat-shield position."""
    heat_shield_prediction_sigma_m: float = Field(10.0, ge=0.0, le=1000.0)
    """Error of the heat-shield prediction per axis per image (m)."""

    @model_validator(mode="wrap")
    @classmethod
    def _perfect_zeroes_sigmas(cls, data: Any, handler: ModelWrapValidatorHandler[SensorConfig]) -> SensorConfig:
        config = handler(data)        # the given sigmas are validated first
        if not config.perfect:
            return config
        # perfect overrides them: a second validated model with zero sigmas (nothing is mutated)
        return handler({**config.model_dump(), **dict.fromkeys(SIGMA_FIELDS, 0.0)})

    @classmethod
    def exact(cls, state_time: Literal["mid_exposure", "exposure_start"] = "mid_exposure", heat_shield_prediction: bool = True) -> SensorConfig:
        """A sensor configuration with every sensor exact.

        Parameters
        ----------
        state_time : {"mid_exposure", "exposure_start"}, optional
            When each image's state is given.
        heat_shield_prediction : bool, optional
            Whether the heat shield position is predicted for the estimator.

        Returns
        -------
        SensorConfig
            All error sigmas zero.
        """
        return cls(perfect=True, state_time=state_time, heat_shield_prediction=heat_shield_prediction)

    @property
    def attitude_bias_sigma_rad(self) -> float:
        """Absolute attitude-knowledge bias sigma per axis (rad)."""
        return math.radians(self.attitude_bias_sigma_deg)

    @property
    def attitude_bias_axis_sigma_rad(self) -> float:
        """Sigma of the bias on each world axis (rad)."""
        axes = {"total_tilt": 2.0, "per_axis": 1.0, "total_angle": 3.0}[self.attitude_bias_sigma_is]
        return self.attitude_bias_sigma_rad / math.sqrt(axes)

    @property
    def attitude_random_sigma_rad(self) -> float:
        """Between-image random attitude error sigma per axis (rad)."""
        return math.radians(self.attitude_random_sigma_deg)

    @property
    def alignment_sigma_rad(self) -> float:
        """Camera-to-lander alignment error sigma per axis (rad)."""
        return math.radians(self.alignment_sigma_deg)

    @property
    def angular_rate_noise_sigma_radps(self) -> float:
        """Angular-rate noise sigma per axis (rad/s)."""
        return math.radians(self.angular_rate_noise_sigma_dps)

    @property
    def radar_altitude_sigma_fraction(self) -> float:
        """Radar altitude error sigma as a fraction of the altitude."""
        return self.radar_altitude_sigma_percent / 100.0


def _state_times(profile: DescentProfile, camera, config: SensorConfig) -> np.ndarray:
    times = np.asarray(profile.image_times_s, dtype=float)
    if config.state_time == "exposure_start":
        return times
    if camera is None:
        raise ValueError("sensors: state_time = 'mid_exposure' needs the camera (for its exposure time)")
    return camera.timing.exposure_mid_time_s(times)


CASE_ERROR_FIELDS = (
    ("attitude_bias_east_rad", "absolute attitude-knowledge bias b, east axis (world)"),
    ("attitude_bias_north_rad", "absolute attitude-knowledge bias b, north axis (world)"),
    ("attitude_bias_up_rad", "absolute attitude-knowledge bias b, up axis (world)"),
    ("imu_velocity_bias_east_mps", "constant IMU velocity bias, east"),
    ("imu_velocity_bias_north_mps", "constant IMU velocity bias, north"),
    ("imu_velocity_bias_up_mps", "constant IMU velocity bias, up"),
    ("alignment_x_rad", "camera-to-lander alignment error a, body x"),
    ("alignment_y_rad", "camera-to-lander alignment error a, body y"),
    ("alignment_z_rad", "camera-to-lander alignment error a, body z"),
)
"""The errors :func:`measure` draws once per descent: (name with its SI unit as suffix, meaning), in the
order of its ``truth`` dict."""

IMAGE_ERROR_FIELDS = (
    ("attitude_random_image{k}_east_rad", "between-image random attitude error r_k, east (world)"),
    ("imu_velocity_error_image{k}_east_mps", "IMU velocity error (bias + random walk), east"),
    ("attitude_random_image{k}_north_rad", "between-image random attitude error r_k, north (world)"),
    ("imu_velocity_error_image{k}_north_mps", "IMU velocity error (bias + random walk), north"),
    ("attitude_random_image{k}_up_rad", "between-image random attitude error r_k, up (world)"),
    ("imu_velocity_error_image{k}_up_mps", "IMU velocity error (bias + random walk), up"),
    ("angular_rate_noise_image{k}_x_radps", "angular-rate noise, body x"),
    ("angular_rate_noise_image{k}_y_radps", "angular-rate noise, body y"),
    ("angular_rate_noise_image{k}_z_radps", "angular-rate noise, body z"),
    ("attitude_error_image{k}_rad", "total angle between measured and true attitude"),
    ("radar_altitude_error_image{k}_m", "radar altitude error"),
    ("heat_shield_prediction_error_image{k}_m", "norm of the heat-shield prediction error (0 when none)"),
)
"""The errors :func:`measure` draws per image ``k`` (from 1), in the order of its ``truth`` dict."""


def error_fields(image_count: int) -> list[tuple[str, str]]:
    """Names and meanings of every error :func:`measure` returns for a descent.

    Parameters
    ----------
    image_count : int
        Number of images of the descent.

    Returns
    -------
    list of (str, str)
        ``(name, meaning)`` in the order of the ``truth`` dict (the case-level errors, then image 1, 2,
        ...). Names end with the SI unit: ``_rad``, ``_radps`` (rad/s), ``_mps`` (m/s), ``_m``.
    """
    per_image = [(name.format(k=k), f"{meaning}, image {k}")
                 for k in range(1, image_count + 1) for name, meaning in IMAGE_ERROR_FIELDS]
    return [*CASE_ERROR_FIELDS, *per_image]


def measure(profile: DescentProfile, camera, sun_direction_world: np.ndarray, config: SensorConfig,
            rng: np.random.Generator) -> tuple[DescentMeasurements, dict[str, float]]:
    """Measurements at every image of ``profile`` and the errors drawn.

    Parameters
    ----------
    profile : DescentProfile
        True trajectory (already placed on the terrain).
    camera : flight_interface.camera.Camera or None
        Used for its exposure time (``state_time = "mid_exposure"``); may be None with "exposure_start".
    sun_direction_world : (3,)
        Unit vector from the ground toward the sun (known from ephemeris; passed through exactly).
    config : SensorConfig
    rng : numpy Generator, seeded per case by the caller.

    Returns
    -------
    measurements : DescentMeasurements
    truth : dict of float
        The drawn errors (SI units in the names): ``attitude_bias_{east,north,up}_rad``,
        ``alignment_{x,y,z}_rad`` (body), per image k (from 1) ``attitude_random_image{k}_{east,north,up}_rad``,
        ``attitude_error_image{k}_rad`` (total angle between measured and true attitude),
        ``angular_rate_noise_image{k}_{x,y,z}_radps``, ``radar_altitude_error_image{k}_m``,
        ``imu_velocity_error_image{k}_{east,north,up}_mps``, ``heat_shield_prediction_error_image{k}_m``
        (norm; 0 when no prediction) and ``imu_velocity_bias_{east,north,up}_mps``.
    """
    state_times = _state_times(profile, camera, config)
    count = len(state_times)
    normals = rng.standard_normal(9 + 13 * count)
    bias = config.attitude_bias_axis_sigma_rad * normals[0:3]
    alignment = config.alignment_sigma_rad * normals[3:6]
    imu_bias = normals[6:9] * np.array([config.imu_velocity_bias_sigma_mps, config.imu_velocity_bias_sigma_mps,
                                        config.imu_vertical_velocity_bias_sigma_mps])
    per_image = normals[9:9 + 10 * count].reshape(count, 10)
    shield_noise = config.heat_shield_prediction_sigma_m * normals[9 + 10 * count:].reshape(count, 3)
    random_attitude = config.attitude_random_sigma_rad * per_image[:, 0:3]
    rate_noise = config.angular_rate_noise_sigma_radps * per_image[:, 3:6]
    altitude_noise = config.radar_altitude_sigma_fraction * per_image[:, 6]
    intervals = np.diff(np.concatenate([[state_times[0]], state_times]))
    walk = np.cumsum(config.imu_velocity_random_walk_mps_per_sqrt_s * np.sqrt(intervals)[:, None] * per_image[:, 7:10], axis=0)

    images, truth = [], {}
    for name, values in (("attitude_bias", bias), ("imu_velocity_bias", imu_bias)):
        for axis, label in enumerate(("east", "north", "up")):
            truth[f"{name}_{label}_mps" if name.startswith("imu") else f"{name}_{label}_rad"] = float(values[axis])
    for axis, label in enumerate("xyz"):
        truth[f"alignment_{label}_rad"] = float(alignment[axis])
    alignment_quat = quat_from_rotation_vector(alignment)
    for k, time_s in enumerate(state_times):
        pose = profile.pose(float(time_s))
        true_attitude = quat_normalize(pose.attitude_quat)
        world_error = quat_from_rotation_vector(bias + random_attitude[k])
        measured = quat_normalize(quat_multiply(quat_multiply(world_error, true_attitude), alignment_quat))
        altitude = float(pose.position_m[2])
        velocity_error = imu_bias + walk[k]
        shield = None
        if config.heat_shield_prediction and pose.heat_shield_position_m is not None:
            shield = pose.heat_shield_position_m - pose.position_m + shield_noise[k]
        images.append(ImageMeasurement(
            time_s=float(profile.image_times_s[k]), attitude_quat=measured,
            angular_rate_radps=np.asarray(pose.angular_rate_radps, dtype=float) + rate_noise[k],
            radar_altitude_m=altitude * (1.0 + float(altitude_noise[k])),
            imu_velocity_mps=np.asarray(pose.velocity_mps, dtype=float) + velocity_error, heat_shield_offset_m=shield))
        n = k + 1
        for axis, label in enumerate(("east", "north", "up")):
            truth[f"attitude_random_image{n}_{label}_rad"] = float(random_attitude[k, axis])
            truth[f"imu_velocity_error_image{n}_{label}_mps"] = float(velocity_error[axis])
        for axis, label in enumerate("xyz"):
            truth[f"angular_rate_noise_image{n}_{label}_radps"] = float(rate_noise[k, axis])
        error = quat_to_rotation_vector(quat_multiply(measured, quat_conjugate(true_attitude)))
        truth[f"attitude_error_image{n}_rad"] = float(np.linalg.norm(error))
        truth[f"radar_altitude_error_image{n}_m"] = altitude * float(altitude_noise[k])
        truth[f"heat_shield_prediction_error_image{n}_m"] = float(np.linalg.norm(shield_noise[k])) if shield is not None else 0.0
    sun = np.asarray(sun_direction_world, dtype=float)
    return DescentMeasurements(images=tuple(images), sun_direction_world=sun / np.linalg.norm(sun)), truth
