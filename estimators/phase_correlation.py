"""Example estimator: whole-image phase correlation of rectified descent images.

A real, simpler alternative to feature tracking, shipped so users see how another method compares on
the same cases (``kind = "python"``, ``callable = "estimators.phase_correlation:estimate"``).

Method
------
1. Pre-process and rectify like the reference estimator (:mod:`dimes_velocity.preprocess` and
   :mod:`dimes_velocity.geometry`): bin to 256 x 256, remove dark and smear, divide by the flat field
   (the calibration product; the design falloff without one), and project each image of a pair onto
   *one* level ground grid (the first image's nadir sampling, centred between the two boresight
   ground points) from the measured attitude, radar altitude and IMU-predicted positions. The lower
   image is blurred first so that both have the first image's resolution on the ground.
2. Ground the camera does not see, the zero-phase zone and saturated or dark pixels are filled with
   the mean of the usable ground, and each image is high-passed (minus a Gaussian of
   ``highpass_sigma_px``) so that albedo gradients do not dominate.
3. ``cv2.phaseCorrelate`` with a Hanning window gives the shift of the second image's view against
   the first and the peak's response. With positions predicted from the biased IMU, the shift is the
   ground offset ``d = bias * dt`` (``d_east = shift_x * sample``, ``d_north = -shift_y * sample``).
4. The velocity is the IMU velocity at the last image minus the mean of the two pairs' biases.

Validity test (own reason codes)
--------------------------------
``bad_attitude``     an image looks further than ``max_off_nadir_deg`` from nadir
``no_overlap``       less than ``min_overlap`` of the common grid is usable in both images
``low_response``     a pair's phase-correlation peak response is below ``min_response``
``shift_out_of_range`` a pair's shift implies a bias above ``max_velocity_bias_mps`` (not a real peak)
``pairs_disagree``   the two pairs' biases differ by more than ``pair_agreement_mps``

Parameters (``inputs.parameters``; defaults in :data:`DEFAULTS`) are checked on every call: an
unknown key or a wrong type raises ``ValueError`` (recorded as this estimator's failed result). The
thresholds were chosen on 57 Gusev cases of campaign seed 7 (not the seed of the README tables): a
blank scene gives a response near 0, textured pairs 0.3-0.95, and no valid answer there was off by
more than 4.2 m/s even with the response test and pair check switched off.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from dimes_velocity import geometry
from dimes_velocity.config import EstimatorConfig
from dimes_velocity.preprocess import flatten, make_flattening
from estimators.contract import EstimatorInputs, EstimatorOutput
from flight_interface.measurements import validate_measurements

DEFAULTS = {
    "grid_size_px": 256,            # side of the common rectified grid (power of two: fast FFT)
    "min_response": 0.05,           # phase-correlation peak response for a valid pair (noise: ~0)
    "min_overlap": 0.25,            # usable fraction of the grid in both images
    "max_velocity_bias_mps": 25.0,  # largest plausible IMU bias (shift range)
    "pair_agreement_mps": 4.0,      # the two pairs' biases must agree within this
    "highpass_sigma_px": 8.0,       # Gaussian subtracted before correlation (grid pixels)
    "max_off_nadir_deg": 60.0,
    "min_signal_dn": 40.0,          # flattened binned DN below this is no signal
}

_FLATTENING: dict = {}


def _parameters(given) -> dict:
    values = dict(DEFAULTS)
    for key, value in dict(given or {}).items():
        if key not in DEFAULTS:
            raise ValueError(f"parameter {key!r} is unknown; allowed: {', '.join(DEFAULTS)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"parameter {key!r} must be a finite number; got {value!r}")
        values[key] = value
    if int(values["grid_size_px"]) < 32:
        raise ValueError(f"parameter 'grid_size_px' = {values['grid_size_px']}; allowed: >= 32")
    return values


def _flattening(inputs: EstimatorInputs, min_signal_dn: float):
    """Per camera / flat field / threshold constants of the reference pre-processing (cached)."""
    flat = inputs.calibration.flat_field
    key = (id(inputs.camera), id(flat), float(min_signal_dn))
    cached = _FLATTENING.get(key)
    if cached is None or cached[0] is not inputs.camera or cached[1] is not flat:
        if len(_FLATTENING) > 8:
            _FLATTENING.clear()
        config = EstimatorConfig(min_signal_dn=float(min_signal_dn))
        cached = (inputs.camera, flat, config, make_flattening(inputs.camera, config, flat))
        _FLATTENING[key] = cached
    return cached[2], cached[3]


def estimate(inputs: EstimatorInputs) -> EstimatorOutput:
    """Phase-correlation velocity estimate for one case (contract of :mod:`estimators.contract`).

    Parameters
    ----------
    inputs : EstimatorInputs
        The case's images, measurements, camera, flat field and parameters (module docstring).

    Returns
    -------
    EstimatorOutput
        The velocity (m/s, world east and north) and validity; when invalid, the IMU's velocity and a
        reason code of the module docstring.
    """
    p = _parameters(inputs.parameters)
    measurements = inputs.measurements
    validate_measurements(measurements)
    camera = inputs.camera
    config, flattening = _flattening(inputs, p["min_signal_dn"])
    flats = [flatten(image, flattening, config) for image in inputs.images]
    positions = geometry.predicted_positions_m(measurements)
    poses = [geometry.camera_pose(camera, m.attitude_quat, m.radar_altitude_m, positions[k])
             for k, m in enumerate(measurements.images)]
    imu_last = np.asarray(measurements.images[-1].imu_velocity_mps, dtype=float)[:2]

    def invalid(reason: str) -> EstimatorOutput:
        return EstimatorOutput(float(imu_last[0]), float(imu_last[1]), False, reason)

    max_off_nadir = math.radians(p["max_off_nadir_deg"])
    if any(pose.off_nadir_rad > max_off_nadir or pose.centre_m[2] <= 0.0 for pose in poses):
        return invalid("bad_attitude")
    sun = np.asarray(measurements.sun_direction_world, dtype=float)
    anti_sun = -sun / np.linalg.norm(sun)
    focal_px = geometry.binned_focal_px(camera)
    times = np.array([m.time_s for m in measurements.images])
    biases = []
    for k in range(len(inputs.images) - 1):
        dt = float(times[k + 1] - times[k])
        shift, response, overlap, sample_m = _pair_shift(flats[k], flats[k + 1], poses[k], poses[k + 1], camera,
                                                         focal_px, anti_sun, max_off_nadir, p)
        if overlap < p["min_overlap"]:
            return invalid("no_overlap")
        if response < p["min_response"]:
            return invalid("low_response")
        displacement = np.array([shift[0], -shift[1]]) * sample_m
        bias = displacement / dt
        if float(np.linalg.norm(bias)) > p["max_velocity_bias_mps"]:
            return invalid("shift_out_of_range")
        biases.append(bias)
    stacked = np.array(biases)
    spread = float(np.linalg.norm(stacked[:, None, :] - stacked[None, :, :], axis=-1).max())
    if spread > p["pair_agreement_mps"]:
        return invalid("pairs_disagree")
    velocity = imu_last - stacked.mean(axis=0)
    return EstimatorOutput(float(velocity[0]), float(velocity[1]), True, "ok")


def _pair_shift(flat_a, flat_b, pose_a, pose_b, camera, focal_px, anti_sun, max_off_nadir, p):
    """Rectify a pair onto one grid and phase-correlate: (shift (x, y) px, response, overlap, sample m)."""
    size = int(p["grid_size_px"])
    height_a, height_b = pose_a.centre_m[2], pose_b.centre_m[2]
    sample_m = max(float(height_a), float(height_b)) / focal_px * 256.0 / size
    centre = 0.5 * (geometry.ground_centre_m(pose_a, max_off_nadir) + geometry.ground_centre_m(pose_b, max_off_nadir))
    grids = []
    for flat, pose in ((flat_a, pose_a), (flat_b, pose_b)):
        rectification = geometry.rectify_map(pose, camera, size, sample_m, centre, 17, anti_sun, math.radians(4.3))
        signal = flat.signal_dn
        ratio = sample_m * focal_px / pose.centre_m[2]
        blur = 0.5 * math.sqrt(max(ratio * ratio - 1.0, 0.0))
        if blur > 0.05:
            signal = cv2.GaussianBlur(signal, (0, 0), min(blur, 8.0), borderType=cv2.BORDER_REPLICATE)
        image = geometry.warp(signal, rectification)
        bad = geometry.warp(flat.excluded, rectification, cv2.INTER_NEAREST) if flat.excluded.any() else 0
        usable = rectification.visible.astype(bool) & ~rectification.excluded_zone.astype(bool) & (np.asarray(bad) == 0)
        grids.append((image, usable))
    overlap = float(np.count_nonzero(grids[0][1] & grids[1][1])) / (size * size)
    if overlap < p["min_overlap"]:
        return (0.0, 0.0), 0.0, overlap, sample_m
    prepared = []
    for image, usable in grids:
        filled = np.where(usable, image, np.float32(image[usable].mean())).astype(np.float32)
        high = filled - cv2.GaussianBlur(filled, (0, 0), float(p["highpass_sigma_px"]), borderType=cv2.BORDER_REPLICATE)
        prepared.append(np.where(usable, high, 0.0).astype(np.float32))
    window = cv2.createHanningWindow((size, size), cv2.CV_32F)
    shift, response = cv2.phaseCorrelate(prepared[0], prepared[1], window)
    return shift, float(response), overlap, sample_m
