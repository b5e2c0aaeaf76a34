"""A minimal ``kind = "python"`` estimator plug-in.

Copy this file, keep ``estimate``'s signature, replace its body. It imports only numpy, so the copy needs nothing
from this project.

    [[estimators]]
    name = "imu_only"
    kind = "python"
    callable = "estimators.examples.minimal_python:estimate"   # a copy: "my_estimator:estimate", with
                                                                # my_estimator.py importable (see docs)
    [estimators.parameters]                                     # arrives as inputs.parameters
    imu_bias_sigma_mps = 2.0
    min_signal_dn = 50.0

What it does (a baseline, not a vision estimator): it answers the IMU's horizontal velocity at the last
image, which still carries the IMU's unknown bias, and says so in its stated uncertainty,
``sqrt(2) x imu_bias_sigma_mps`` (the RMS of a horizontal error with that sigma per axis). It is valid
only when every image shows lit ground (mean signal above the ADC offset of at least ``min_signal_dn``,
after the flat field) and the sun is above the horizon. Per image it reports one "feature": the image's
flat-fielded mean and standard deviation (DN).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np


def estimate(inputs: Any) -> dict:
    """One case's answer.

    Parameters
    ----------
    inputs : estimators.contract.EstimatorInputs
        The case's images, measurements, camera, flat field and parameters (read-only arrays).

    Returns
    -------
    dict
        The answer's JSON form: horizontal IMU velocity at the last image (m/s, east and north),
        ``valid``, ``reason``, per-image ``features`` and, when valid, ``velocity_uncertainty_mps``.
    """
    parameters = inputs.parameters                       # dict from [estimators.parameters] (JSON types)
    bias_sigma_mps = float(parameters.get("imu_bias_sigma_mps", 2.0))
    min_signal_dn = float(parameters.get("min_signal_dn", 50.0))
    offset_dn = float(inputs.camera.electronics.adc_offset_dn)        # DN of zero signal
    flat = inputs.calibration.flat_field                 # float32 (rows, columns), ~1 on axis, or None

    features, signal_dn = [], []
    for image in inputs.images:                          # uint16 DN (rows, columns) = camera.binned_shape
        signal = np.asarray(image, dtype=np.float64) - offset_dn        # a copy: the input is read-only
        if flat is not None:
            signal /= np.maximum(flat, 1e-3)
        signal_dn.append(float(signal.mean()))
        features.append({"brightness_dn": signal_dn[-1] + offset_dn, "contrast_dn": float(signal.std()), "status": "ok"})

    last = inputs.measurements.images[-1]                # ImageMeasurement of the last image
    east_mps, north_mps = float(last.imu_velocity_mps[0]), float(last.imu_velocity_mps[1])   # world x east, y north
    answer = {"velocity_east_mps": east_mps, "velocity_north_mps": north_mps, "features": features}
    if inputs.measurements.sun_direction_world[2] <= 0.0:          # z up: the sun at or below the horizon
        return {**answer, "valid": False, "reason": "sun_below_horizon"}
    if min(signal_dn) < min_signal_dn:
        return {**answer, "valid": False, "reason": "no_signal"}
    return {**answer, "valid": True, "reason": "ok", "velocity_uncertainty_mps": math.sqrt(2.0) * bias_sigma_mps}
