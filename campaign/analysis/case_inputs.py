"""What went into each case and what came out, as the tables a sensitivity analysis reads.

Inputs (one row per case, the same for every estimator):

- the placement and descent the store recorded: appearance class, heading, offsets, wind, altitudes of
  images 1 and 3, the true horizontal velocity, heat shield in view and fraction of the footprint off the
  terrain (per image: ``..._image<k>``);
- every sensor draw the store recorded (``sensor_*``: attitude biases, alignment, per-image random attitude,
  IMU velocity, angular-rate, radar altitude and heat-shield prediction errors);
- the trajectory's attitude excursion, read from the campaign's trajectory set at the image times: the tilt
  of the lander's z axis from the vertical (``tilt_image<k>_rad``), the angular-rate magnitude
  (``angular_rate_image<k>_radps``) and the descent rate between images 1 and 3 (``descent_rate_mps``).

Outputs, per estimator: ``valid`` (1 when the estimator reported a valid velocity, 0 otherwise, a failed row
included), ``false_valid`` (1 for a valid velocity whose horizontal error exceeds ``[campaign]
false_valid_mps``) and ``velocity_error_mps`` (the horizontal error of the valid velocities only).

Derived columns are left out: ``attitude_floor_mps`` is the error the attitude bias alone causes (a function
of the bias and the descent, not an input), the template statistics (``feature_*``) are what the estimator
measured, ``profile_index`` is a label (its physical content is the trajectory columns above).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flight_interface.frames import quat_to_matrix
from sitedata.edl.trajectory_io import read_profiles

RECORDED_INPUTS = ("class_name", "heading_rad", "offset_east_m", "offset_north_m", "footprint_inside",
                   "wind_east_mps", "wind_north_mps", "altitude_image1_m", "altitude_image3_m",
                   "truth_velocity_east_mps", "truth_velocity_north_mps", "heat_shield_in_view",
                   "outside_terrain_fraction")
"""Result columns that are inputs of a case (besides every ``sensor_*`` column)."""
OUTPUTS = ("valid", "false_valid", "velocity_error_mps")
OUTPUT_MEANINGS = {"valid": "valid velocity (0/1, every case)",
                   "false_valid": "valid but wrong (0/1, every case)",
                   "velocity_error_mps": "horizontal error of the valid velocities (m/s)"}


def trajectory_inputs(trajectory_path: str | Path, profile_indices: np.ndarray) -> pd.DataFrame:
    """Attitude excursion and descent rate of each case's trajectory at its image times.

    Parameters
    ----------
    trajectory_path : str or pathlib.Path
        The campaign's trajectory set.
    profile_indices : numpy.ndarray
        Each case's profile (index into the set in file order), shape (n,).

    Returns
    -------
    pandas.DataFrame
        ``tilt_image<k>_rad`` (rad, angle of the body z axis from the vertical), ``angular_rate_image<k>_radps``
        (rad/s, magnitude) for every image k, and ``descent_rate_mps`` (m/s, altitude lost between the first
        and last image over their time difference), one row per case.
    """
    profiles = read_profiles(trajectory_path, image_count=None)
    per_profile: dict[int, dict[str, float]] = {}
    for index in np.unique(profile_indices):
        profile = profiles[int(index)]
        features: dict[str, float] = {}
        poses = [profile.pose(float(time_s)) for time_s in profile.image_times_s]
        for image, pose in enumerate(poses, start=1):
            body_z_world = quat_to_matrix(pose.attitude_quat)[:, 2]
            features[f"tilt_image{image}_rad"] = float(np.arccos(np.clip(abs(body_z_world[2]), 0.0, 1.0)))
            features[f"angular_rate_image{image}_radps"] = float(np.linalg.norm(pose.angular_rate_radps))
        span_s = float(profile.image_times_s[-1] - profile.image_times_s[0])
        drop_m = float(poses[0].position_m[2] - poses[-1].position_m[2])
        features["descent_rate_mps"] = drop_m / span_s if span_s > 0 else float("nan")
        per_profile[int(index)] = features
    return pd.DataFrame([per_profile[int(index)] for index in profile_indices])


def case_inputs(results: pd.DataFrame, trajectory_path: str | Path | None) -> pd.DataFrame:
    """One row per case (index ``case_id``): the recorded inputs, the sensor draws and, when the trajectory
    set is given, the trajectory columns (module docstring). Columns that do not vary are dropped (nothing
    to learn from them)."""
    per_case = results.drop_duplicates("case_id").sort_values("case_id").reset_index(drop=True)
    columns = [name for name in RECORDED_INPUTS if name in per_case]
    columns += sorted(name for name in per_case.columns if name.startswith("sensor_"))
    inputs = per_case[columns].copy()
    for name in ("heat_shield_in_view", "outside_terrain_fraction"):       # one value per image
        if name in inputs:
            per_image = np.stack([np.asarray(value, dtype=float) for value in inputs.pop(name)])
            for image in range(per_image.shape[1]):
                inputs[f"{name}_image{image + 1}"] = per_image[:, image]
    if "footprint_inside" in inputs:
        inputs["footprint_inside"] = inputs["footprint_inside"].astype(float)
    if trajectory_path is not None and "profile_index" in per_case:
        trajectory = trajectory_inputs(trajectory_path, per_case["profile_index"].to_numpy())
        inputs = pd.concat([inputs, trajectory], axis=1)
    inputs.index = pd.Index(per_case["case_id"].to_numpy(), name="case_id")
    varying = [name for name in inputs.columns if inputs[name].nunique(dropna=True) > 1]
    return inputs[varying]


def case_outputs(results: pd.DataFrame, estimator: str, false_valid_mps: float) -> pd.DataFrame:
    """One estimator's outputs per case (index ``case_id``): ``valid``, ``false_valid`` (0/1) and
    ``velocity_error_mps`` (NaN where the velocity is not valid)."""
    rows = results[results["estimator"] == estimator].sort_values("case_id")
    valid = (rows["valid"].fillna(False).astype(bool) & (rows["status"] == "ok")).to_numpy()
    error_mps = rows["velocity_error_mps"].to_numpy(dtype=float)
    return pd.DataFrame({"valid": valid.astype(float),
                         "false_valid": (valid & (error_mps > false_valid_mps)).astype(float),
                         "velocity_error_mps": np.where(valid, error_mps, np.nan)},
                        index=pd.Index(rows["case_id"].to_numpy(), name="case_id"))
