"""Synthetic descent images with known motion, for the tests of the estimators (test helper).

Not the simulator's descent path (:func:`simulator.descent_image.render_descent_image`): exact truth
for the estimator tests. A textured ground plane (a band-limited random reflectance field) is
seen through the camera's CAHVOR model (per-pixel rays from :attr:`Camera.pixel_rays`, ray-plane
intersection, bilinear resampling with ``cv2.remap``) from known poses, and the resulting radiance
is turned into DN by the simulator's public camera chain :func:`simulator.detector.camera_chain.render_image`.
The scene is static during each image's flush, exposure and transfer (no motion blur) and there is
no photometric function, so the truth is exact.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from flight_interface.camera import Camera
from flight_interface.frames import quat_to_matrix
from flight_interface.measurements import DescentMeasurements, ImageMeasurement
from simulator.detector.camera_chain import CameraEffects, render_image

RADIANCE_PER_IF = 160.0   # W m^-2 sr^-1 um^-1 per unit I/F (Mars at 1.52 AU, band 0.4-1.1 um: I/F 0.25 -> 40)


@dataclass(frozen=True)
class Ground:
    """A north-up reflectance grid on the plane z = 0: pixel (row, col) centre at
    ``(east, north) = origin_m + metres_per_pixel * (col, -row)``."""

    reflectance_if: np.ndarray
    metres_per_pixel: float
    origin_m: np.ndarray


def random_ground(rng: np.random.Generator, size_px: int = 2048, metres_per_pixel: float = 3.0,
                  mean_if: float = 0.25, contrast: float = 0.08, slope: float = 1.5,
                  smallest_scale_m: float = 12.0) -> Ground:
    """A band-limited random field with a power-law spectrum (``amplitude ~ f^-slope``), centred on
    the world origin, relative standard deviation ``contrast``; ``contrast = 0`` gives a blank scene."""
    frequency_y = np.fft.fftfreq(size_px)[:, None]
    frequency_x = np.fft.rfftfreq(size_px)[None, :]
    frequency = np.hypot(frequency_x, frequency_y)
    cutoff = metres_per_pixel / smallest_scale_m
    amplitude = np.where(frequency > 0, (frequency + 1.0 / size_px) ** -slope, 0.0) * np.exp(-(frequency / cutoff) ** 2)
    spectrum = amplitude * (rng.standard_normal(amplitude.shape) + 1j * rng.standard_normal(amplitude.shape))
    field = np.fft.irfft2(spectrum, s=(size_px, size_px))
    field = field / max(float(field.std()), 1e-30)
    reflectance = np.clip(mean_if * (1.0 + contrast * field), 0.0, None).astype(np.float32)
    half = 0.5 * (size_px - 1) * metres_per_pixel
    return Ground(reflectance, float(metres_per_pixel), np.array([-half, half]))


def radiance_field(camera: Camera, ground: Ground, lander_position_m: np.ndarray, attitude_quat: np.ndarray,
                   radiance_per_if: float = RADIANCE_PER_IF) -> np.ndarray:
    """Radiance (W m^-2 sr^-1 um^-1) seen by every full-frame pixel, (height, width) float32; 0 for sky
    and for ground outside the reflectance grid."""
    body_to_world = quat_to_matrix(attitude_quat)
    camera_to_world = body_to_world @ camera.camera_to_lander_matrix
    centre = np.asarray(lander_position_m, dtype=float) + body_to_world @ camera.camera_position_in_lander_m
    centre = centre + camera_to_world @ camera.model.c
    rays = camera.pixel_rays @ camera_to_world.T
    down = rays[..., 2] < -1e-9
    distance = np.where(down, -centre[2] / np.where(down, rays[..., 2], -1.0), 0.0)
    east = centre[0] + distance * rays[..., 0]
    north = centre[1] + distance * rays[..., 1]
    columns = ((east - ground.origin_m[0]) / ground.metres_per_pixel).astype(np.float32)
    rows = ((ground.origin_m[1] - north) / ground.metres_per_pixel).astype(np.float32)
    columns[~down] = -10.0
    value = cv2.remap(ground.reflectance_if, columns, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0)
    return (value * np.float32(radiance_per_if)).astype(np.float32)


@dataclass(frozen=True)
class SyntheticDescent:
    """Three images with their true states.

    Attributes
    ----------
    images : list of ndarray uint16 (256, 1024)
    truth : DescentMeasurements
        Exact measurements (true attitude, altitude, velocity; zero bias).
    true_velocity_mps : ndarray (3,)
        Constant world velocity of the lander.
    positions_m : ndarray (K, 3)
        Lander positions at the image times.
    """

    images: list
    truth: DescentMeasurements
    true_velocity_mps: np.ndarray
    positions_m: np.ndarray


def constant_velocity_descent(camera: Camera, ground: Ground, rng: np.random.Generator,
                              velocity_mps=(12.0, -7.0, -72.0), altitudes_m=(2000.0, 1725.0, 1450.0),
                              attitudes=None, start_east_north_m=(0.0, 0.0),
                              sun_direction=(0.5, 0.3, 0.81), noise: bool = True, effects=None) -> SyntheticDescent:
    """Render images at the given altitudes along a constant-velocity descent.

    ``attitudes``: body-to-world quaternions, one per image (default level). Images are taken when the
    lander passes each altitude; times start at 0.
    """

    velocity = np.asarray(velocity_mps, dtype=float)
    altitudes = np.asarray(altitudes_m, dtype=float)
    times = (altitudes[0] - altitudes) / -velocity[2]
    positions = np.column_stack([start_east_north_m[0] + velocity[0] * times,
                                 start_east_north_m[1] + velocity[1] * times, altitudes])
    if attitudes is None:
        attitudes = [np.array([1.0, 0.0, 0.0, 0.0])] * len(altitudes)
    if effects is None:
        effects = CameraEffects() if noise else CameraEffects(shot_noise=False, read_noise=False)
    images, records = [], []
    for _k, (time_s, position, attitude) in enumerate(zip(times, positions, attitudes)):
        radiance = radiance_field(camera, ground, position, attitude)
        rendered = render_image(camera, (radiance, radiance, radiance), rng, effects)
        images.append(rendered.dn if noise else np.rint(rendered.expected_dn).astype(np.uint16))
        records.append(ImageMeasurement(time_s=float(time_s), attitude_quat=np.asarray(attitude, dtype=float),
                                        angular_rate_radps=np.zeros(3), radar_altitude_m=float(position[2]),
                                        imu_velocity_mps=velocity.copy()))
    sun = np.asarray(sun_direction, dtype=float)
    truth = DescentMeasurements(images=tuple(records), sun_direction_world=sun / np.linalg.norm(sun))
    return SyntheticDescent(images=images, truth=truth, true_velocity_mps=velocity, positions_m=positions)
