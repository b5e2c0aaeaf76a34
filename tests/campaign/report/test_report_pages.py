"""`campaign report DIR` on a real small campaign (3 Gusev cases, the reference estimator and a command
estimator that always declines): the comparison figures and the failure gallery are written as non-empty
PNGs of the sizes their modules declare; the gallery holds exactly the cases the selection rule names
(every reference case false-valid at a 0.01 m/s threshold, the 3 declined cases as invalid), and the
reference's templates are drawn inside the images. Plus the selection rule on a hand-made table."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from campaign.report import compare_plots, gallery
from service_campaigns import campaign_with_command_estimator, run_campaign

DECLINER = '''import json, sys
json.dump({"velocity_east_mps": 0.0, "velocity_north_mps": 0.0, "valid": False, "reason": "declined"},
          open(sys.argv[1], "w"))
'''


def _png_size(path) -> tuple[int, int]:
    assert path.is_file() and path.stat().st_size > 0, path
    with Image.open(path) as image:
        return image.size


@pytest.fixture(scope="module")
def reported(tmp_path_factory, warm_scheduler):
    """The reported store (on the test process's warm cluster, ``warm_scheduler`` in tests/conftest.py: the
    report is tested, not the cluster's start-up)."""
    directory = tmp_path_factory.mktemp("report")
    config = campaign_with_command_estimator(directory, "decliner", DECLINER)
    config.write_text(config.read_text().replace("[campaign]\n", "[campaign]\nfalse_valid_mps = 0.01\n", 1))
    out = directory / "out"
    submit = run_campaign("submit", config, "--output", out, "--scheduler", warm_scheduler, "--no-progress")
    assert submit.returncode == 0, submit.stdout + submit.stderr
    report = run_campaign("report", out)
    assert report.returncode == 0 and "Traceback" not in report.stderr, report.stderr
    return out


@pytest.mark.cluster
@pytest.mark.slow
def test_report_writes_comparison_figures_of_the_declared_sizes(reported):
    report = reported / "report"
    dpi = compare_plots.FIGURE_DPI
    panels = 3 + 1                                           # gcp, gdcp, gkep and the site
    width, height = compare_plots.CDF_PANEL_INCHES
    assert _png_size(report / "error_cdf.png") == (round(panels * width * dpi), round(height * dpi))
    bars_width, bars_height = compare_plots.BARS_FIGURE_INCHES
    assert _png_size(report / "valid_false_valid.png") == (round(bars_width * dpi), round(bars_height * dpi))
    text = (report / "report.md").read_text()
    assert "![error CDF](error_cdf.png)" in text and "![% valid and false-valid](valid_false_valid.png)" in text
    assert "[failure gallery](gallery.md)" in text


@pytest.mark.cluster
@pytest.mark.slow
def test_gallery_shows_each_false_valid_and_declined_case_with_templates_drawn(reported):
    results = pd.read_parquet(reported / "results.parquet")
    dimes = results[results["estimator"] == "dimes"]
    valid_ids = sorted(dimes.loc[dimes["valid"], "case_id"].astype(int))
    png = sorted(path.name for path in (reported / "report" / "gallery").glob("*.png"))
    invalid_dimes = dimes[~dimes["valid"]]
    expected_dimes = valid_ids + sorted(invalid_dimes.groupby("reason")["case_id"].apply(
        lambda ids: sorted(ids.astype(int))[:3]).explode().astype(int))
    declined = sorted(results.loc[results["estimator"] == "decliner", "case_id"].astype(int))
    assert len(declined) == 3                              # 3 cases, each declined: one reason, all 3 shown
    expected = sorted([f"case-{i}-dimes.png" for i in expected_dimes] + [f"case-{i}-decliner.png" for i in declined])
    assert png == expected
    size = (round(gallery.FIGURE_INCHES[0] * gallery.FIGURE_DPI), round(gallery.FIGURE_INCHES[1] * gallery.FIGURE_DPI))
    for name in png:
        assert _png_size(reported / "report" / "gallery" / name) == size
    page = (reported / "report" / "gallery.md").read_text()
    assert page.count("![case ") == len(expected)
    assert page.count("reason `declined`") == 3
    # a drawn gallery image is not blank: its first image panel has grey levels and coloured marks
    if valid_ids:
        pixels = np.asarray(Image.open(reported / "report" / "gallery" / f"case-{valid_ids[0]}-dimes.png").convert("RGB"))
        green = (pixels[..., 1] > 200) & (pixels[..., 0] < 100) & (pixels[..., 2] < 100)
        assert green.sum() > 20                           # lime marks of the templates used
        assert pixels.std() > 10


def test_gallery_selection_rule_on_a_hand_made_table():
    rows = pd.DataFrame([
        # case, estimator, status, valid, reason, error
        (0, "a", "ok", True, "ok", 1.0), (1, "a", "ok", True, "ok", 9.0), (2, "a", "ok", True, "ok", 7.0),
        (3, "a", "ok", True, "ok", math.nan), (4, "a", "ok", False, "flat_peak", None),
        (5, "a", "ok", False, "flat_peak", None), (6, "a", "ok", False, "flat_peak", None),
        (7, "a", "ok", False, "flat_peak", None), (8, "a", "ok", False, "sky", None),
        (9, "a", "failed", False, "case_failed", None), (0, "b", "ok", True, "ok", 6.0),
    ], columns=["case_id", "estimator", "status", "valid", "reason", "velocity_error_mps"])
    chosen = [(c.estimator, c.case_id, c.kind) for c in gallery.gallery_cases(rows, 5.0)]
    assert chosen == [("a", 3, "false-valid"), ("a", 1, "false-valid"), ("a", 2, "false-valid"),   # NaN, 9, 7
                      ("a", 4, "invalid"), ("a", 5, "invalid"), ("a", 6, "invalid"),               # 3 of 4 flat_peak
                      ("a", 8, "invalid"), ("b", 0, "false-valid")]
    assert gallery.gallery_cases(rows.iloc[:0], 5.0) == []


@pytest.mark.cluster
@pytest.mark.slow
def test_template_marks_agree_with_the_estimators_own_image_motion(reported):
    """The gallery places templates and matches by projecting the estimator's ground positions through
    the camera model; the estimator measures the same motion through its rectification maps: two
    independent routes to the same pixels (within a pixel of the square binned frame)."""
    from campaign.case.compute import estimator_inputs, simulate_case_inputs
    from campaign.case.inputs import PlanRow, campaign_inputs
    from campaign.store.campaign_store import CampaignStore
    from campaign.store.stored_config import stored_config
    from dimes_velocity.estimator import estimate_velocity

    store = CampaignStore(reported)
    resources = campaign_inputs(stored_config(store, store.manifest()))
    plan = store.plan()
    row = PlanRow.from_record(plan.iloc[0].to_dict())
    shared = estimator_inputs(resources, simulate_case_inputs(resources, row))
    reference = next(built for spec, built in resources.estimators() if spec.kind == "reference")
    answer = estimate_velocity(list(shared.images), shared.measurements, shared.camera, reference.config,
                               shared.calibration.flat_field)
    marks = [mark for mark in gallery.feature_marks(shared.camera, shared.measurements, answer.features)
             if mark["status"] == "ok"]
    assert marks
    for mark in marks:
        assert abs(mark["motion_px"] - mark["estimator_motion_px"]) < 1.5, mark
        column, binned_row = mark["template"]
        assert 0 <= column < shared.images[0].shape[1] and 0 <= binned_row < shared.images[0].shape[0]


def _extreme_rows():
    """Two estimators; gcp with 1e30, inf, NaN and ordinary errors, gdcp with no valid case, gkep empty."""
    rows = []
    for name in ("dimes", "other"):
        for error, east in ((1e30, 1e30), (math.inf, math.inf), (math.nan, math.nan), (2.0, 3.0), (-0.0, -1e30)):
            rows.append({"estimator": name, "class_name": "gcp", "status": "ok", "valid": True, "reason": "ok",
                         "velocity_error_mps": error, "estimate_velocity_east_mps": east,
                         "estimate_velocity_north_mps": 0.0, "truth_velocity_east_mps": 1.0,
                         "truth_velocity_north_mps": math.nan})
        rows.append({"estimator": name, "class_name": "gdcp", "status": "ok", "valid": False, "reason": "sky",
                     "velocity_error_mps": None, "estimate_velocity_east_mps": None, "estimate_velocity_north_mps": None,
                     "truth_velocity_east_mps": 1.0, "truth_velocity_north_mps": 1.0})
    return pd.DataFrame(rows)


@pytest.mark.slow
def test_plots_survive_nan_inf_1e30_and_empty_classes(tmp_path):
    from campaign.report import plots
    from campaign.report.aggregate import site_table
    from campaign.report.compare import comparison_table

    results = _extreme_rows()
    fractions = {"gcp": 0.5, "gdcp": 0.5, "gkep": 0.0}
    comparison = comparison_table(results, fractions, "Gusev", false_valid_mps=5.0)
    written = [
        compare_plots.error_cdf(results, list(fractions), "Gusev", ["dimes", "other"], tmp_path / "cdf.png", 5.0),
        compare_plots.valid_false_valid_bars(comparison, tmp_path / "bars.png"),
        compare_plots.error_cdf(results.iloc[:0], list(fractions), "Gusev", ["dimes"], tmp_path / "cdf_empty.png", 5.0),
    ]
    dimes = results[results["estimator"] == "dimes"]
    table = site_table(dimes, fractions, "Gusev")
    written += [plots.error_histograms(dimes, tmp_path / "hist.png", "dimes", 5.0, list(fractions)),
                plots.valid_fraction_bars(table, tmp_path / "valid.png", "dimes"),
                plots.estimate_vs_truth(dimes, tmp_path / "scatter.png", "dimes")]
    for path in written:
        assert _png_size(path)[0] > 100
    # the bars of the empty gkep class and the 0 %-valid gdcp class are still drawn as text (n/a, 0%)
    assert comparison.set_index(["estimator", "class"]).loc[("dimes", "gdcp"), "pct_valid"] == 0.0


@pytest.mark.cluster
@pytest.mark.slow
def test_a_missing_stated_uncertainty_is_stored_nan_not_zero(reported):
    results = pd.read_parquet(reported / "results.parquet")
    declined = results[results["estimator"] == "decliner"]["velocity_uncertainty_mps"]
    assert len(declined) == 3 and declined.isna().all()             # invalid, nothing stated: NaN, never 0
    dimes = results[(results["estimator"] == "dimes") & results["valid"]]["velocity_uncertainty_mps"]
    assert (dimes > 0).all()                                        # the reference states one when valid
