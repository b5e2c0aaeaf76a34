"""sitedata.terrain.synthetic_classes: the six class presets keep the paper's (and the cited literature's)
ordering and pass their own range checks; a nonsense value is refused naming the preset and field."""
from __future__ import annotations

import dataclasses

import pytest

from sitedata.terrain.synthetic_classes import CLASS_PRESETS, ClassTerrainParams

CLASSES = ("gcp", "gdcp", "gkep", "hbsp", "hdcp", "heb")


def test_presets_are_the_six_classes_and_their_rough_moc_variants_and_valid():
    assert set(CLASS_PRESETS) == {*CLASSES, *(f"{name}_rough_moc" for name in CLASSES)}
    for name, params in CLASS_PRESETS.items():
        assert params.name == name
        params.validate()
    # a default class is its rough-MOC-ground variant with a contrast scale below 1 and nothing else changed
    for name in CLASSES:
        rough, default = CLASS_PRESETS[f"{name}_rough_moc"], CLASS_PRESETS[name]
        assert rough.contrast_scale == 1.0 and 0.0 < default.contrast_scale < 1.0
        assert dataclasses.replace(default, name=rough.name, contrast_scale=1.0) == rough


def test_presets_follow_the_described_physics():
    p = {name: CLASS_PRESETS[name] for name in CLASSES}
    # Meridiani hematite plains are darker and smoother than the Gusev plains
    assert max(p[c].normal_albedo_mean for c in ("hbsp", "hdcp", "heb")) < min(
        p[c].normal_albedo_mean for c in ("gcp", "gdcp", "gkep"))
    assert p["hbsp"].rms_slope_deg < min(p[c].rms_slope_deg for c in ("gcp", "gdcp", "gkep"))
    # "dark" cratered plains are darker than their bright neighbours
    assert p["gdcp"].normal_albedo_mean < p["gcp"].normal_albedo_mean
    assert p["hdcp"].normal_albedo_mean < p["hbsp"].normal_albedo_mean
    # only gdcp has dust devil tracks, only gkep knobs, only heb a large ejecta crater
    assert [c for c in p if p[c].track_length_per_km2 > 0] == ["gdcp"]
    assert [c for c in p if p[c].knob_density_per_km2 > 0] == ["gkep"]
    assert [c for c in p if p[c].ejecta_crater_diameter_m > 0] == ["heb"]
    # MOC observation geometry of the selected images: incidence < 60 deg, emission < 30 deg
    assert all(params.moc_incidence_deg < 60 and params.moc_emission_deg < 30 for params in p.values())


def test_area_and_refusal():
    params = ClassTerrainParams(name="x", rows=1000, cols=500, metres_per_pixel=2.0)
    assert params.area_km2 == pytest.approx(2.0 * 1.0)          # 2 km x 1 km
    with pytest.raises(ValueError, match=r"preset 'gcp': hurst_exponent = 1\.0 is out of range; allowed: 0 < H < 1"):
        dataclasses.replace(CLASS_PRESETS["gcp"], hurst_exponent=1.0).validate()
