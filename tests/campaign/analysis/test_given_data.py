"""The given-data PAWN estimator against closed forms and against SALib's own implementation."""
from __future__ import annotations

import numpy as np
import pytest

from campaign.analysis.given_data import (
    analyse_input,
    continuous_null,
    holm_noise,
    pawn_index,
    slice_count,
    slice_labels,
)


def test_step_output_has_the_closed_form_index():
    """Y = 1[X1 > 1/2], X1 ~ U(0, 1): every one of 10 equal-count slices lies on one side of 1/2 (up to the
    sample's median), where P(Y=1 | slice) is 0 or 1 against P(Y=1) = 1/2: T = 1/2. X2 is independent: T ~ 0."""
    rng = np.random.default_rng(1)
    inputs = rng.uniform(0, 1, (20_000, 2))
    outputs = (inputs[:, 0] > 0.5).astype(float)
    assert pawn_index(inputs[:, 0], outputs, 10) == pytest.approx(0.5, abs=0.01)
    assert pawn_index(inputs[:, 1], outputs, 10) < 0.02


def test_identity_output_has_the_closed_form_index():
    """Y = X ~ U(0, 1) and slice k = [k/S, (k+1)/S): KS(slice, all) = max(k/S, 1 - (k+1)/S); the mean over
    S = 10 slices is 0.7."""
    rng = np.random.default_rng(2)
    values = rng.uniform(0, 1, 20_000)
    expected = np.mean([max(k / 10, 1 - (k + 1) / 10) for k in range(10)])
    assert expected == pytest.approx(0.7)
    assert pawn_index(values, values, 10) == pytest.approx(expected, abs=0.005)


def test_matches_salib_pawn_mean():
    """For equal-count slices the index is SALib's ``pawn.analyze`` "mean" (an independent implementation
    with scipy's KS statistic); they may differ only by SALib leaving the largest input value out."""
    from SALib.analyze import pawn

    rng = np.random.default_rng(3)
    inputs = rng.uniform(-np.pi, np.pi, (3000, 3))
    outputs = np.sin(inputs[:, 0]) + 7 * np.sin(inputs[:, 1]) ** 2 + 0.1 * inputs[:, 2] ** 4 * np.sin(inputs[:, 0])
    problem = {"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-np.pi, np.pi]] * 3}
    reference = pawn.analyze(problem, inputs, outputs, S=10, seed=1)["mean"]
    ours = [pawn_index(inputs[:, column], outputs, 10) for column in range(3)]
    np.testing.assert_allclose(ours, reference, atol=2e-3)


def test_categorical_input_conditions_on_each_value():
    """A class with P(valid) 0.2 at 1/4 of the cases and 1.0 elsewhere: P = 0.8; T = 1/4 |0.2 - 0.8| +
    3/4 |1.0 - 0.8| = 0.3 (Borgonovo's delta of a binary output)."""
    classes = np.array(["bland"] * 250 + ["plains"] * 750)
    valid = np.concatenate([np.r_[np.ones(50), np.zeros(200)], np.ones(750)])
    assert pawn_index(classes, valid) == pytest.approx(0.3)


def test_noise_input_is_marked_and_driver_is_not():
    rng = np.random.default_rng(4)
    inputs = rng.normal(size=(400, 6))
    outputs = 2.0 * inputs[:, 0] + rng.normal(size=400)
    null = continuous_null(outputs, rng, 1000)
    estimates = [analyse_input(inputs[:, column], outputs, rng, resamples=100, permutations=1000, null=null)
                 for column in range(6)]
    noise = holm_noise(np.array([estimate.p_value for estimate in estimates]))
    assert not noise[0] and noise[1:].all()
    driver = estimates[0]
    assert driver.low <= driver.index <= driver.high
    # a noise input's bias-corrected interval still covers its own index
    assert all(estimate.low <= estimate.index + 1e-9 and estimate.index <= estimate.high + 1e-9
               for estimate in estimates[1:])


def test_holm_step_down():
    """Holm at 0.05 over 4 p-values: 0.001 <= 0.0125 rejected, 0.01 <= 0.0167 rejected, 0.03 > 0.025 stops."""
    assert holm_noise(np.array([0.03, 0.001, 0.5, 0.01])).tolist() == [True, False, True, False]


def test_slices():
    assert slice_count(38) == 2 and slice_count(376) == 10 and slice_count(100) == 4
    labels = slice_labels(np.array([5.0, 1.0, 3.0, 2.0, 4.0, 0.0]), 3, False)
    assert labels.tolist() == [2, 0, 1, 1, 2, 0]
