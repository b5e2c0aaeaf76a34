"""A wrong attitude or IMU prior makes every match fail, and the invalid reason says so.

The estimator searches for each template within the circle the priors allow: for a pair ``dt`` apart,
``max_velocity_bias_mps * dt`` (25 m/s) plus the attitude and altitude terms. An IMU velocity 40 m/s
off puts the ground ``40 dt`` metres from where it is looked for (about 150 m at dt = 3.8 s, against a
window of about 100 m); an image's attitude 5 deg off moves its ground by ``H tan 5 deg`` (150 m at
1725 m) against the 0.3 deg relative-attitude allowance. Both must answer ``no_match_within_prior``,
and the same descent with a 10 m/s IMU error (inside the prior) a valid velocity within 0.5 m/s.
"""
from __future__ import annotations

import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from dimes_velocity import REASONS, DimesEstimator, EstimatorConfig
from dimes_velocity.result import failed_pair_reason
from flight_interface.frames import quat_from_axis_angle, quat_multiply
from flight_interface.measurements import DescentMeasurements

VELOCITY = (12.0, -7.0, -72.0)


@pytest.fixture(scope="module")
def descent(mer_a):
    return constant_velocity_descent(mer_a, random_ground(np.random.default_rng(31)), np.random.default_rng(32),
                                     velocity_mps=VELOCITY)


def with_imu_error(truth: DescentMeasurements, east_mps: float) -> DescentMeasurements:
    images = tuple(type(m)(**{**m.__dict__, "imu_velocity_mps": m.imu_velocity_mps + np.array([east_mps, 0.0, 0.0])})
                   for m in truth.images)
    return DescentMeasurements(images, truth.sun_direction_world)


def with_attitude_error(truth: DescentMeasurements, image: int, degrees: float) -> DescentMeasurements:
    turn = quat_from_axis_angle([0.0, 1.0, 0.0], np.radians(degrees))
    images = list(truth.images)
    images[image] = type(images[image])(**{**images[image].__dict__,
                                           "attitude_quat": quat_multiply(turn, images[image].attitude_quat)})
    return DescentMeasurements(tuple(images), truth.sun_direction_world)


def test_a_prior_error_inside_the_search_is_absorbed(descent, mer_a):
    """A 10 m/s IMU error from an IMU whose error model allows it (5 m/s per axis; the default 2 m/s
    refuses it: test_implied_imu_bias.py)."""
    wide_imu = EstimatorConfig(imu_velocity_bias_sigma_mps=5.0)
    result = DimesEstimator(mer_a, wide_imu).estimate(descent.images, with_imu_error(descent.truth, 10.0))
    assert result.valid, result.reason
    assert np.hypot(result.velocity_east_mps - VELOCITY[0], result.velocity_north_mps - VELOCITY[1]) < 0.5
    assert result.imu_bias_east_mps == pytest.approx(10.0, abs=0.5)


@pytest.mark.parametrize("wrong", ["imu_40_mps", "attitude_image2_5_deg"])
def test_a_wrong_prior_is_named_as_the_reason(descent, mer_a, wrong):
    measurements = (with_imu_error(descent.truth, 40.0) if wrong == "imu_40_mps"
                    else with_attitude_error(descent.truth, 1, 5.0))
    result = DimesEstimator(mer_a).estimate(descent.images, measurements)
    assert not result.valid and result.reason == "no_match_within_prior" and result.reason in REASONS
    assert any(pair.reason == "no_match_within_prior" for pair in result.pairs)
    assert result.velocity_east_mps == pytest.approx(measurements.images[-1].imu_velocity_mps[0])  # IMU, uncorrected


def test_failed_pair_reason_counts_the_prior_failures_together():
    # 2 search_border + 2 outside_prior outnumber 3 ambiguous_match; ties go to the prior
    assert failed_pair_reason(["search_border", "outside_prior"] * 2 + ["ambiguous_match"] * 3) == "no_match_within_prior"
    assert failed_pair_reason(["search_border", "flat_peak"]) == "no_match_within_prior"
    assert failed_pair_reason(["search_border", "flat_peak", "flat_peak"]) == "flat_peak"
    assert failed_pair_reason(["ok", "flat_peak", "flat_peak", "search_border"], "too_few_features") == "too_few_features"
    assert failed_pair_reason(["ok", "search_border", "search_border", "flat_peak"], "too_few_features") \
        == "no_match_within_prior"
