"""An answer implies an IMU velocity bias, ``v_IMU - v``; one the IMU's error model does not allow at the
stated confidence is invalid, ``imu_bias_implausible`` (issue 31: a shadow drifting with the wind over
bland ground, tracked as ground, gave valid answers off by the wind)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from dimes_velocity import REASONS, DimesEstimator, EstimatorConfig
from dimes_velocity.solution import implied_bias_limit_mps

VELOCITY = (12.0, -7.0, -72.0)


@pytest.fixture(scope="module")
def descent(mer_a):
    return constant_velocity_descent(mer_a, random_ground(np.random.default_rng(51)), np.random.default_rng(52),
                                     velocity_mps=VELOCITY)


def with_imu_bias(truth, bias_mps):
    step = np.array([bias_mps[0], bias_mps[1], 0.0])
    return dataclasses.replace(truth, images=tuple(dataclasses.replace(m, imu_velocity_mps=m.imu_velocity_mps + step)
                                                   for m in truth.images))


def test_limit_closed_form():
    """sqrt(-2 ln 0.001) = 3.717; per-axis sigma sqrt(2^2 + 2^2 / 2) = sqrt(6)."""
    assert implied_bias_limit_mps(0.0, 2.0, 0.999) == pytest.approx(np.sqrt(2 * np.log(1000.0)) * 2.0, rel=1e-12)
    assert implied_bias_limit_mps(2.0, 2.0, 0.999) == pytest.approx(3.7169 * np.sqrt(6.0), rel=1e-4)
    assert implied_bias_limit_mps(2.0, 2.0, 1.0) == np.inf


@pytest.mark.parametrize("confidence", [0.9, 0.99, 0.999])
def test_a_right_answer_exceeds_the_limit_as_often_as_the_confidence_says(confidence):
    """Sampled independently: IMU bias normal 2 m/s per axis, answer error of RMS magnitude 1.5 m/s."""
    rng = np.random.default_rng(3)
    draws = 2_000_000
    implied = 2.0 * rng.standard_normal((draws, 2)) - (1.5 / np.sqrt(2.0)) * rng.standard_normal((draws, 2))
    outside = float(np.mean(np.hypot(implied[:, 0], implied[:, 1]) > implied_bias_limit_mps(1.5, 2.0, confidence)))
    expected = 1.0 - confidence
    assert outside == pytest.approx(expected, abs=4 * np.sqrt(expected * confidence / draws))


def test_a_3_sigma_imu_bias_is_answered(mer_a, descent):
    """6, -3 m/s (|b| = 6.7 m/s, 3 sigma on east of the default 2 m/s per axis): inside 3.72 x 2.x m/s."""
    result = DimesEstimator(mer_a).estimate(descent.images, with_imu_bias(descent.truth, (6.0, -3.0)))
    assert result.valid, result.reason
    assert np.hypot(result.imu_bias_east_mps - 6.0, result.imu_bias_north_mps + 3.0) < 0.5


@pytest.mark.parametrize("bias", [(12.0, 0.0), (-8.0, 9.0), (0.0, -20.0)])
def test_an_answer_implying_a_bias_the_imu_cannot_have_is_invalid(mer_a, descent, bias):
    """12-20 m/s is 6-10 sigma of a 2 m/s IMU: the match is right, but an answer that needs such a bias
    (or a shadow moving with the wind) is not trusted. With the check off the same images are valid."""
    measurements = with_imu_bias(descent.truth, bias)
    refused = DimesEstimator(mer_a).estimate(descent.images, measurements)
    assert not refused.valid and refused.reason == "imu_bias_implausible" and refused.reason in REASONS
    assert refused.velocity_uncertainty_mps == 0.0
    unchecked = DimesEstimator(mer_a, EstimatorConfig(implied_bias_confidence=1.0)).estimate(descent.images, measurements)
    assert unchecked.valid, unchecked.reason
    assert np.hypot(unchecked.imu_bias_east_mps - bias[0], unchecked.imu_bias_north_mps - bias[1]) < 0.5
    limit = implied_bias_limit_mps(unchecked.velocity_uncertainty_mps, 2.0, 0.999)
    assert limit < np.hypot(*bias)
