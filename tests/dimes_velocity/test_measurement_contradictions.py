"""Contradictory measurements are an input error, never a valid answer (issue 20): IMU positions
describing 24 m/s of horizontal motion with IMU velocities of 0 used to give `valid` at 0.4 m/s,
23.5 m/s from the truth (the bias taken from one field, the answer from the other). Now the
estimator raises MeasurementError and `python -m dimes_velocity` exits 2 with one line naming both
fields; a consistent record with a realistic IMU bias and drift is still answered."""
from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from dimes_velocity import DimesEstimator, MeasurementError
from dimes_velocity.__main__ import main
from file_formats.measurements_json import measurements_to_dict

VELOCITY = (24.0, 0.0, -72.0)           # true: 24 m/s east
BIAS = np.array([6.0, -3.0, 0.0])       # a 3-sigma IMU velocity bias of the campaign's 2 m/s


@pytest.fixture(scope="module")
def descent(mer_a):
    return constant_velocity_descent(mer_a, random_ground(np.random.default_rng(31)), np.random.default_rng(32),
                                     velocity_mps=VELOCITY)


def with_imu(descent, velocities, positions):
    images = tuple(dataclasses.replace(m, imu_velocity_mps=np.asarray(v, dtype=float), imu_position_m=np.asarray(p, dtype=float))
                   for m, v, p in zip(descent.truth.images, velocities, positions))
    return dataclasses.replace(descent.truth, images=images)


def contradiction(descent):
    """Positions: the true ones (24 m/s east, 275 m of height per 3.82 s); velocities: 0 horizontally."""
    return with_imu(descent, [(0.0, 0.0, -72.0)] * 3, descent.positions_m)


def test_times_are_the_closed_form_ones(descent):
    """Images at 2000, 1725, 1450 m falling at 72 m/s: 275 / 72 = 3.819 s apart."""
    assert [m.time_s for m in descent.truth.images] == pytest.approx([0.0, 275 / 72, 550 / 72])


def test_the_estimator_refuses_positions_for_24_mps_with_velocities_of_0(mer_a, descent):
    with pytest.raises(MeasurementError, match=r"imu_position_m and imu_velocity_mps disagree.*24 m/s.*allowed 5 m/s"):
        DimesEstimator(mer_a).estimate(descent.images, contradiction(descent))


def test_a_consistent_record_with_realistic_imu_drift_is_answered(mer_a, descent):
    """IMU velocity = truth + a 6, -3 m/s bias + a 0.05 m/s/sqrt(s) random walk; positions integrated from
    it (trapezoid) plus 0.3 m of integration noise: disagreement ~0.1 m/s, well inside 5 m/s."""
    times = np.array([m.time_s for m in descent.truth.images])
    walk = np.cumsum(0.05 * np.sqrt(np.diff(times, prepend=0.0))[:, None] * np.random.default_rng(5).standard_normal((3, 3)), axis=0)
    velocities = np.asarray(VELOCITY) + BIAS + walk
    steps = 0.5 * (velocities[1:] + velocities[:-1]) * np.diff(times)[:, None]
    positions = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)]) + np.array([100.0, -50.0, 2000.0])
    positions += 0.3 * np.random.default_rng(6).standard_normal((3, 3))
    result = DimesEstimator(mer_a).estimate(descent.images, with_imu(descent, velocities, positions))
    assert result.valid, result.reason
    assert np.hypot(result.velocity_east_mps - VELOCITY[0], result.velocity_north_mps - VELOCITY[1]) < 1.0


def test_the_cli_exits_2_with_one_line_naming_both_fields(mer_a_path, descent, tmp_path, capsys):
    paths = [tmp_path / f"image_{k}.png" for k in (1, 2, 3)]
    for path, image in zip(paths, descent.images):
        cv2.imwrite(str(path), image)
    measurements = tmp_path / "measurements.json"
    measurements.write_text(json.dumps(measurements_to_dict(contradiction(descent))))
    code = main([str(p) for p in (*paths, measurements)] + ["--camera", str(mer_a_path)])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert str(measurements) in lines[0] and "imu_position_m and imu_velocity_mps disagree" in lines[0]
