"""`campaign gate` and the sweep features a nightly job needs (issue 32), with real parts.

Fast: one sweep file covers Gusev and Meridiani (a ``site`` axis, each point on its own site's classes);
a plug-in's parameter is an axis; the sweep table fits 120 columns with counts beside every %; a
directory that is neither store nor sweep is one line, exit 2.

On a real cluster (tiny campaigns of the IMU-minus-bias plug-in, tests/plugins/python_estimators.py): two
campaign stores whose plug-in differs by a 6 m/s east bias are gated: exit 4 (distinct from 1 failed
cases, 2 bad input), gate.json holds every compared row with its test, p-value and decision and both
stores' identities, the verdict line is first and ``| head -1`` keeps the exit code; an identical
candidate passes (exit 0). A sweep directory reused with ``--reuse`` copies verified unchanged points and
recomputes a point whose copy does not verify.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from campaign.cli import main
from campaign.configuration.sweep_file import SITE_AXIS, load_sweep
from campaign.report.gate import REGRESSION_EXIT
from campaign.report.sweep_outputs import PointSummary, format_sweep_table, sensitivity_table
from service_campaigns import campaign_file

REPO = Path(__file__).resolve().parents[3]
NIGHTLY = REPO / "sitedata" / "sweeps" / "nightly.toml"
PLUGINS = REPO / "tests"


# --- one sweep file, several sites ----------------------------------------------------------------
def test_the_nightly_file_sweeps_gusev_and_meridiani_each_on_its_own_classes(tmp_path):
    spec = load_sweep(NIGHTLY, output_dir=tmp_path / "out")
    assert list(spec.axes)[0] == SITE_AXIS and spec.axes[SITE_AXIS] == ["Gusev", "Meridiani"]
    per_site = {site: [p for p in spec.points if p.values[SITE_AXIS] == site] for site in ("Gusev", "Meridiani")}
    assert len(per_site["Gusev"]) == len(per_site["Meridiani"]) == 9 and len(spec.points) == 18
    for site, classes in (("Gusev", {"gcp", "gdcp", "gkep"}), ("Meridiani", {"hbsp", "hdcp", "heb"})):
        for point in per_site[site]:
            assert point.config.site.name == site and set(point.config.cases_per_class) == classes
    # the same axis values on both sites: distinct configurations (and stores)
    assert len({p.config_hash for p in spec.points}) == 18
    # [sweep] cases_scale 0.05 of the paper counts, each site its own (gkep 78 -> 4, hbsp 44 -> 2)
    assert per_site["Gusev"][0].config.cases_per_class == {"gcp": 9, "gdcp": 6, "gkep": 4}
    assert per_site["Meridiani"][0].config.cases_per_class == {"hbsp": 2, "hdcp": 9, "heb": 2}
    assert [view.base.site.name for view in spec.site_views()] == ["Gusev", "Meridiani"]
    assert all(SITE_AXIS not in view.axes and len(view.points) == 9 for view in spec.site_views())


def test_two_bases_of_one_site_are_refused_in_one_line(tmp_path, capsys):
    path = tmp_path / "twice.toml"
    gusev = REPO / "sitedata" / "gusev.toml"
    path.write_text(f'[sweep]\nbase = ["{gusev}", "{gusev}"]\n[axes]\n"sensors.perfect" = [true, false]\n')
    code = main(["sweep", str(path), "--output", str(tmp_path / "out"), "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 2 and "one base per site" in stderr and len(stderr.strip().splitlines()) == 1, stderr


# --- plug-in parameters are sweepable ------------------------------------------------------------
def _probe_campaign(directory: Path, bias_east_mps: float = 0.0, cases: dict | None = None) -> Path:
    extra = ('[[estimators]]\nname = "probe"\nkind = "python"\ncallable = "plugins.python_estimators:imu_minus_bias"\n'
             f'[estimators.parameters]\nbias = [{bias_east_mps}, 0.0]\n')
    return campaign_file(directory, cases=cases, extra=extra, name=f"probe_{bias_east_mps:g}.toml")


def test_a_plugin_parameter_is_an_axis(tmp_path):
    base = _probe_campaign(tmp_path)
    path = tmp_path / "bias.toml"
    path.write_text(f'[sweep]\nbase = "{base}"\n[axes]\n"estimators.probe.parameters.bias" = [[0.0, 0.0], [6.0, 0.0]]\n'
                    '"estimators.probe.timeout_s" = [30.0]\n')
    spec = load_sweep(path, output_dir=tmp_path / "out")
    assert [p.values["estimators.probe.parameters.bias"] for p in spec.points] == [[0.0, 0.0], [6.0, 0.0]]
    for point, bias in zip(spec.points, ([0.0, 0.0], [6.0, 0.0])):
        (probe,) = point.config.estimators
        assert probe.name == "probe" and probe.parameters == {"bias": bias} and probe.timeout_s == 30.0
    assert spec.points[0].config_hash != spec.points[1].config_hash      # a parameter is part of the hash
    unknown = tmp_path / "unknown.toml"
    unknown.write_text(f'[sweep]\nbase = "{base}"\n[axes]\n"estimators.nobody.parameters.bias" = [1.0]\n')
    with pytest.raises(Exception, match="no estimator named 'nobody'.*its estimators are probe"):
        load_sweep(unknown, output_dir=tmp_path / "out2")


# --- the sweep table: 120 columns, counts beside every % --------------------------------------------
def _rows(point_id: str, class_name: str, valid_errors: list[float], invalid: int) -> list[dict]:
    row = {"point_id": point_id, "estimator": "a_rather_long_estimator_name", "class_name": class_name, "status": "ok"}
    return ([{**row, "valid": True, "velocity_error_mps": e, "velocity_error_east_mps": e, "velocity_error_north_mps": 0.0}
             for e in valid_errors]
            + [{**row, "valid": False, "velocity_error_mps": math.nan, "velocity_error_east_mps": math.nan,
                "velocity_error_north_mps": math.nan}] * invalid)


def test_the_sweep_table_fits_120_columns_with_counts_beside_every_percentage():
    axes = {"scene.off_nominal.dust_particle_count": 0, "scene.off_nominal.angular_rate_multiplier": 1.0,
            "sensors.attitude_random_sigma_deg": 0.05}
    fractions = {"gcp": 0.59, "gdcp": 0.41, "gkep": 0.0}
    points = [PointSummary(f"p00{i}", {k: v * (i + 1) for k, v in axes.items()}, "h", "Gusev", fractions,
                           {"gcp": 186, "gdcp": 112, "gkep": 78}, 5.0, ["a_rather_long_estimator_name"]) for i in range(2)]
    results = pd.DataFrame(_rows("p000", "gcp", [1.0] * 183, 3) + _rows("p000", "gdcp", [2.0] * 100, 12)
                           + _rows("p000", "gkep", [9.0] * 3, 75) + _rows("p001", "gcp", [1.0] * 10, 176)
                           + _rows("p001", "gdcp", [1.0] * 112, 0) + _rows("p001", "gkep", [], 78))
    for column in ("floor_error_east_mps", "floor_error_north_mps"):
        results[column] = 0.0
    text = format_sweep_table(points, sensitivity_table(points, results))
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 120, max(lines, key=len)
    assert "98.4% (183/186)" in text and "89.3% (100/112)" in text and "3.8% (3/78)" in text   # counts by hand
    assert "5.4% (10/186)" in text and "100.0% (112/112)" in text and "0.0% (0/78)" in text
    # the site group: weighted % valid, with the valid/ran counts of the classes inside the ellipse
    assert f"{0.59 * 100 * 183 / 186 + 0.41 * 100 * 100 / 112:.1f}% (283/298)" in text
    assert "3/286" in text           # gkep's 3 valid cases at 9 m/s are false-valid (all classes)
    assert any(line.startswith("block 2 of") for line in lines)


def test_a_directory_that_is_neither_store_nor_sweep_is_one_line_exit_2(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code = main(["gate", str(tmp_path / "empty"), "--baseline", str(tmp_path / "empty")])
    stderr = capsys.readouterr().err
    assert code == 2 and "not a campaign store and not a sweep output directory" in stderr
    assert len(stderr.strip().splitlines()) == 1
    for command in ("table", "report"):          # the store commands say what they accept
        code = main([command, str(tmp_path / "empty")])
        stderr = capsys.readouterr().err
        assert code == 2 and "not a campaign store (no manifest.json) and not a sweep output directory" in stderr
        assert len(stderr.strip().splitlines()) == 1


# --- on a real cluster --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scheduler(warm_scheduler) -> str:
    """The test process's warm cluster (``warm_scheduler``, tests/conftest.py): its start-up is not tested here."""
    return warm_scheduler


@pytest.fixture(scope="module")
def probe_stores(tmp_path_factory, scheduler):
    """Two stores of the same 3 Gusev cases: the plug-in honest (baseline) and 6 m/s off east (candidate)."""
    directory = tmp_path_factory.mktemp("gate")
    stores = {}
    for bias in (0.0, 6.0):
        out = directory / f"bias{bias:g}"
        code = main(["submit", str(_probe_campaign(directory, bias)), "--output", str(out), "--scheduler", scheduler,
                     "--no-progress"])
        assert code == 0
        stores[bias] = out
    return stores


@pytest.mark.cluster
@pytest.mark.slow
def test_a_6_mps_bias_is_a_regression_exit_4_with_the_verdict_in_gate_json(probe_stores, capsys):
    baseline, candidate = probe_stores[0.0], probe_stores[6.0]
    code = main(["gate", str(candidate), "--baseline", str(baseline)])
    stdout = capsys.readouterr().out
    assert code == REGRESSION_EXIT == 4
    assert stdout.splitlines()[0].startswith("gate: REGRESSION: ") and str(candidate / "gate.json") in stdout.splitlines()[0]
    record = json.loads((candidate / "gate.json").read_text())
    assert (candidate / "gate.md").read_text().startswith("# Gate: regression")
    assert record["verdict"] == "regression" and record["exit_code"] == 4
    assert record["candidate"]["kind"] == record["baseline"]["kind"] == "campaign"
    for side, store in (("candidate", candidate), ("baseline", baseline)):
        manifest = json.loads((store / "manifest.json").read_text())
        (point,) = record[side]["points"]
        assert point["config_hash"] == manifest["config_hash"] and point["manifest_sha256"] == manifest["manifest_sha256"]
    rows = record["rows"]
    # every compared row: 2 classes with cases and the site, 3 metrics each (gkep ran no case: not compared)
    assert {(row["class"], row["metric"]) for row in rows} == {
        (c, m) for c in ("gcp", "gdcp") for m in ("false-valid", "% valid", "error mean+3 sigma m/s")} | {
        ("Gusev weighted", m) for m in ("false-valid", "weighted % valid", "weighted error m/s")}
    before, after = (pd.read_parquet(store / "results.parquet") for store in (baseline, candidate))

    def false_valid(results: pd.DataFrame, class_name: str) -> int:
        members = results if class_name == "Gusev weighted" else results[results["class_name"] == class_name]
        return int((members["valid"] & (members["velocity_error_mps"] > 5.0)).sum())

    for row in rows:
        assert row["decision"] in ("regression", "pass", "not judged") and row["estimator"] == "probe"
        if row["metric"] == "false-valid":          # recounted from both stores' rows, valid and error > 5 m/s
            assert row["baseline_value"] == false_valid(before, row["class"]) == 0    # the IMU velocity: within 5 m/s
            assert row["candidate_value"] == false_valid(after, row["class"]) and row["p_value"] is None
            assert row["decision"] == ("regression" if row["candidate_value"] > 0 else "pass")
        if row["metric"] in ("% valid", "weighted % valid"):     # same valid flags: no drop, exact p = 1
            assert row["decision"] == "pass" and row["p_value"] == 1.0 and row["test_name"] == "fisher_exact_one_sided"
    assert false_valid(after, "Gusev weighted") > 0      # 6 m/s east makes at least one valid case false-valid
    assert record["regressions"] == sum(row["decision"] == "regression" for row in rows) >= 2


@pytest.mark.cluster
@pytest.mark.slow
def test_head_minus_1_shows_the_verdict_and_keeps_the_exit_code(probe_stores):
    baseline, candidate = probe_stores[0.0], probe_stores[6.0]
    script = (f"set -o pipefail; {sys.executable} -m campaign.cli gate {candidate} --baseline {baseline} "
              f"--verdict {candidate / 'piped' / 'gate.json'} | head -1")
    result = subprocess.run(["bash", "-c", script], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 4, result.stderr
    assert result.stdout.startswith("gate: REGRESSION: ") and len(result.stdout.splitlines()) == 1
    assert json.loads((candidate / "piped" / "gate.json").read_text())["verdict"] == "regression"


@pytest.mark.cluster
@pytest.mark.slow
def test_an_unchanged_candidate_passes_with_exit_0(probe_stores, capsys):
    baseline = probe_stores[0.0]
    code = main(["gate", str(baseline), "--baseline", str(baseline), "--verdict", str(baseline / "self" / "gate.json")])
    first = capsys.readouterr().out.splitlines()[0]
    assert code == 0 and first.startswith("gate: PASS: no regression in ")
    record = json.loads((baseline / "self" / "gate.json").read_text())
    assert record["verdict"] == "pass" and record["regressions"] == 0
    assert {row["decision"] for row in record["rows"]} == {"pass"}


@pytest.mark.cluster
@pytest.mark.slow
def test_reuse_copies_verified_unchanged_points_and_recomputes_a_corrupt_one(tmp_path, scheduler, capsys):
    base = _probe_campaign(tmp_path, 0.0, cases={"gcp": 1, "gdcp": 1, "gkep": 0})
    path = tmp_path / "night.toml"
    path.write_text(f'[sweep]\nbase = "{base}"\n[axes]\n"estimators.probe.parameters.bias" = [[0.0, 0.0], [1.0, 0.0]]\n')
    first, second = tmp_path / "night-1", tmp_path / "night-2"
    assert main(["sweep", str(path), "--output", str(first), "--scheduler", scheduler, "--no-progress"]) == 0
    capsys.readouterr()
    stores = sorted((first / "points").glob("*/manifest.json"))
    assert len(stores) == 2
    damaged = stores[1].parent
    case_file = next((damaged / "cases").glob("??/batch-*.parquet"))
    case_file.write_bytes(case_file.read_bytes()[:-7] + b"garbage")      # same name, other bytes
    code = main(["sweep", str(path), "--output", str(second), "--reuse", str(first), "--scheduler", scheduler,
                 "--no-progress", "--baseline", str(first)])
    captured = capsys.readouterr()
    assert code == 0, captured.out + captured.err
    assert "2 points, 1 reused, 1 copied from" in captured.out and "2 cases done" in captured.out
    assert "not reused, computed: the copy does not verify" in captured.err
    description = json.loads((second / "sweep.json").read_text())
    reused = [p for p in description["points"] if "reused_from" in p]
    assert len(reused) == 1 and reused[0]["store"] == f"points/{stores[0].parent.name}"
    kept = second / reused[0]["store"] / "cases"
    assert {p.name: p.read_bytes() for p in kept.rglob("*.parquet")} == {
        p.name: p.read_bytes() for p in (stores[0].parent / "cases").rglob("*.parquet")}
    assert json.loads((second / "gate.json").read_text())["verdict"] == "pass"
    # a point whose configuration changed since the previous night is computed, and a note says why
    path.write_text(f'[sweep]\nbase = "{base}"\n[axes]\n"estimators.probe.parameters.bias" = [[0.0, 0.0], [2.0, 0.0]]\n')
    third = tmp_path / "night-3"
    code = main(["sweep", str(path), "--output", str(third), "--reuse", str(first), "--scheduler", scheduler,
                 "--no-progress"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "p001: no store of the same configuration hash in" in captured.err and "computed" in captured.err
