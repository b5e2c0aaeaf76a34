"""Python callables plugged in by the plugin tests (``kind = "python"``): one that keeps the contract,
and ones that break it (bad output, crash, exit, writes into the read-only inputs, implausible answers)."""
import sys
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


def halves_image(inputs):
    """Writes into its input images (``image //= 2``): must raise, the images are read-only."""
    for image in inputs.images:
        image //= 2
    return imu_minus_bias(inputs)


def scales_flat(inputs):
    """Writes into the (per-worker cached) flat field: must raise, it is read-only."""
    flat = inputs.calibration.flat_field
    flat *= 1.5
    return imu_minus_bias(inputs)


def changes_imu(inputs):
    """Writes into a measurement array: must raise, it is read-only."""
    inputs.measurements.images[-1].imu_velocity_mps[:] = 0.0
    return imu_minus_bias(inputs)


def exits(inputs):
    sys.exit(3)


def interrupts(inputs):
    raise KeyboardInterrupt


def too_fast(inputs):
    return {"velocity_east_mps": 1e30, "velocity_north_mps": 0.0, "valid": True, "reason": "ok"}


def negative_uncertainty(inputs):
    return {**imu_minus_bias(inputs), "velocity_uncertainty_mps": -1.0}


def changes_camera(inputs):
    """Writes into the camera model shared by the simulator and every estimator: must raise, it is read-only."""
    inputs.camera.falloff_map[:] = 1.0
    return imu_minus_bias(inputs)


def writes_through_base(inputs):
    """Gets around the read-only view (writes into the array behind it): `campaign check-estimators` must
    see the changed input."""
    image = inputs.images[0]
    if image.base is not None and image.base.flags.writeable:
        image.base[0, 0] += 1
    return imu_minus_bias(inputs)


def differs_on_worker(inputs):
    """Answers 1 m/s more east in a spawned (worker) process than in the driver's main process."""
    import multiprocessing

    answer = imu_minus_bias(inputs)
    if multiprocessing.parent_process() is not None:
        answer["velocity_east_mps"] += 1.0
    return answer
