"""dimes_velocity.features (template statistics, corner-like selection) and dimes_velocity.result (the
JSON form of an estimate), against values worked out by hand."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dimes_velocity.config import EstimatorConfig
from dimes_velocity.features import (
    FeatureSelector,
    interest_map,
    select_features,
    template_statistics,
    templates_statistics,
)
from dimes_velocity.result import REASONS, FeatureMetrics, PairResult, StageTimings, VelocityEstimate


def test_a_plane_has_contrast_but_no_detrended_contrast():
    half = 3
    rows, cols = np.mgrid[0:21, 0:21].astype(np.float64)
    plane = 100.0 + 2.0 * cols - 1.0 * rows
    mean, std, detrended = template_statistics(plane.astype(np.float32), 10, 10, half)
    assert mean == pytest.approx(100.0 + 20.0 - 10.0)
    # a 7x7 grid of 2 x - y: variance = (4 + 1) * var(-3..3) = 5 * 4
    assert std == pytest.approx(math.sqrt(20.0))
    assert detrended == pytest.approx(0.0, abs=1e-9)


def test_checkerboard_detrended_contrast_is_its_amplitude():
    image = np.where((np.add.outer(np.arange(15), np.arange(15)) % 2) == 0, 10.0, 30.0).astype(np.float32)
    mean, std, detrended = template_statistics(image, 7, 7, 2)     # 5x5: 13 of one value, 12 of the other
    assert mean == pytest.approx((13 * 10.0 + 12 * 30.0) / 25)
    assert std == pytest.approx(math.sqrt(13 * 12) / 25 * 20.0)
    assert detrended == pytest.approx(std, rel=1e-9)               # no plane in a checkerboard


def test_selector_prefers_corners_to_edges_and_keeps_its_spacing():
    config = EstimatorConfig()
    size = 160
    image = np.zeros((size, size), np.float32)
    image[40:120, 40:120] = 200.0                      # a bright square: 4 corners, 4 straight edges
    image += np.random.default_rng(0).normal(0.0, 0.5, image.shape).astype(np.float32)
    interest = interest_map(image, config)
    half = config.template_size_px // 2
    assert interest[40, 40] > 10 * interest[40, 80]    # corner >> middle of an edge
    candidates = np.zeros(image.shape, bool)
    candidates[half + 2:size - half - 2, half + 2:size - half - 2] = True
    selection = select_features(image, candidates, lambda column, row: 1.0, config)
    assert selection.offered >= 1 and selection.features
    first = selection.features[0]
    # the best template contains a corner of the square (within half a template of it on each axis)
    assert any(abs(first.column - c) <= half and abs(first.row - r) <= half for c in (40, 119) for r in (40, 119))
    for i, a in enumerate(selection.features):
        for b in selection.features[i + 1:]:
            assert math.hypot(a.column - b.column, a.row - b.row) >= config.min_feature_spacing_px
    empty = FeatureSelector(image, np.zeros(image.shape, bool), lambda column, row: 1.0, config)
    assert empty.offered == 0 and empty.next() is None


def test_estimate_to_dict_is_json_with_non_finite_numbers_as_zero():
    pair = PairResult(0, 1, True, "ok", 1.0, 2.0, 0.5, 1.0, 0.1, 20.0, 5, 4)
    feature = FeatureMetrics(pair=0, index=0, column_px=10, row_px=11, east_m=1.0, north_m=2.0, brightness_dn=50.0,
                             contrast_dn=5.0, contrast_to_noise=float("inf"), correlation=0.9, second_peak_ratio=0.5,
                             peak_curvature_per_px2=0.1, coarse_peak_curvature_per_px2=0.1, noise_decorrelation=0.01,
                             image_motion_px=3.0, displacement_east_m=1.0, displacement_north_m=2.0, status="ok",
                             used=True)
    estimate = VelocityEstimate(3.0, -4.0, True, "ok", 0.5, float("nan"), 0.0, 1.0, (pair,), (feature,),
                                StageTimings(1.0, 2.0, 3.0, 4.0, 5.0, 15.0))
    data = json.loads(json.dumps(estimate.to_dict(), allow_nan=False))
    assert data["imu_bias_east_mps"] == 0.0 and data["velocity_north_mps"] == -4.0
    assert data["features"][0]["contrast_to_noise"] == 0.0 and data["pairs"][0]["features_used"] == 4
    assert REASONS[0] == "ok" and len(set(REASONS)) == len(REASONS)


def test_template_contrast_gate_in_dn_refuses_the_blander_templates_only():
    """Left half: checkerboard of +-10 DN about 1000 (template standard deviation ~10 DN); right half: +-30 DN
    (~30 DN). A 20 DN gate keeps only right-half templates; the default (0, off) keeps both halves."""
    size = 128
    checker = np.where((np.add.outer(np.arange(size), np.arange(size)) % 2) == 0, 1.0, -1.0)
    image = (1000.0 + checker * np.where(np.arange(size)[None, :] < size // 2, 10.0, 30.0)).astype(np.float32)
    image += np.random.default_rng(1).normal(0.0, 0.5, image.shape).astype(np.float32)
    half = EstimatorConfig().template_size_px // 2
    candidates = np.zeros(image.shape, bool)
    candidates[half + 1:size - half - 1, half + 1:size - half - 1] = True
    candidates[:, size // 2 - half - 1:size // 2 + half + 1] = False      # no template straddles the two halves
    ungated = select_features(image, candidates, lambda column, row: 1.0, EstimatorConfig(feature_grid=4, features_per_pair=16))
    assert {f.column < size // 2 for f in ungated.features} == {True, False} and ungated.low_contrast == 0
    gated = select_features(image, candidates, lambda column, row: 1.0,
                            EstimatorConfig(feature_grid=4, features_per_pair=16, min_template_contrast_dn=20.0))
    assert gated.features and all(f.column > size // 2 and f.contrast_dn >= 20.0 for f in gated.features)
    assert gated.low_contrast >= 1 and all(f.contrast_dn == pytest.approx(30.0, rel=0.05) for f in gated.features)


def test_templates_statistics_are_the_one_template_values_bit_for_bit():
    """Measured together (the selector's batches), each template's statistics are exactly its own."""
    rng = np.random.default_rng(11)
    columns = np.arange(64.0)
    image = (400.0 + 3.0 * columns[None, :] - 2.0 * columns[:, None] + rng.normal(0.0, 25.0, (64, 64))).astype(np.float32)
    centres = [(int(c), int(r)) for c, r in rng.integers(7, 57, (9, 2))]
    assert templates_statistics(image, centres, 7) == [template_statistics(image, c, r, 7) for c, r in centres]
    assert templates_statistics(image, [], 7) == []
    for trial in range(60):              # sizes on both sides of numpy's 8- and 128-value summation blocks, scales
        half = int(rng.choice([1, 3, 5, 7, 9, 12]))
        scene = (rng.gamma(2.0, 50.0, (64, 64)) * rng.uniform(0.01, 100.0)).astype(np.float32 if trial % 2 else np.float64)
        centres = [(int(c), int(r)) for c, r in rng.integers(half, 64 - half, (int(rng.integers(1, 10)), 2))]
        assert templates_statistics(scene, centres, half) == [template_statistics(scene, c, r, half) for c, r in centres]
