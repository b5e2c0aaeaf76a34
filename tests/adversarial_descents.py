"""Image triples built to fool a feature-tracking velocity estimator, each with a known true answer.

Not part of the estimator. Scenes are rendered fast but with the simulator's real camera chain
(:func:`simulator.detector.camera_chain.render_image`: falloff, PRNU, dark current, flush and transfer smear, shot
and read noise, 12-bit ADC): the ground I/F is sampled along the mean ray of each 4 x 4 binning
block (the camera sums 4 rows on chip, the estimator 4 columns, so sub-block detail never reaches
the estimator), ray-plane intersection with the level ground z = 0, and the block radiance fills
the block's 16 pixels. The lander moves at constant velocity with exact measured attitude and
altitude; the IMU velocity carries a known constant bias. The truth is the lander's horizontal
velocity, whatever is done to the images or measurements afterwards.

Families (:data:`FAMILIES`): ``ordinary`` (band-limited random terrain, nothing done to it) and the
adversaries: ``dune_ripples`` and ``crater_lattice`` (repetitive texture; IMU biases place the true
peak anywhere in the search window, so an alias can sit nearer the prediction than the truth),
``uncorrelated`` (one image from another place), ``shifted_copy`` / ``rotated_copy`` (one image
replaced by a shifted or rotated copy of another), ``image_fixed_spots`` / ``random_spots``
(planted bright spots that stay in the image plane, or differ per image), ``unmodelled_yaw`` /
``unmodelled_tilt`` (the camera turned between images but the measured attitude says not),
``offset_gain_jump`` (one image with another gain and ADC offset), ``saturated_blobs`` and
``heat_shield_occlusion`` (a dark disc of the heat shield's apparent size over the ground, in one
image or moving across two, not predicted by the measurements), ``implausible_record`` (the images
untouched, the measurement record contradicting its own physics: the middle IMU velocity 10-27 m/s
off and back, or all three radar altitudes 15-40 % high or low against the IMU's vertical velocity).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from flight_interface.measurements import DescentMeasurements, ImageMeasurement

ALTITUDES_M = (2000.0, 1725.0, 1450.0)
RADIANCE_PER_IF = 160.0          # W m^-2 sr^-1 um^-1 per unit I/F (Mars, 0.4-1.1 um)
GROUND_M_PER_PX = 5.0
GROUND_PX = 1024
FAMILIES = ("ordinary", "dune_ripples", "crater_lattice", "uncorrelated", "shifted_copy", "rotated_copy",
            "image_fixed_spots", "random_spots", "unmodelled_yaw", "unmodelled_tilt", "offset_gain_jump",
            "saturated_blobs", "heat_shield_occlusion", "implausible_record")


@dataclass(frozen=True)
class AdversarialCase:
    """One generated triple.

    Attributes
    ----------
    family : str
        One of :data:`FAMILIES`.
    images : list of ndarray uint16 (256, 1024)
    measurements : DescentMeasurements
    truth_velocity_mps : ndarray (2,)
        True horizontal velocity (east, north) at the last image (constant velocity).
    """

    family: str
    images: list
    measurements: DescentMeasurements
    truth_velocity_mps: np.ndarray


def quaternion(axis, angle_rad: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[np.cos(0.5 * angle_rad)], np.sin(0.5 * angle_rad) * axis])


def multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = p
    w2, x2, y2, z2 = q
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


# ------------------------------------------------------------------------------------------------ ground
def _grid():
    half = 0.5 * (GROUND_PX - 1) * GROUND_M_PER_PX
    coordinates = np.linspace(-half, half, GROUND_PX, dtype=np.float32)
    return coordinates[None, :], -coordinates[:, None]            # east (columns), north (rows, north up)


def random_field(rng: np.random.Generator) -> np.ndarray:
    """Band-limited random field of unit standard deviation (power-law spectrum, slope 1.2-1.8,
    smallest scale 12-20 m), float32 (GROUND_PX, GROUND_PX)."""
    fy = np.fft.fftfreq(GROUND_PX).astype(np.float32)[:, None]
    fx = np.fft.rfftfreq(GROUND_PX).astype(np.float32)[None, :]
    frequency = np.hypot(fx, fy)
    cutoff = GROUND_M_PER_PX / rng.uniform(12.0, 20.0)
    amplitude = np.where(frequency > 0, (frequency + 1.0 / GROUND_PX) ** -rng.uniform(1.2, 1.8), 0.0)
    amplitude *= np.exp(-(frequency / cutoff) ** 2)
    spectrum = amplitude * (rng.standard_normal(amplitude.shape, dtype=np.float32)
                            + 1j * rng.standard_normal(amplitude.shape, dtype=np.float32))
    field = np.fft.irfft2(spectrum, s=(GROUND_PX, GROUND_PX)).astype(np.float32)
    return field / max(float(field.std()), 1e-30)


def random_terrain(rng: np.random.Generator, contrast: float) -> np.ndarray:
    """Band-limited random I/F: mean 0.22, relative standard deviation ``contrast``."""
    return np.clip(0.22 * (1.0 + contrast * random_field(rng)), 0.01, None).astype(np.float32)


def ripple_terrain(rng: np.random.Generator, background: np.ndarray) -> np.ndarray:
    """Dune ripples: parallel crests of one wavelength (25-120 m, any direction), asymmetric profile,
    on a faint random ``background`` (unit standard deviation, scaled to 1 %)."""
    east, north = _grid()
    angle = rng.uniform(0.0, np.pi)
    wavelength = rng.uniform(25.0, 120.0)
    phase = 2.0 * np.pi * (east * np.cos(angle) + north * np.sin(angle)) / wavelength
    profile = np.sin(phase) + 0.35 * np.sin(2.0 * phase + 0.8)
    return np.clip(0.22 * (1.0 + rng.uniform(0.05, 0.2) * profile + 0.01 * background), 0.01, None).astype(np.float32)


def lattice_terrain(rng: np.random.Generator, background: np.ndarray) -> np.ndarray:
    """A regular crater field: identical craters (dark floor, bright rim) on a square or hexagonal
    lattice (spacing 40-150 m, any orientation), optionally jittered by up to 5 % of the spacing, on a
    faint random ``background``."""
    east, north = _grid()
    spacing = rng.uniform(40.0, 150.0)
    angle = rng.uniform(0.0, np.pi)
    hexagonal = rng.random() < 0.5
    u = (east * np.cos(angle) + north * np.sin(angle)) / spacing
    v = (-east * np.sin(angle) + north * np.cos(angle)) / spacing
    if hexagonal:
        v = v / (np.sqrt(3.0) / 2.0)
        u = u + 0.5 * (np.floor(v) % 2)
    jitter = rng.uniform(0.0, 0.05) if rng.random() < 0.5 else 0.0
    du = u - np.round(u) + jitter * np.sin(7.1 * np.round(u) + 3.7 * np.round(v))
    dv = v - np.round(v)
    if hexagonal:
        dv = dv * (np.sqrt(3.0) / 2.0)
    r = np.hypot(du, dv) * spacing / (rng.uniform(0.25, 0.4) * spacing)       # in crater radii
    crater = np.where(r < 0.8, -1.0, 0.0) + np.exp(-((r - 1.0) / 0.15) ** 2)
    return np.clip(0.22 * (1.0 + rng.uniform(0.08, 0.25) * crater + 0.01 * background), 0.01, None).astype(np.float32)


# ------------------------------------------------------------------------------------------------ render
class Renderer:
    """Renders binned images of a ground I/F grid with the simulator's camera chain (module docstring)."""

    def __init__(self, camera):
        self.camera = camera
        b = camera.binning_rows
        rays = camera.pixel_rays.reshape(camera.height_px // b, b, camera.width_px // b, b, 3).mean(axis=(1, 3))
        self.block_rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        self.focal_block_px = float(camera.model.hs) / b

    def radiance(self, ground: np.ndarray, position_m: np.ndarray, attitude: np.ndarray) -> np.ndarray:
        camera = self.camera
        body = rotation(attitude)
        to_world = body @ camera.camera_to_lander_matrix
        centre = np.asarray(position_m, float) + body @ camera.camera_position_in_lander_m + to_world @ camera.model.c
        rays = self.block_rays @ to_world.T
        down = rays[..., 2] < -1e-6
        distance = np.where(down, -centre[2] / np.where(down, rays[..., 2], -1.0), 0.0)
        half = 0.5 * (GROUND_PX - 1) * GROUND_M_PER_PX
        columns = ((centre[0] + distance * rays[..., 0] + half) / GROUND_M_PER_PX).astype(np.float32)
        rows = ((half - centre[1] - distance * rays[..., 1]) / GROUND_M_PER_PX).astype(np.float32)
        columns[~down] = -10.0
        sigma = 0.45 * centre[2] / self.focal_block_px / GROUND_M_PER_PX     # block footprint on the ground
        blurred = cv2.GaussianBlur(ground, (0, 0), max(sigma, 0.3))
        value = cv2.remap(blurred, columns, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return value * np.float32(RADIANCE_PER_IF)

    def image(self, ground: np.ndarray, position_m, attitude, rng: np.random.Generator) -> np.ndarray:
        from simulator.detector.camera_chain import render_image

        block = self.radiance(ground, position_m, attitude)                       # (256, 256)
        b = self.camera.binning_rows
        per_block = np.repeat(block, b, axis=1)                                    # (256, 1024)
        exposure = np.repeat(per_block, b, axis=0)                                 # (1024, 1024)
        return render_image(self.camera, (per_block, exposure, per_block), rng).dn


@dataclass(frozen=True)
class Descent:
    """A rendered constant-velocity descent (exact attitude and altitude measurements, no IMU bias yet)."""

    images: list
    times_s: np.ndarray
    positions_m: np.ndarray
    attitudes: list
    velocity_mps: np.ndarray
    sun: np.ndarray

    def measurements(self, bias_mps=(0.0, 0.0), attitudes=None) -> DescentMeasurements:
        imu = self.velocity_mps + np.array([bias_mps[0], bias_mps[1], 0.0])
        attitudes = self.attitudes if attitudes is None else attitudes
        records = tuple(ImageMeasurement(time_s=float(t), attitude_quat=np.asarray(q, float),
                                         angular_rate_radps=np.zeros(3), radar_altitude_m=float(p[2]),
                                         imu_velocity_mps=imu.copy())
                        for t, p, q in zip(self.times_s, self.positions_m, attitudes))
        return DescentMeasurements(images=records, sun_direction_world=self.sun)

    def case(self, family: str, images=None, bias_mps=(0.0, 0.0), attitudes=None) -> AdversarialCase:
        return AdversarialCase(family, list(self.images if images is None else images),
                               self.measurements(bias_mps, attitudes), self.velocity_mps[:2].copy())


def random_descent(renderer: Renderer, ground: np.ndarray, rng: np.random.Generator, max_tilt_deg=10.0) -> Descent:
    """Constant velocity (horizontal up to 25 m/s, vertical 67-77 m/s down), images at 2000, 1725 and
    1450 m, attitude tilted up to ``max_tilt_deg`` about a random horizontal axis with any heading and
    a little motion between images; sun 35-70 deg high."""
    speed = rng.uniform(0.0, 25.0)
    heading = rng.uniform(0.0, 2.0 * np.pi)
    velocity = np.array([speed * np.sin(heading), speed * np.cos(heading), -rng.uniform(67.0, 77.0)])
    altitudes = np.array(ALTITUDES_M)
    times = (altitudes[0] - altitudes) / -velocity[2]
    start = rng.uniform(-400.0, 400.0, size=2) - velocity[:2] * times[1]
    positions = np.column_stack([start[0] + velocity[0] * times, start[1] + velocity[1] * times, altitudes])
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    axis = rng.uniform(0.0, 2.0 * np.pi)
    tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
    attitudes = []
    for _k in range(len(altitudes)):
        wobble = np.radians(rng.uniform(-1.0, 1.0))
        q = multiply(quaternion([0, 0, 1], yaw + 0.5 * wobble),
                     quaternion([np.cos(axis), np.sin(axis), 0.0], tilt + wobble))
        attitudes.append(q)
    elevation, azimuth = np.radians(rng.uniform(35.0, 70.0)), rng.uniform(0.0, 2.0 * np.pi)
    sun = np.array([np.cos(elevation) * np.sin(azimuth), np.cos(elevation) * np.cos(azimuth), np.sin(elevation)])
    images = [renderer.image(ground, p, q, rng) for p, q in zip(positions, attitudes)]
    return Descent(images, times, positions, attitudes, velocity, sun)


def random_bias(rng: np.random.Generator, limit_mps: float = 20.0) -> tuple[float, float]:
    magnitude, angle = limit_mps * np.sqrt(rng.random()), rng.uniform(0.0, 2.0 * np.pi)
    return magnitude * np.cos(angle), magnitude * np.sin(angle)
