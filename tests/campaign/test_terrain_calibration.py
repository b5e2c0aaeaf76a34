"""The synthetic appearance classes against real MOC NA ground of their kind (issue 15).

CI has no real data: the class test uses the ranges recorded in campaign/realism/terrain_reference.py (with
their source); when ../shared/realdata is present a second test re-measures those ranges."""
from __future__ import annotations

from pathlib import Path

import pytest

from campaign.realism import terrain_reference as ref
from campaign.realism.terrain_stats import descent_sampling, nadir_photometric_ratio, terrain_statistics

REPO = Path(__file__).resolve().parents[2]
REALDATA = REPO.parent / "shared" / "realdata"


@pytest.fixture(scope="module")
def mer_sampling(mer_a):
    return descent_sampling(mer_a, 1.478)


@pytest.fixture(scope="module")
def class_statistics(site_strips, mer_sampling):
    return {name: terrain_statistics(t.reflectance_if, t.metres_per_pixel, mer_sampling)
            for name, (_, _, t) in site_strips.items()}


@pytest.mark.slow
def test_every_class_falls_inside_the_real_range_of_its_kind(class_statistics):
    assert set(class_statistics) == set(ref.KIND_OF_CLASS)
    for name, stats in class_statistics.items():
        kind = ref.RECORDED_RANGES[ref.KIND_OF_CLASS[name]]
        low, high = kind["contrast"]
        for value in (stats.contrast_1km, stats.contrast_2km):
            assert low <= value <= high, f"{name}: contrast {value:.3f} outside real {ref.KIND_OF_CLASS[name]} {low}-{high}"
        low, high = kind["crater_density_per_km2"]
        assert low <= stats.crater_density_per_km2 <= high, f"{name}: {stats.crater_density_per_km2:.1f} dark features/km2"
        low, high = ref.RECORDED_PSD_SLOPE_RANGE
        assert low <= stats.psd_slope <= high, f"{name}: PSD slope {stats.psd_slope:.2f}"
        assert stats.untrackable_2km < 0.05, name


@pytest.mark.skipif(not REALDATA.is_dir(), reason=f"real Mars data folder {REALDATA} is absent: recorded ranges not re-measured")
def test_recorded_ranges_are_what_the_real_images_measure(mer_sampling):
    measured = ref.measure_reference_ranges(mer_sampling, REALDATA)
    assert set(measured) == set(ref.RECORDED_RANGES)
    for kind, entry in measured.items():
        for key, (low, high) in entry.items():
            rec_low, rec_high = ref.RECORDED_RANGES[kind][key]
            tolerance = 0.0011 if key == "contrast" else 1.01
            assert rec_low <= low <= rec_low + tolerance and rec_high - tolerance <= high <= rec_high, (kind, key, low, high)
    low, high = ref.measure_psd_slope_range(REALDATA)
    assert ref.RECORDED_PSD_SLOPE_RANGE[0] <= low <= ref.RECORDED_PSD_SLOPE_RANGE[0] + 0.011
    assert ref.RECORDED_PSD_SLOPE_RANGE[1] - 0.011 <= high <= ref.RECORDED_PSD_SLOPE_RANGE[1]


def test_photometric_ratio_of_a_nadir_view_is_one_at_the_same_geometry():
    # same sun and a nadir orbital view: the descent view sees the orbital I/F unchanged
    import math

    assert nadir_photometric_ratio(math.radians(60.0), math.radians(30.0), 0.0, math.radians(30.0)) == pytest.approx(1.0)
    assert nadir_photometric_ratio(math.radians(70.0), math.radians(45.0), 0.0, math.radians(45.0)) > 1.0
