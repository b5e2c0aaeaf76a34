"""The paper's table arithmetic, checked against Table 1 of the paper."""
import math

import numpy as np
import pandas as pd
import pytest

from campaign.report.aggregate import format_table, mean_plus_3_sigma, site_table


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


def test_false_valid_and_worst_valid_error_per_class_and_site():
    results = pd.DataFrame(_rows("a", [1.0, 4.9, 5.0, 5.1, 7.5], invalid=2) + _rows("b", [0.5, 2.0], failed=1)
                           + _rows("c", [], invalid=3))
    table = site_table(results, {"a": 0.5, "b": 0.5, "c": 0.0}, "site", false_valid_mps=5.0).set_index("class")
    assert table.loc["a", "false_valid"] == 2 and table.loc["a", "worst_valid_error_mps"] == 7.5   # 5.1 and 7.5
    assert table.loc["b", "false_valid"] == 0 and table.loc["b", "worst_valid_error_mps"] == 2.0
    assert table.loc["c", "false_valid"] == 0 and math.isnan(table.loc["c", "worst_valid_error_mps"])
    assert table.loc["site", "false_valid"] == 2 and table.loc["site", "worst_valid_error_mps"] == 7.5
    strict = site_table(results, {"a": 0.5, "b": 0.5, "c": 0.0}, "site", false_valid_mps=1.5)
    assert strict.set_index("class").loc["site", "false_valid"] == 5          # 4.9, 5.0, 5.1, 7.5 and 2.0
    assert "False-valid (>1.5 m/s)" in format_table(strict) and "7.50" in format_table(strict, markdown=True)


def test_flight_metrics_table_summarises_templates_per_class():
    from campaign.realism.flight_metrics import metrics_table

    rows = []
    for k in range(10):                      # brightness 1000..1009, contrast 10..19, one failed match per case
        rows.append({"class_name": "a", "status": "ok", "feature_brightness": [1000.0 + k],
                     "feature_contrast": [10.0 + k], "feature_correlation": [0.9, 0.1],
                     "feature_status": ["ok", "ambiguous_match"]})
    text = metrics_table(pd.DataFrame(rows), ["a"])
    line = next(row for row in text.splitlines() if row.startswith("| a "))
    assert "| 10 |" in line and "1004 [1001-1008]" in line and "14.5 [10.9-18.1]" in line
    assert "0.900 [0.900-0.900]" in line                      # the failed match's 0.1 is not a correlation
    # per-template ratio (10 + k) / (1000 + k): median of 14/1004 and 15/1005, percentiles interpolated
    assert "| 1.44 [1.09-1.80] |" in line
    assert ("| MER-A flight (paper) | 3 | 4710, 3898, 4693 | 47.5, 41.7, 55.6 | 1.01, 1.07, 1.18 | 0.88, 0.91, 1.00 |"
            in text)


def _site_row_cells(text: str, site: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith(site)][0].split()


def test_class_rows_show_their_own_pct_valid_and_the_site_row_the_weighted_one():
    # gcp 3/3 valid (100 %), gdcp 1 of 2 ran valid (50 %, one failed), gkep outside the ellipse, 0/2 valid
    results = pd.DataFrame(_rows("gcp", [1.0, 2.0, 3.0]) + _rows("gdcp", [6.0], invalid=1, failed=1)
                           + _rows("gkep", [], invalid=2))
    fractions = {"gcp": 0.59, "gdcp": 0.41, "gkep": 0.0}
    table = site_table(results, fractions, "Gusev")
    text = format_table(table)
    lines = {line.split()[0]: line for line in text.splitlines()[1:]}
    cells = lines["gcp"].split()         # class cases valid failed %valid (v/ran) false-valid error worst %ellipse
    assert cells[4:6] == ["100.0%", "(3/3)"] and cells.count("59%") == 1 and cells[-1] == "59%"   # 59 %: ellipse only
    assert "50.0% (1/2)" in lines["gdcp"] and "0.0% (0/2)" in lines["gkep"]
    # site: sum(weight * pct) / sum(weight) over classes inside the ellipse = (0.59*100 + 0.41*50) / 1.0
    expected = (0.59 * 100.0 + 0.41 * 50.0) / (0.59 + 0.41)
    assert table.iloc[-1]["weighted_pct_valid"] == pytest.approx(expected)
    assert f"{expected:.1f}% weighted" in lines["Gusev"]
    # false-valid next to every % valid, over the valid cases: gdcp's 6 m/s valid case is false-valid
    assert _site_row_cells(text, "gdcp")[6] == "1/1" and _site_row_cells(text, "Gusev")[6] == "1/4"
    # error: mean + 3 sample sigma of gcp's [1, 2, 3] = 2 + 3 * 1 = 5.00; site weighted (0.59*5 + 0.41*6)
    assert "5.00" in lines["gcp"] and f"{0.59 * 5.0 + 0.41 * 6.0:.2f} weighted" in lines["Gusev"]


def test_weighted_site_row_divides_by_the_sum_of_the_weights():
    # fractions not summing to 1 (2 and 1): (2 * 100 + 1 * 0) / 3
    results = pd.DataFrame(_rows("a", [1.0]) + _rows("b", [], invalid=1))
    table = site_table(results, {"a": 2.0, "b": 1.0}, "site")
    assert table.iloc[-1]["weighted_pct_valid"] == pytest.approx(200.0 / 3.0)


def test_table_footer_states_the_sigma_convention_and_denominators():
    from campaign.report.aggregate import TABLE_NOTE

    note = " ".join(TABLE_NOTE.split())
    assert "sample standard deviation (ddof=1" in note and "population" in note
    assert "mean + 3 sigma of the horizontal velocity error over the valid cases" in note
    assert "% valid = valid / (cases - failed)" in note
    assert max(len(line) for line in TABLE_NOTE.splitlines()) <= 120
    # the convention is the one computed: [1, 3] has sample sigma sqrt(2), population sigma 1
    assert mean_plus_3_sigma(np.array([1.0, 3.0])) == pytest.approx(2.0 + 3.0 * math.sqrt(2.0))


def test_magnitude_per_axis_and_floor_statistics_against_the_closed_form():
    """A synthetic class whose only error is a tilt bias b (per-axis sigma s) seen from a lander dropping at
    V: errors V (-tan b_north, tan b_east). Over many cases the magnitude is Rayleigh(V s), whose mean + 3
    sigma is (sqrt(pi/2) + 3 sqrt(2 - pi/2)) V s, and each axis normal(0, V s): 3 V s. The floor equals
    the error here, so it has the same two statistics."""
    rng = np.random.default_rng(5)
    count, drop_rate_mps, sigma_rad = 40000, 72.0, math.radians(1.0) / math.sqrt(2.0)
    bias_east, bias_north = rng.normal(0.0, sigma_rad, count), rng.normal(0.0, sigma_rad, count)
    error_east, error_north = -drop_rate_mps * np.tan(bias_north), drop_rate_mps * np.tan(bias_east)
    truth_east, truth_north = rng.normal(0.0, 10.0, count), rng.normal(0.0, 10.0, count)
    results = pd.DataFrame({
        "class_name": "gcp", "status": "ok", "valid": True, "velocity_error_mps": np.hypot(error_east, error_north),
        "estimate_velocity_east_mps": truth_east + error_east, "estimate_velocity_north_mps": truth_north + error_north,
        "truth_velocity_east_mps": truth_east, "truth_velocity_north_mps": truth_north,
        "attitude_floor_mps": drop_rate_mps * np.tan(np.hypot(bias_east, bias_north)),
        "sensor_attitude_bias_east_rad": bias_east, "sensor_attitude_bias_north_rad": bias_north})
    row = site_table(results, {"gcp": 1.0}, "Gusev").set_index("class").loc["gcp"]
    scale = drop_rate_mps * sigma_rad                    # 0.888 m/s: total tilt 1 deg RMS
    magnitude = (math.sqrt(math.pi / 2.0) + 3.0 * math.sqrt(2.0 - math.pi / 2.0)) * scale
    assert row["error_mean_3sigma_mps"] == pytest.approx(magnitude, rel=0.015)
    assert row["error_axis_mean_3sigma_mps"] == pytest.approx(3.0 * scale, rel=0.015)
    assert row["floor_mean_3sigma_mps"] == pytest.approx(magnitude, rel=0.015)
    assert row["floor_axis_mean_3sigma_mps"] == pytest.approx(3.0 * scale, rel=0.015)
    site = site_table(results, {"gcp": 1.0}, "Gusev").iloc[-1]
    assert site["error_axis_mean_3sigma_mps"] == pytest.approx(row["error_axis_mean_3sigma_mps"])
    text = format_table(site_table(results, {"gcp": 1.0}, "Gusev"))
    rows = {line.split("  ")[0]: line.split() for line in text.splitlines()}
    assert rows["error per axis"][-2:] == [f"{row['error_axis_mean_3sigma_mps']:.2f}"] * 2      # gcp, site
    assert rows["floor |v|"][-1] == f"{site['floor_mean_3sigma_mps']:.2f}"
    assert rows["error |v|"][-2:] == [f"{row['error_mean_3sigma_mps']:.2f}"] * 2          # site: the weighted one
    assert max(len(line) for line in text.splitlines()) <= 120


def test_tables_without_the_per_axis_columns_leave_those_statistics_unknown():
    table = site_table(pd.DataFrame(_rows("a", [1.0, 2.0])), {"a": 1.0}, "site").set_index("class")
    assert math.isnan(table.loc["a", "error_axis_mean_3sigma_mps"]) and math.isnan(table.loc["site", "floor_mean_3sigma_mps"])
    assert table.loc["a", "error_mean_3sigma_mps"] == pytest.approx(1.5 + 3 * math.sqrt(0.5))


def test_flight_metrics_of_a_plugin_without_template_metrics_say_so_never_nan():
    """A plug-in reporting features without brightness/contrast/correlation stores NaN per template (one
    reporting none stores empty lists): its Table-3 rows say "no valid templates", never "nan [nan-nan]";
    a class mixing NaN and finite values summarises the finite ones."""
    from campaign.realism.flight_metrics import metrics_table

    nan = math.nan
    rows = [{"class_name": "a", "status": "ok", "feature_brightness": [nan, nan], "feature_contrast": [nan, nan],
             "feature_correlation": [nan, nan], "feature_status": ["ok", "ok"]},
            {"class_name": "b", "status": "ok", "feature_brightness": [], "feature_contrast": [],
             "feature_correlation": [], "feature_status": []},
            {"class_name": "c", "status": "ok", "feature_brightness": [nan, 2000.0], "feature_contrast": [nan, 20.0],
             "feature_correlation": [nan, 0.5], "feature_status": ["ok", "ok"]}]
    text = metrics_table(pd.DataFrame(rows), ["a", "b", "c"])
    assert "nan" not in text.lower()
    for name in ("a", "b"):
        line = next(row for row in text.splitlines() if row.startswith(f"| {name} "))
        assert line.count("no valid templates") == 4, line
    line = next(row for row in text.splitlines() if row.startswith("| c "))
    assert "2000 [2000-2000]" in line and "0.500 [0.500-0.500]" in line and "1.00 [1.00-1.00]" in line
