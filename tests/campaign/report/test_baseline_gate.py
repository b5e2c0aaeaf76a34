"""The --baseline gate's decision rules on hand-made case rows, against independent answers: Fisher exact
p-values in closed form (and scipy's), false-valid counts, permutation verdicts on errors built to be
noise or a real shift (and the permutation test's level on same-distribution pairs); the one-line refusal of a
corrupt or incompatible baseline directory; status of a sweep directory; --cases-scale."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import fisher_exact

from campaign.cli import main
from campaign.configuration.sweep_file import Tolerances, load_sweep
from campaign.report.baseline_gate import (
    GateRules,
    format_findings,
    growth_p_value,
    judge_point,
    valid_drop_p_value,
)
from campaign.report.gate import GatePoint, GateSide, gate
from campaign.report.sweep_baseline import read_baseline
from campaign.store.campaign_store import StoreError
from campaign.store.sweep_directory import sweep_status_lines

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"
FRACTIONS = {"gcp": 0.6, "gdcp": 0.4, "gkep": 0.0}
DEFAULT = GateRules()          # the defaults of [tolerances]


def _rows(class_name: str, errors=(), invalid: int = 0, failed: int = 0, estimator: str = "dimes") -> list[dict]:
    row = {"estimator": estimator, "class_name": class_name}
    return ([{**row, "status": "ok", "valid": True, "velocity_error_mps": float(e)} for e in errors]
            + [{**row, "status": "ok", "valid": False, "velocity_error_mps": math.nan}] * invalid
            + [{**row, "status": "failed", "valid": False, "velocity_error_mps": math.nan}] * failed)


def _judge(before: list[dict], now: list[dict], rules: GateRules = DEFAULT):
    return judge_point("p000 (x=1)", "key", pd.DataFrame(before), pd.DataFrame(now), FRACTIONS, "Gusev", 5.0, rules)


def _metrics(findings) -> set[tuple[str, str]]:
    return {(finding.class_name, finding.metric) for finding in findings}


# --- the exact test --------------------------------------------------------------------------------
def test_fisher_p_value_in_closed_form():
    # 10/10 vs 0/10: only the observed table is as extreme, p = 1 / C(20, 10)
    assert valid_drop_p_value(10, 10, 0, 10) == pytest.approx(1.0 / math.comb(20, 10), rel=1e-12)
    # 9/9 vs 8/9: the one invalid case is equally likely in either group, p = 9/18
    assert valid_drop_p_value(9, 9, 8, 9) == pytest.approx(0.5, rel=1e-12)
    # 5/5 vs 3/5: P(X >= 5), X hypergeometric (10 cases, 8 valid, 5 drawn) = C(8,5) / C(10,5) = 56/252
    assert valid_drop_p_value(5, 5, 3, 5) == pytest.approx(56 / 252, rel=1e-12)
    assert valid_drop_p_value(3, 9, 9, 9) == pytest.approx(1.0)     # the candidate is better: no evidence


@pytest.mark.parametrize("counts", [(10, 10, 0, 10), (9, 9, 8, 9), (17, 20, 9, 20), (40, 50, 45, 60), (0, 4, 0, 7)])
def test_fisher_p_value_equals_scipy_one_sided(counts):
    valid_before, cases_before, valid_now, cases_now = counts
    _, expected = fisher_exact([[valid_before, cases_before - valid_before], [valid_now, cases_now - valid_now]],
                               alternative="greater")
    assert valid_drop_p_value(*counts) == pytest.approx(expected, rel=1e-9)


def test_all_valid_to_none_valid_is_a_regression_with_its_p_value():
    before = _rows("gcp", [1.0] * 10)
    now = _rows("gcp", invalid=10)
    rules = GateRules(pct_valid_drop_points=100.0)        # only the exact test can call it
    findings = [f for f in _judge(before, now, rules) if f.class_name == "gcp"]
    assert [(f.metric, f.baseline, f.candidate) for f in findings] == [("% valid", "100.0 (10/10)", "0.0 (0/10)")]
    assert findings[0].test == f"p = {1 / math.comb(20, 10):.3g}" and findings[0].why == "p < 0.01"


def test_one_flip_among_nine_is_not_a_regression_at_one_percent():
    before = _rows("gcp", [1.0, 1.2, 0.8, 1.1, 0.9, 1.0, 1.05, 0.95, 1.0])
    now = _rows("gcp", [1.0, 1.2, 0.8, 1.1, 0.9, 1.0, 1.05, 0.95], invalid=1)
    assert _judge(before, now) == []                     # default tolerances: p = 0.5, drop 11.1 < 20 points
    tight = GateRules(pct_valid_drop_points=10.0)        # a points tolerance below one case in nine trips it
    assert [f.why for f in _judge(before, now, tight) if f.class_name == "gcp"] == ["drop 11.1 > 10 points"]


def test_failed_rows_are_left_out_of_the_counts():
    before = _rows("gcp", [1.0] * 9)
    now = _rows("gcp", [1.0] * 5, failed=4)             # 5/5 of the cases that ran: no drop
    assert _judge(before, now) == []


# --- false-valid -------------------------------------------------------------------------------------
def test_any_false_valid_increase_is_a_regression_whatever_the_error_tolerance():
    before = _rows("gcp", [1.0, 1.5, 2.0, 1.2])
    now = _rows("gcp", [1.0, 1.5, 2.0, 6.0])             # one valid case now 6 m/s off (> 5 m/s)
    rules = GateRules(error_increase_mps=1000.0)
    findings = _judge(before, now, rules)
    assert _metrics(findings) == {("gcp", "false-valid"), ("Gusev weighted", "false-valid")}
    gcp = next(f for f in findings if f.class_name == "gcp")
    assert (gcp.baseline, gcp.candidate) == ("0 of 4 valid", "1 of 4 valid")
    assert _judge(before, now, GateRules(false_valid_increase=1, error_increase_mps=1000.0)) == []
    assert _judge(now, now, rules) == []


def test_false_valid_baseline_count_is_scaled_to_the_candidate_cases():
    before = _rows("gcp", [1.0] * 9 + [7.0])             # 1 false-valid in 10 cases
    same_rate = _rows("gcp", [1.0] * 18 + [7.0, 8.0])     # 2 in 20: the same rate
    higher = _rows("gcp", [1.0] * 17 + [7.0, 8.0, 9.0])   # 3 in 20
    rules = GateRules(error_increase_mps=1000.0)
    assert _judge(before, same_rate, rules) == []
    assert ("gcp", "false-valid") in _metrics(_judge(before, higher, rules))


# --- the error's permutation test ------------------------------------------------------------------
def test_a_real_error_shift_is_a_regression_with_its_permutation_p_value():
    errors = np.random.default_rng(7).normal(1.0, 0.2, 30).clip(0.1)
    before = _rows("gcp", errors) + _rows("gdcp", errors)
    now = _rows("gcp", errors + 1.0) + _rows("gdcp", errors)   # gcp every error + 1 m/s: growth exactly 1 m/s
    findings = _judge(before, now)
    assert _metrics(findings) == {("gcp", "error mean+3 sigma m/s"), ("Gusev weighted", "weighted error m/s")}
    gcp = next(f for f in findings if f.class_name == "gcp")
    # 1 m/s is 5 sigma of the errors: only the observed split of the 60 pooled errors (1 in C(60, 30)) grows
    # that much, so no shuffle does, p = 1 / (1 + 2000)
    assert gcp.why == "+1.00 > 0.5 m/s; p < 0.01" and gcp.test == f"p = {1 / 2001:.3g} (permutation)"
    site = next(f for f in findings if f.class_name == "Gusev weighted")
    assert site.why.startswith("+0.60 > 0.5 m/s")               # 0.6 * 1 m/s (gdcp unchanged, gkep weight 0)
    assert _judge(before, now, GateRules(error_increase_mps=1.0)) == []      # growth not above the tolerance


def test_one_outlier_among_five_is_noise_not_a_regression():
    before = np.array([1.0, 1.1, 0.9, 1.0, 1.05])
    now = np.array([1.0, 1.1, 0.9, 1.0, 2.0])           # mean+3 sigma 1.22 -> 2.57 m/s, but from one case
    assert _judge(_rows("gcp", before), _rows("gcp", now), GateRules(pct_valid_drop_points=100.0)) == []
    # the 2.0 lands in the candidate half of a shuffle of the ten pooled values half of the time
    assert growth_p_value([(1.0, before, now)], "key") > 0.05


def test_smallest_permutation_p_value_is_one_over_the_number_of_splits():
    before, now = np.array([1.0, 1.1, 0.9, 1.0]), np.array([30.0, 31.0, 29.0, 30.5])   # every large one moved
    p_value = growth_p_value([(1.0, before, now)], "key")
    assert p_value == pytest.approx(1 / math.comb(8, 4), abs=0.006)       # 1/70 up to Monte Carlo error (2000)


def test_permutation_test_keeps_its_level_and_sees_a_real_growth():
    """100 pairs from one distribution (9 valid cases each side) and 100 whose candidate errors are doubled
    (30 each side): a calibrated one-sided test rejects about 5 of the first at 5 % and 1 at 1 %."""
    rng = np.random.default_rng(2026)
    same = [growth_p_value([(1.0, rng.gamma(4, 0.5, 9), rng.gamma(4, 0.5, 9))], f"a{k}") for k in range(100)]
    doubled = [growth_p_value([(1.0, rng.gamma(4, 0.5, 30), 2.0 * rng.gamma(4, 0.5, 30))], f"b{k}")
               for k in range(100)]
    assert sum(p < 0.05 for p in same) <= 10 and sum(p < 0.01 for p in same) <= 3
    assert sum(p < 0.01 for p in doubled) >= 80


def test_resampling_is_seeded_by_what_it_judges():
    pair = [(1.0, np.array([1.0, 2.0, 3.0, 2.5]), np.array([2.0, 3.0, 5.0, 2.2]))]
    assert growth_p_value(pair, "a") == growth_p_value(pair, "a")
    assert growth_p_value(pair, "a") != growth_p_value(pair, "b")


def test_estimators_are_judged_against_their_own_baseline_rows():
    good = _rows("gcp", [1.0] * 10) + _rows("gcp", [1.0] * 10, estimator="pc")
    worse = _rows("gcp", [1.0] * 10) + _rows("gcp", invalid=10, estimator="pc")
    findings = _judge(good, worse)
    assert findings and {f.estimator for f in findings} == {"pc"}
    table = format_findings(findings).splitlines()
    assert table[0].split() == ["point", "class", "estimator", "metric", "baseline", "candidate", "test", "why"]
    assert len(table) == 1 + len(findings)


def test_tolerances_defaults_and_bounds():
    assert Tolerances().false_valid_increase == 0 and Tolerances().significance == 0.01
    assert Tolerances().pct_valid_drop_points == DEFAULT.pct_valid_drop_points


# --- the baseline directory ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    directory = tmp_path_factory.mktemp("spec")
    path = directory / "sweep.toml"
    path.write_text(f'[sweep]\nbase = "{GUSEV}"\n[sweep.cases]\ngcp = 2\ngdcp = 1\ngkep = 0\n'
                    '[axes]\n"scene.camera_effects.dark_current_scale" = [1.0, 2.0]\n')
    return path, load_sweep(path, output_dir=directory / "out")


def _description(spec, **changes) -> dict:
    description = {"axes": spec.axes, "site": spec.base.site.name, "cases_per_class": spec.base.cases_per_class,
                   "points": [{"point_id": p.point_id, "values": p.values, "config_hash": p.config_hash,
                               "store": f"points/{p.config_hash[:16]}"} for p in spec.points]}
    return {**description, **changes}


@pytest.mark.parametrize("content, expected", [
    ("{not json", "not valid JSON"),
    ('{"axes": {}}', "not a sweep description"),
    (None, "other axes"),
    ("site", "of site 'Meridiani'"),
    ("values", "no point of this sweep has the site and axis values of a baseline point"),
    ("rows", "no case rows of p000"),
])
def test_corrupt_or_incompatible_baseline_is_one_line_exit_2(spec, tmp_path, capsys, content, expected):
    path, sweep = spec
    baseline = tmp_path / "baseline"
    baseline.mkdir()
    if content is None:
        text = json.dumps(_description(sweep, axes={"sensors.attitude_random_sigma_deg": [0.1]}))
        expected = "the baseline sweeps sensors.attitude_random_sigma_deg, this sweep scene.camera_effects"
    elif content == "site":
        text = json.dumps(_description(sweep, site="Meridiani"))
    elif content == "values":
        text = json.dumps(_description(sweep, points=[{"point_id": "p000", "store": "points/x",
                                                       "values": {"scene.camera_effects.dark_current_scale": 9.0}}]))
    elif content == "rows":
        text = json.dumps(_description(sweep))
    else:
        text = content
    (baseline / "sweep.json").write_text(text)
    with pytest.raises(StoreError, match=expected):
        read_baseline(baseline, sweep)
    out = tmp_path / "out"
    code = main(["sweep", str(path), "--output", str(out), "--baseline", str(baseline), "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and expected in stderr, stderr
    assert not out.exists()


def test_status_of_a_sweep_directory_before_any_case(spec, tmp_path, capsys):
    _, sweep = spec
    (tmp_path / "sweep.json").write_text(json.dumps(_description(sweep)))
    lines = sweep_status_lines(tmp_path)
    assert len(lines) == 3 and lines[0].startswith("p000 (scene.camera_effects.dark_current_scale=1): no store yet")
    assert lines[0].endswith(": 3 cases missing") and lines[-1].endswith("6 planned, 0 done, 0 failed, 6 missing")
    assert main(["status", str(tmp_path)]) == 0
    assert "not a campaign directory" not in capsys.readouterr().out


def test_cases_scale_on_the_command_line_replaces_the_sweep_files(spec, tmp_path):
    path, _ = spec
    scaled = load_sweep(path, output_dir=tmp_path, cases_scale=0.5)
    assert scaled.base.cases_per_class == {"gcp": 1, "gdcp": 1, "gkep": 0}     # 2 * 0.5, and at least 1
    assert [p.config_hash for p in scaled.points] == [p.config_hash for p in spec[1].points]


def test_bad_cases_scale_is_one_line_exit_2(spec, tmp_path, capsys):
    path, _ = spec
    code = main(["sweep", str(path), "--output", str(tmp_path / "out"), "--cases-scale", "-1", "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 2 and "--cases-scale" in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert not (tmp_path / "out").exists()


def _side(directory: str, points: list[tuple[str, dict]], site: str = "Gusev") -> GateSide:
    return GateSide(Path(directory), "sweep", ["scene.camera_effects.dark_current_scale"],
                    [GatePoint(point_id, values, site, Path(directory) / point_id, "hash", "", FRACTIONS | {"gcp": 0.59,
                               "gdcp": 0.41}, 5.0, 20, 20, 0) for point_id, values in points])


def test_points_are_matched_by_axis_values_and_the_rest_is_noted():
    axis = "scene.camera_effects.dark_current_scale"
    baseline = _side("base", [("b007", {axis: 1})])            # only p000's values (1 and 1.0 match), another id
    candidate = _side("cand", [("p000", {axis: 1.0}), ("p001", {axis: 2.0})])
    rows = pd.DataFrame(_rows("gcp", invalid=10) + _rows("gdcp", [1.0] * 10) + _rows("gcp", [1.0], estimator="pc"))
    report = gate(candidate, baseline, GateRules(), {"b007": pd.DataFrame(_rows("gcp", [1.0] * 10) + _rows("gdcp", [1.0] * 10))},
                  {"p000": rows, "p001": rows})
    assert report.compared == 1
    findings = report.regressions
    assert {(f.point.split()[0], f.class_name, f.estimator, f.metric) for f in findings} == {
        ("p000", "gcp", "dimes", "% valid"), ("p000", "Gusev weighted", "dimes", "weighted % valid")}
    site = next(f for f in findings if f.class_name == "Gusev weighted")   # 0.59 * 0 + 0.41 * 100 (gkep 0)
    assert (site.baseline, site.candidate) == ("100.0 (20/20)", "41.0 (10/20)")
    assert site.test == f"p = {math.comb(30, 20) / math.comb(40, 20):.3g}"   # the 10 invalid all in the candidate
    assert report.notes == [
        f"p001 ({axis}=2): no baseline point with this site and these axis values: not compared",
        f"p000 ({axis}=1): estimator pc has no rows in baseline point b007: not compared"]
    # the same point on another site is not a partner
    with pytest.raises(StoreError, match="the baseline is of site 'Gusev', the candidate of 'Meridiani'"):
        gate(_side("cand", [("p000", {axis: 1.0})], site="Meridiani"), baseline, GateRules())
