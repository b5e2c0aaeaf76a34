"""Estimators side by side: per estimator and class % valid, false-valid (valid, error > 5 m/s) and
error, counted by hand; stores without an estimator column read as the reference; four estimators side
by side within 120 columns. (The sweep's baseline gate is tested in test_baseline_gate.py.)"""
from __future__ import annotations

import pandas as pd
import pytest

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
    assert lines[0].split()[0] == "dimes" and " pc " in lines[0] and lines[1].split().count("false-valid") == 2
    # dimes gcp: 3 valid of 4 ran, 1 of the 3 valid false-valid; pc gcp: 1 of 3 ran (1 failed), 1 of 1 false-valid
    assert lines[2].split()[:4] == ["gcp", "75.0%", "(3/4)", "1/3"] and "33.3% (1/3)" in lines[2] and "1/1" in lines[2]
    assert lines[-1].startswith("Site (weighted)")
    assert f"{0.6 * 75.0 + 0.4 * 100.0:.1f}%" in lines[-1]


def test_rows_without_estimator_column_are_the_reference(results):
    old = results[results["estimator"] == "dimes"].drop(columns="estimator")
    assert estimator_names(old) == ["dimes"]
    assert with_estimator_column(old)["estimator"].eq("dimes").all()


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


def _four_estimators(names):
    rows = []
    for name in names:        # Gusev-sized counts: the widest cells a real table prints
        rows += _rows(name, "gcp", [1.0, 2.0, 6.0] * 62, invalid=1) + _rows(name, "gdcp", [1.0, 1e30], failed=1)
        rows += _rows(name, "gkep", [], invalid=1)
    return comparison_table(pd.DataFrame(rows), {"gcp": 0.59, "gdcp": 0.41, "gkep": 0.0}, "Meridiani")


@pytest.mark.parametrize("names", [["dimes", "phase_correlation", "imu_only", "pc2"],
                                   ["dimes", "an_estimator_with_a_very_long_name_indeed_and_then_some_more_of_it",
                                    "b", "c"]])
def test_four_estimators_side_by_side_fit_120_columns(names):
    table = _four_estimators(names)
    text = format_comparison(table)
    assert max(len(line) for line in text.splitlines()) <= 120, text
    assert max(len(line) for line in COMPARISON_NOTE.splitlines()) <= 120
    for name in names:        # every estimator is named, in a group line or a block title
        assert name in text
    # every estimator's gcp % valid (186 of 187 ran) and site row appear: 4 groups of cells
    assert text.count("99.5% (186/187)") == 4 and text.count("62/186") == 4
    blocks = max(1, text.count("(block "))            # the site's weighted row closes every block
    assert sum(line.startswith("Meridiani (weighted)") for line in text.splitlines()) == blocks
    blocks = [block for block in format_comparison(table, markdown=True).split("\n\n") if block.startswith("|")]
    assert sum(block.count(" % valid |") for block in blocks) == 4
