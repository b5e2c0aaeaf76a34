"""Sweep heat maps: % valid and false-valid over a 2-D grid of points, a point at 0 % valid drawn as a
dark cell reading 0 %, a point without cases grey and "n/a", counted by hand on a synthetic sweep table."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from campaign.report.compare import comparison_table
from campaign.report.sweep_plots import grid_pairs, heat_cell, write_heat_maps

FRACTIONS = {"gcp": 0.6, "gdcp": 0.4}


def _spec(dust, rate):
    points = [SimpleNamespace(point_id=f"p{i:03d}", values={"dust": d, "rate": r, "held": 1})
              for i, (d, r) in enumerate((d, r) for r in rate for d in dust)]
    classes = [SimpleNamespace(name=name, ellipse_fraction=f) for name, f in FRACTIONS.items()]
    base = SimpleNamespace(site=SimpleNamespace(name="Site", classes=classes), cases_per_class={"gcp": 2, "gdcp": 2})
    return SimpleNamespace(mode="grid", axes={"dust": dust, "rate": rate, "held": [1]}, axis_names=["dust", "rate", "held"],
                           points=points, base=base)


def _rows(valid_gcp, valid_gdcp, false_valid_gcp=0):
    rows = []
    for name, valid in (("gcp", valid_gcp), ("gdcp", valid_gdcp)):
        for k in range(2):
            ok = k < valid
            error = 9.0 if ok and name == "gcp" and k < false_valid_gcp else 1.0
            rows.append({"estimator": "dimes", "class_name": name, "status": "ok", "valid": ok,
                         "velocity_error_mps": error if ok else None})
    return pd.DataFrame(rows)


def test_heat_map_cells_and_the_zero_percent_point(tmp_path):
    spec = _spec([0.1, 0.5], [1, 2, 3])
    frames = []
    per_point = {"p000": _rows(2, 2), "p001": _rows(0, 0), "p002": _rows(2, 1, false_valid_gcp=1),
                 "p003": _rows(1, 2), "p004": _rows(2, 0)}                 # p005: no cases at all
    for point in spec.points:
        results = per_point.get(point.point_id, pd.DataFrame(columns=["estimator", "class_name", "status", "valid",
                                                                       "velocity_error_mps"]))
        table = comparison_table(results, FRACTIONS, "Site", estimators=["dimes"]).assign(point_id=point.point_id)
        frames.append(table)
    table = pd.concat(frames, ignore_index=True)
    assert grid_pairs(spec) == [("dust", "rate")]                               # "held" has one value
    pct, false_pct, pct_text, false_text = heat_cell(table, "p001", "Site", True, "dimes")
    assert pct == 0.0 and pct_text == "0%"                                       # 0 % valid is a value, not n/a
    assert heat_cell(table, "p001", "gcp", False, "dimes")[2] == "0%\n0/2"
    pct, false_pct, _, false_text = heat_cell(table, "p002", "Site", True, "dimes")
    assert pct == pytest.approx(0.6 * 100 + 0.4 * 50) and false_text == "1/3" and false_pct == pytest.approx(100 / 3)
    assert heat_cell(table, "p005", "gcp", False, "dimes")[2] == "n/a"
    assert heat_cell(table, None, "gcp", False, "dimes")[2] == "n/a"
    paths = write_heat_maps(spec, table, tmp_path)
    assert [path.name for path in paths] == ["heatmap-dimes-dust-x-rate.png"]
    with Image.open(paths[0]) as image:
        assert image.size == (round(3.6 * 3 * 80), round(6.4 * 80))
        pixels = np.asarray(image.convert("RGB")).astype(int)
    dark = np.abs(pixels - np.array([68, 1, 84])).sum(axis=-1) < 30           # viridis at 0 %
    grey = np.abs(pixels - np.array([191, 191, 191])).sum(axis=-1) < 6        # no value
    assert dark.sum() > 500 and grey.sum() > 500
