"""Python callables plugged in by the plugin tests (``kind = "python"``): one that keeps the contract,
and ones that break it."""
import time

import numpy as np


def imu_minus_bias(inputs):
    """Velocity = IMU velocity at the last image minus ``parameters["bias"]``; features carry each
    image's mean DN and the flat field's mean (-1 without one)."""
    last = np.asarray(inputs.measurements.images[-1].imu_velocity_mps, dtype=float)
    bias = inputs.parameters.get("bias", [0.0, 0.0])
    flat = inputs.calibration.flat_field
    return {"velocity_east_mps": last[0] - bias[0], "velocity_north_mps": last[1] - bias[1], "valid": True,
            "reason": "ok", "features": [{"brightness_dn": float(np.mean(image)),
                                          "contrast_dn": -1.0 if flat is None else float(np.mean(flat))}
                                         for image in inputs.images]}


def raises(inputs):
    raise RuntimeError("flight code assertion: attitude quaternion not normalised")


def forgets_valid(inputs):
    return {"velocity_east_mps": 1.0, "velocity_north_mps": 2.0, "reason": "ok"}


def hangs(inputs):
    time.sleep(120)
