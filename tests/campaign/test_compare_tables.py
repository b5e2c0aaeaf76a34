"""Estimators side by side: per estimator and class % valid, false-valid (valid, error > 5 m/s) and
error, counted by hand; stores without an estimator column read as the reference; the sweep
baseline check compares each estimator with its own baseline rows."""
from __future__ import annotations

from types import SimpleNamespace

import pandas as pd
import pytest

from campaign.configuration.sweep_file import Tolerances
from campaign.report.aggregate import format_number
from campaign.report.compare import (
    COMPARISON_NOTE,
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    failure_lines,
    format_comparison,
    with_estimator_column,
)
from campaign.run.sweep import compare_to_baseline

FRACTIONS = {"gcp": 0.6, "gdcp": 0.4}


def _rows(estimator, class_name, errors, invalid=0, failed=0):
    rows = [{"estimator": estimator, "class_name": class_name, "status": "ok", "valid": True,
             "velocity_error_mps": e} for e in errors]
    rows += [{"estimator": estimator, "class_name": class_name, "status": "ok", "valid": False,
              "velocity_error_mps": None}] * invalid
    rows += [{"estimator": estimator, "class_name": class_name, "status": "failed", "valid": False,
              "velocity_error_mps": None}] * failed
    return rows


@pytest.fixture
def results():
    return pd.DataFrame(_rows("dimes", "gcp", [1.0, 2.0, 6.0], invalid=1) + _rows("dimes", "gdcp", [1.0, 1.0])
                        + _rows("pc", "gcp", [9.0], invalid=2, failed=1) + _rows("pc", "gdcp", [2.0, 2.0]))


def test_comparison_counts_valid_false_valid_and_failed_per_estimator(results):
    table = comparison_table(results, FRACTIONS, "Site").set_index(["estimator", "class"])
    assert estimator_names(results) == ["dimes", "pc"]
    assert table.loc[("dimes", "gcp"), ["cases", "valid", "false_valid", "failed"]].tolist() == [4, 3, 1, 0]
    assert table.loc[("pc", "gcp"), ["cases", "valid", "false_valid", "failed"]].tolist() == [4, 1, 1, 1]
    assert table.loc[("pc", "gdcp"), "error_mean_3sigma_mps"] == pytest.approx(2.0)
    assert table.loc[("dimes", "Site"), "false_valid"] == 1 and table.loc[("pc", "Site"), "valid"] == 3
    assert table.loc[("dimes", "Site"), "weighted_pct_valid"] == pytest.approx(0.6 * 75.0 + 0.4 * 100.0)
    text = format_comparison(comparison_table(results, FRACTIONS, "Site"))
    lines = text.splitlines()
    assert "dimes false-valid" in lines[0] and "pc % valid" in lines[0]
    assert lines[1].split()[:4] == ["gcp", "75%", "1/3", lines[1].split()[3]] and "1/1" in lines[1]
    assert lines[-1].startswith("Site (weighted)")


def test_rows_without_estimator_column_are_the_reference(results):
    old = results[results["estimator"] == "dimes"].drop(columns="estimator")
    assert estimator_names(old) == ["dimes"]
    assert with_estimator_column(old)["estimator"].eq("dimes").all()


def test_baseline_regressions_are_per_estimator(results):
    spec = SimpleNamespace(points=[SimpleNamespace(point_id="p000", values={"sensors.x": 1.0})],
                           base=SimpleNamespace(site=SimpleNamespace(name="Site")))
    now = comparison_table(results, FRACTIONS, "Site").assign(point_id="p000")
    worse = results.copy()
    worse.loc[(worse["estimator"] == "pc") & (worse["class_name"] == "gdcp"), "valid"] = False   # pc loses gdcp
    before = comparison_table(results, FRACTIONS, "Site").assign(point_id="b000")
    after = comparison_table(worse, FRACTIONS, "Site").assign(point_id="p000")
    baseline = ({"points": [{"point_id": "b000", "values": {"sensors.x": 1.0}}]}, before)
    tolerances = Tolerances(pct_valid_drop_points=5.0, error_increase_mps=0.5)
    assert compare_to_baseline(spec, now, baseline, tolerances) == ([], 1)
    regressions, compared = compare_to_baseline(spec, after, baseline, tolerances)
    assert compared == 1 and regressions and all("estimator pc" in line for line in regressions)
    assert any("gdcp % valid 100.0 -> 0.0" in line for line in regressions)


def test_failed_rows_are_counted_per_estimator_and_left_out_of_pct_valid(results):
    failing = results.assign(case_id=range(len(results)), reason="ok", error="")
    failing.loc[failing["status"] == "failed", ["reason", "error"]] = ["estimator_failed", "field 'valid'\nmust be true"]
    counts = {count.name: count for count in estimator_counts(failing)}
    assert (counts["dimes"].valid, counts["dimes"].invalid, counts["dimes"].failed) == (5, 1, 0)
    assert (counts["pc"].valid, counts["pc"].invalid, counts["pc"].failed) == (3, 2, 1)
    assert counts_line(list(counts.values())) == ("estimator rows: dimes 5 valid, 1 invalid, 0 failed; "
                                                  "pc 3 valid, 2 invalid, 1 failed")
    assert failure_lines(list(counts.values())) == [
        "estimator pc: 1 of 6 rows failed; first: case 9 (estimator_failed): field 'valid' must be true"]
    table = comparison_table(results, FRACTIONS, "Site").set_index(["estimator", "class"])
    assert table.loc[("pc", "gcp"), "pct_valid"] == pytest.approx(100 * 1 / 3)    # valid / (cases - failed)
    assert "valid / (cases - failed)" in COMPARISON_NOTE


def test_numbers_of_any_size_stay_short_cells():
    assert format_number(1e30, "{:.2f}") == "1e+30" and format_number(float("inf"), "{:.2f}") == "inf"
    assert format_number(-1e30, "{:.0f}%") == "-1e+30%" and format_number(float("nan"), "{:.2f}") == "n/a"
    assert format_number(4.25, "{:.2f}") == "4.25"
