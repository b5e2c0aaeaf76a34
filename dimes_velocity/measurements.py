"""What the flight system measured when each descent image was taken (the estimator's inputs
besides the images). Frames as in :mod:`simulator.kinematics`: world x east, y north, z up;
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
    """

    time_s: float
    attitude_quat: np.ndarray
    angular_rate_radps: np.ndarray
    radar_altitude_m: float
    imu_velocity_mps: np.ndarray


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
