"""The attitude-knowledge floor: the closed form's geometry, and the reference estimator's error on real
simulated cases whose only large sensor error is a common attitude bias."""
from __future__ import annotations

import math

import numpy as np
import pytest

from campaign.case.compute import compute_case
from campaign.case.error_budget import attitude_floor_mps
from campaign.case.inputs import PlanRow, campaign_inputs
from campaign.configuration.campaign_file import load_campaign_config
from campaign.run.planning import plan_campaign
from service_campaigns import campaign_file


def test_floor_is_the_change_of_the_tilt_displacement_over_the_interval():
    # 540 m of descent in 7.5 s seen with a 1 deg tilt error: the ground point under the optical axis
    # moves by 2000 tan(1 deg) = 34.91 m at image 1 and 1460 tan(1 deg) = 25.49 m at image 3
    moved_m = 2000.0 * math.tan(math.radians(1.0)) - 1460.0 * math.tan(math.radians(1.0))
    assert attitude_floor_mps(math.radians(1.0), 0.0, 2000.0, 1460.0, 2.0, 9.5) == pytest.approx(moved_m / 7.5)
    # the tilt is the vector sum of the east and north parts; its sign and a descent order do not matter
    east, north = math.radians(0.6), math.radians(-0.8)
    assert attitude_floor_mps(east, north, 2000.0, 1460.0, 0.0, 7.5) == pytest.approx(moved_m / 7.5)
    assert attitude_floor_mps(0.0, 0.0, 2000.0, 1460.0, 0.0, 7.5) == 0.0
    with pytest.raises(ValueError):
        attitude_floor_mps(0.01, 0.0, 2000.0, 1460.0, 5.0, 5.0)


def test_estimator_error_follows_the_floor_when_the_attitude_bias_dominates(tmp_path):
    """Sensors exact but for a 3 deg sigma attitude bias common to the images (and the IMU bias the
    estimator solves for): each valid case's error is its floor within the matching's scatter."""
    sensors = ("[sensors]\nattitude_bias_sigma_deg = 3.0\nattitude_random_sigma_deg = 0.0\nalignment_sigma_deg = 0.0\n"
               "angular_rate_noise_sigma_dps = 0.0\nradar_altitude_sigma_percent = 0.0\n"
               "heat_shield_prediction_sigma_m = 0.0\n")
    config = load_campaign_config(campaign_file(tmp_path, cases={"gcp": 0, "gdcp": 5, "gkep": 0}, extra=sensors))
    _, plan = plan_campaign(config)
    resources = campaign_inputs(config)
    cases = [compute_case(resources, PlanRow.from_record(record)) for record in plan.to_dict("records")]
    valid = [(case.truth, estimate) for case in cases for estimate in case.estimates if estimate.valid]
    assert len(valid) >= 3, [estimate.reason for case in cases for estimate in case.estimates]
    floors = np.array([truth.attitude_floor_mps for truth, _ in valid])
    errors = np.array([estimate.velocity_error_mps for _, estimate in valid])
    assert floors.max() > 2.0                          # the bias dominates: floors of metres per second
    # within the scatter of matching and IMU-bias estimation (0.3-0.4 m/s rms on full campaigns)
    assert np.all(np.abs(errors - floors) <= 0.15 * floors + 0.7), np.c_[errors, floors]
    assert np.corrcoef(errors, floors)[0, 1] > 0.9


def test_report_lists_each_false_valid_case_beside_its_floor():
    import pandas as pd

    from campaign.report.markdown import _false_valid_section

    rows = pd.DataFrame({
        "case_id": [7, 8, 9], "class_name": ["gdcp"] * 3, "valid": [True, True, False],
        "velocity_error_mps": [6.24, 1.0, None], "velocity_uncertainty_mps": [2.02, 1.9, 0.0],
        "attitude_floor_mps": [5.41, 0.9, 0.2],
        "sensor_attitude_bias_east_rad": [math.radians(3.0), 0.0, 0.0],
        "sensor_attitude_bias_north_rad": [math.radians(4.0), 0.0, 0.0]})
    lines = _false_valid_section(rows, "##", 5.0)
    table = [line for line in lines if line.startswith("| 7 ")]
    assert table == ["| 7 | gdcp | 6.24 | 2.02 | 5.00 | 5.41 | 0.83 |"]          # 3-4-5 deg tilt
    assert not any(line.startswith(("| 8 ", "| 9 ")) for line in lines)
    assert _false_valid_section(rows.iloc[1:], "##", 5.0) == []
