"""The plug-in of ``my_estimator_gusev.toml``: a template for your own velocity estimator.

What it estimates: the horizontal velocity at the last image as the IMU measured it (dead reckoning,
no vision). It is the baseline a vision estimator has to beat: its error is the IMU's velocity bias,
which DIMES exists to measure. Replace the body of :func:`estimate` with your own estimator; the
inputs and the answer are described in docs/estimators.md (the estimator contract).

It imports nothing from this project (numpy only): plug-in code depends on the contract, not on the
simulator. The campaign ships this file to its dask workers.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np


def estimate(inputs: Any) -> Mapping[str, Any]:
    """Horizontal velocity at the last image from the IMU alone.

    Parameters
    ----------
    inputs : estimators.contract.EstimatorInputs
        The case's images, measurements, camera, calibration and ``parameters`` (the
        ``[[estimators]]`` entry's table): ``stated_uncertainty_mps`` (m/s, 1 sigma, default 2.0),
        the uncertainty this estimator states for its answer.

    Returns
    -------
    Mapping
        ``velocity_east_mps``, ``velocity_north_mps`` (m/s, world frame x east, y north), ``valid``,
        ``reason`` and ``velocity_uncertainty_mps`` (m/s).
    """
    velocity_mps = np.asarray(inputs.measurements.images[-1].imu_velocity_mps, dtype=float)
    if not np.all(np.isfinite(velocity_mps[:2])):
        return {"velocity_east_mps": None, "velocity_north_mps": None, "valid": False, "reason": "no_imu_velocity"}
    return {"velocity_east_mps": float(velocity_mps[0]), "velocity_north_mps": float(velocity_mps[1]),
            "valid": True, "reason": "ok",
            "velocity_uncertainty_mps": float(inputs.parameters.get("stated_uncertainty_mps", 2.0))}
