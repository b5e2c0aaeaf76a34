"""The paper's table arithmetic, checked against Table 1 of the paper."""
import math

import numpy as np
import pandas as pd
import pytest

from campaign.aggregate import format_table, mean_plus_3_sigma, site_table


def _rows(class_name, valid_errors, invalid=0, failed=0):
    rows = [{"class_name": class_name, "status": "ok", "valid": True, "velocity_error_mps": e} for e in valid_errors]
    rows += [{"class_name": class_name, "status": "ok", "valid": False, "velocity_error_mps": None}] * invalid
    rows += [{"class_name": class_name, "status": "failed", "valid": False, "velocity_error_mps": None}] * failed
    return rows


def test_mean_plus_three_sigma_closed_form():
    errors = np.array([1.0, 2.0, 3.0, 4.0])
    assert mean_plus_3_sigma(errors) == pytest.approx(2.5 + 3 * math.sqrt(5.0 / 3.0))
    assert math.isnan(mean_plus_3_sigma(np.array([])))


def test_weighting_reproduces_paper_table_1_arithmetic():
    # classes whose mean+3sigma is exactly the paper's value: constant errors
    results = pd.DataFrame(_rows("gcp", [3.90] * 182, invalid=4) + _rows("gdcp", [3.48] * 112)
                           + _rows("gkep", [3.29] * 77, failed=1))
    table = site_table(results, {"gcp": 0.59, "gdcp": 0.41, "gkep": 0.0}, "Gusev")
    by_class = table.set_index("class")
    assert by_class.loc["gcp", "pct_valid"] == pytest.approx(100 * 182 / 186)
    assert by_class.loc["gcp", "weighted_error_mps"] == pytest.approx(2.301)
    assert by_class.loc["gdcp", "weighted_error_mps"] == pytest.approx(1.4268)
    assert by_class.loc["gkep", "failed"] == 1 and by_class.loc["gkep", "valid"] == 77
    site = by_class.loc["Gusev"]
    assert site["cases"] == 376 and site["valid"] == 371
    assert site["weighted_error_mps"] == pytest.approx(3.73, abs=0.005)
    assert round(site["weighted_pct_valid"]) == 99
    text = format_table(table)
    assert "Gusev" in text and "3.73" in text
    assert format_table(table, markdown=True).startswith("| Class")


def test_class_without_valid_cases_makes_weighted_error_unknown():
    results = pd.DataFrame(_rows("a", [1.0, 2.0]) + _rows("b", [], invalid=3))
    table = site_table(results, {"a": 0.5, "b": 0.5}, "site").set_index("class")
    assert table.loc["b", "pct_valid"] == 0.0
    assert math.isnan(table.loc["site", "weighted_error_mps"])
