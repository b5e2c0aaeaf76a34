"""`campaign sweep` with real parts: a dask LocalCluster of worker processes, real Parquet stores.

Validation errors are one line naming the sweep file and field (exit 2, nothing written); points are
reused by configuration hash; a degraded configuration and an estimator that adds false-valid cases are
caught by --baseline, an identical re-run is not; `campaign status` counts each point; plots are written;
and the estimator degrades with lens dust and with the angular rate multiplier (issue 7, done when).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from PIL import Image

from campaign.cli import main

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"
SMALL_CASES = "[sweep.cases]\ngcp = 3\ngdcp = 2\ngkep = 0\n"      # 5 cases per point


def _sweep_file(directory: Path, axes: str, extra: str = "", base: Path = GUSEV, name: str = "sweep.toml") -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / name
    path.write_text(f'[sweep]\nbase = "{base}"\n{extra}\n{SMALL_CASES}\n[axes]\n{axes}\n')
    return path


def _verdict(stdout: str) -> str:
    """The gate's verdict line: the first line the sweep prints after the cluster's dashboard line."""
    lines = [line for line in stdout.splitlines() if not line.startswith("dask dashboard: ")]
    return lines[0] if lines else ""


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main(["sweep", *map(str, argv), "--no-progress"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# --- validation at the edge -----------------------------------------------------------------------
@pytest.mark.parametrize("axes, extra, expected", [
    ('"scene.camera_effects.dark_current_scal" = [1.0, 2.0]', "", ["scene.camera_effects.dark_current_scal",
                                                                   "allowed", "dark_current_scale"]),
    ('"scene.camera_effects.dark_current_scale" = [1.0, -3.0]', "", ["scene.camera_effects.dark_current_scale",
                                                                     "out of range", "allowed: >= 0"]),
    ('"sensors.attitude_random_sigma_deg" = ["low", "high"]', "", ["sensors.attitude_random_sigma_deg",
                                                                   "must be a number"]),
    ('"estimator.template_size_px" = [15, 15.5]', "", ["estimator.template_size_px", "must be an integer"]),
    ('"site.sun.elevation_deg" = [40.0, 60.0]', "", ["axes.site.sun.elevation_deg", "allowed: sensors.<field>"]),
    ('"scene.camera_effects.dark_current_scale" = [1.0, "x"]', "", ["axes.scene.camera_effects.dark_current_scale",
                                                                    "mix types"]),
    ('"scene.camera_effects.dark_current_scale" = [1.0, 2.0]\n"sensors.attitude_random_sigma_deg" = [0.05]',
     'mode = "list"', ["equal length"]),
    ('"scene.camera_effects.dark_current_scale" = [1.0]', 'mode = "zigzag"', ["sweep.mode", "allowed: grid, list"]),
    ('"scene.camera_effects.dark_current_scale" = [1.0]', "cases_scale = -1.0", ["sweep.cases_scale", "out of range"]),
    ('"scene.camera_effects.dark_current_scale" = [1.0]\n[tolerances]\nerror_increase_mps = "big"', "",
     ["tolerances.error_increase_mps", "must be a number"]),
])
def test_bad_sweep_is_one_line_exit_2_nothing_written(tmp_path, capsys, axes, extra, expected):
    path = _sweep_file(tmp_path, axes, extra)
    out = tmp_path / "out"
    code, stdout, stderr = _run(capsys, path, "--output", out)
    assert code == 2, stdout + stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0], lines
    for text in expected:
        assert text in lines[0], lines[0]
    assert not out.exists()


def test_bad_base_and_unknown_class_name_the_sweep_file(tmp_path, capsys):
    missing = _sweep_file(tmp_path / "a", '"scene.camera_effects.dark_current_scale" = [1.0]', base=tmp_path / "no.toml")
    code, _, stderr = _run(capsys, missing, "--output", tmp_path / "out")
    assert code == 2 and str(missing) in stderr and "sweep.base" in stderr
    path = tmp_path / "b" / "sweep.toml"
    path.parent.mkdir()
    path.write_text(f'[sweep]\nbase = "{GUSEV}"\n[sweep.cases]\ngxx = 3\n[axes]\n"sensors.perfect" = [true, false]\n')
    code, _, stderr = _run(capsys, path, "--output", tmp_path / "out")
    assert code == 2 and "sweep.cases.gxx" in stderr and "allowed: gcp, gdcp, gkep" in stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("base, expected", [
    ('["gusev", "no.toml"]', "sweep.base = 'no.toml': no such file"),
    ('["gusevv"]', "sweep.base = 'gusevv' is not a shipped site"),
    ('"no.toml"', "sweep.base = 'no.toml': no such file"),
    ("[]", "sweep.base = [] names no campaign"),
])
def test_a_missing_base_is_one_readable_line(tmp_path, capsys, base, expected):
    """A base that names no file (in a list or alone) is said in words, not as the validator's union tags."""
    path = tmp_path / "sweep.toml"
    path.write_text(f'[sweep]\nbase = {base}\n[axes]\n"campaign.seed" = [1]\n')
    code, _, stderr = _run(capsys, path, "--output", tmp_path / "out")
    lines = stderr.strip().splitlines()
    assert code == 2 and len(lines) == 1 and expected in lines[0], stderr
    assert "function-before" not in lines[0] and "allowed: a shipped site (gusev, meridiani)" in lines[0]
    assert not (tmp_path / "out").exists()


def test_a_sweep_base_may_name_a_shipped_site(tmp_path):
    """``base = ["gusev", "meridiani"]`` in a sweep file is sitedata/gusev.toml and sitedata/meridiani.toml of the
    installed package, as in a campaign file; the points are those of the same sweep written with the paths."""
    from campaign.configuration.sweep_file import load_sweep

    by_name, by_path = tmp_path / "names.toml", tmp_path / "paths.toml"
    axes = '[axes]\n"campaign.seed" = [1, 2]\n'
    by_name.write_text(f'[sweep]\nbase = ["gusev", "meridiani"]\n{axes}')
    by_path.write_text(f'[sweep]\nbase = ["{GUSEV}", "{REPO / "sitedata" / "meridiani.toml"}"]\n{axes}')
    named, written = load_sweep(by_name, output_dir=tmp_path / "a"), load_sweep(by_path, output_dir=tmp_path / "b")
    assert [point.values["site"] for point in named.points] == ["Gusev", "Gusev", "Meridiani", "Meridiani"]
    assert [point.config_hash for point in named.points] == [point.config_hash for point in written.points]
    assert [Path(base.source).resolve() for base in named.all_bases] == [GUSEV.resolve(), (REPO / "sitedata" / "meridiani.toml").resolve()]


def test_command_line_exit_code_and_bad_baseline(tmp_path):
    path = _sweep_file(tmp_path, '"scene.camera_effects.dark_current_scale" = [1.0]')
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "sweep", str(path), "--output", str(tmp_path / "out"),
                             "--baseline", str(tmp_path / "nowhere")], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 2 and "not a sweep output directory" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


# --- runs on a real cluster -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scheduler(warm_scheduler) -> str:
    """The test process's warm cluster (``warm_scheduler``, tests/conftest.py): its start-up is not tested here."""
    return warm_scheduler


def _case_files(out: Path) -> dict:
    return {p.relative_to(out): p.stat().st_mtime_ns for p in out.glob("points/*/cases/*/batch-*.parquet")}


@pytest.fixture(scope="module")
def first_sweep(tmp_path_factory, scheduler):
    directory = tmp_path_factory.mktemp("sweep")
    path = _sweep_file(directory, '"scene.camera_effects.dark_current_scale" = [1.0, 2.0]')
    out = directory / "out"
    code = main(["sweep", str(path), "--output", str(out), "--scheduler", scheduler, "--no-progress"])
    assert code == 0
    return path, out


@pytest.mark.cluster
@pytest.mark.slow
def test_results_are_one_dataset_keyed_by_point(first_sweep):
    _, out = first_sweep
    results = pd.read_parquet(out / "results.parquet")
    assert list(results.columns[:3]) == ["point_id", "scene.camera_effects.dark_current_scale", "config_hash"]
    assert {"case_id", "class_name", "valid", "velocity_error_mps", "status"} <= set(results.columns)
    per_point = results.groupby("point_id")
    assert per_point.size().to_dict() == {"p000": 5, "p001": 5}
    assert per_point["scene.camera_effects.dark_current_scale"].first().to_dict() == {"p000": 1.0, "p001": 2.0}
    assert per_point["config_hash"].nunique().eq(1).all() and results["config_hash"].nunique() == 2
    for _point_id, members in per_point:      # each point's rows are its campaign store's, under its hash
        store = out / "points" / members["config_hash"].iloc[0][:16]
        assert (store / "manifest.json").exists()
        assert sorted(members["case_id"]) == sorted(pd.read_parquet(store / "results.parquet")["case_id"])
    table = pd.read_csv(out / "sensitivity.csv")
    assert set(table["class"]) == {"gcp", "gdcp", "gkep", "Gusev"} and len(table) == 8
    for _, row in table[table["class"] == "gcp"].iterrows():   # % valid recounted from the case rows
        members = results[(results.point_id == row.point_id) & (results.class_name == "gcp")]
        assert row.pct_valid == pytest.approx(100.0 * members["valid"].sum() / len(members))
    assert "| point |" in (out / "sensitivity.md").read_text()


@pytest.mark.cluster
@pytest.mark.slow
def test_status_of_a_sweep_directory_counts_each_point(first_sweep, capsys):
    _, out = first_sweep
    assert main(["status", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines == ["p000 (scene.camera_effects.dark_current_scale=1): 5 planned, 5 done, 0 failed, 0 missing",
                     "p001 (scene.camera_effects.dark_current_scale=2): 5 planned, 5 done, 0 failed, 0 missing",
                     f"{out}: sweep of 2 points: 10 planned, 10 done, 0 failed, 0 missing"]
    description = (out / "sweep.json").read_bytes()        # a first sweep still running has no sweep.json yet:
    (out / "sweep.json").unlink()                           # its point stores (manifests) name the points
    try:
        assert main(["status", str(out)]) == 0
    finally:
        (out / "sweep.json").write_bytes(description)
    lines = capsys.readouterr().out.strip().splitlines()
    stores = sorted(path.name for path in (out / "points").iterdir() if path.is_dir())     # not the .lock files
    assert sorted(line.split(" (")[0] for line in lines[:2]) == [f"points/{name}" for name in stores]
    assert {line.split(" (", 1)[1] for line in lines[:2]} == {
        "scene.camera_effects.dark_current_scale=1): 5 planned, 5 done, 0 failed, 0 missing",
        "scene.camera_effects.dark_current_scale=2): 5 planned, 5 done, 0 failed, 0 missing"}
    assert lines[2] == f"{out}: sweep of 2 points: 10 planned, 10 done, 0 failed, 0 missing"


@pytest.mark.cluster
@pytest.mark.slow
def test_table_report_verify_and_status_take_a_sweep_directory(first_sweep, capsys):
    """Per point, or one point picked with --point; never "not a campaign directory" (issue 32)."""
    _, out = first_sweep
    assert main(["table", str(out)]) == 0
    text = capsys.readouterr().out
    assert max(len(line) for line in text.splitlines()) <= 120
    results = pd.read_parquet(out / "results.parquet")
    for (point_id, class_name), members in results.groupby(["point_id", "class_name"]):   # counts beside every %
        valid = int(members["valid"].sum())
        line = next(line for line in text.splitlines() if line.startswith(point_id + " "))
        assert f"{100 * valid / len(members):.1f}% ({valid}/{len(members)})" in line, (class_name, line)
    assert f"`campaign table {out} --point ID`" in text
    assert main(["table", str(out), "--point", "p001"]) == 0
    single = capsys.readouterr().out
    store = out / "points" / results.loc[results.point_id == "p001", "config_hash"].iloc[0][:16]
    assert single.startswith("Gusev: 5 of 5 cases finished") and (store / "table.md").is_file()
    assert main(["verify", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("p000 (scene.camera_effects.dark_current_scale=1): clean (5 case files")
    assert lines[-1] == f"{out}: sweep of 2 point stores: clean"
    assert main(["report", str(out), "--point", store.name]) == 0
    assert str(store / "report" / "report.md") in capsys.readouterr().out and (store / "report" / "report.md").is_file()
    assert main(["status", str(out), "--point", "p000"]) == 0
    assert "5 planned, 5 done, 0 failed, 0 missing" in capsys.readouterr().out
    assert main(["table", str(out), "--point", "p009"]) == 2
    stderr = capsys.readouterr().err
    assert "no point 'p009'; allowed: p000 (scene.camera_effects.dark_current_scale=1), p001" in stderr


@pytest.mark.cluster
@pytest.mark.slow
def test_plots_of_each_metric_against_each_axis(first_sweep):
    _, out = first_sweep
    for metric in ("pct_valid", "error_mean_3sigma_mps"):
        path = out / "plots" / f"{metric}-vs-scene.camera_effects.dark_current_scale.png"
        with Image.open(path) as image:
            assert image.format == "PNG" and image.size[0] > 300 and image.size[1] > 200


@pytest.mark.cluster
@pytest.mark.slow
def test_rerun_computes_nothing_and_a_changed_value_only_its_point(first_sweep, scheduler, capsys):
    path, out = first_sweep
    before = _case_files(out)
    code, stdout, _ = _run(capsys, path, "--output", out, "--scheduler", scheduler)
    assert code == 0 and "2 points, 2 reused; 0 cases done" in stdout
    assert "dask dashboard" not in stdout, stdout          # every point finished: no cluster connected
    assert _case_files(out) == before
    changed = _sweep_file(path.parent, '"scene.camera_effects.dark_current_scale" = [1.0, 3.0]', name="changed.toml")
    code, stdout, _ = _run(capsys, changed, "--output", out, "--scheduler", scheduler)
    assert code == 0 and "2 points, 1 reused; 5 cases done" in stdout and "dask dashboard" in stdout
    after = _case_files(out)
    assert {k: after[k] for k in before} == before and len(after) == len(before) + 5
    results = pd.read_parquet(out / "results.parquet")
    assert sorted(results["scene.camera_effects.dark_current_scale"].unique()) == [1.0, 3.0]
    lost = sorted(set(after) - set(before))[:2]   # as if a killed sweep had not written two cases yet
    for name in lost:
        (out / name).unlink()
    code, stdout, _ = _run(capsys, changed, "--output", out, "--scheduler", scheduler)
    assert code == 0 and "2 cases done" in stdout
    # the same cases (a recomputed case's file name, and its shard cases/<sha[:2]>, record the sha256 of its new
    # write, timings included)
    assert ({(p.parents[1], p.name.split(".")[0]) for p in _case_files(out)}
            == {(p.parents[1], p.name.split(".")[0]) for p in after})
    assert pd.read_parquet(out / "results.parquet").equals(results)


@pytest.mark.cluster
@pytest.mark.slow
def test_baseline_regression_exits_1_naming_the_point(first_sweep, scheduler, capsys, tmp_path):
    path, out = first_sweep
    code, stdout, _ = _run(capsys, path, "--output", out, "--scheduler", scheduler)   # every point kept: 0 cases
    assert code == 0 and "2 points, 2 reused; 0 cases done" in stdout
    code, stdout, _ = _run(capsys, path, "--output", out, "--scheduler", scheduler, "--baseline", out)
    assert code == 0 and _verdict(stdout).startswith("gate: PASS: no regression in ") and " in 2 points" in stdout
    # the same sweep on a campaign whose attitude sensor is 40 x noisier (2 deg per image, the estimator
    # budgets 0.3 deg 3 sigma): every point must lose valid cases or accuracy
    base = tmp_path / "sitedata" / "noisy.toml"
    base.parent.mkdir()
    for sub in ("cameras", "trajectories"):
        (base.parent / sub).symlink_to(REPO / "sitedata" / sub)
    base.write_text(GUSEV.read_text() + "\n[sensors]\nattitude_random_sigma_deg = 2.0\n")
    noisy = _sweep_file(tmp_path, '"scene.camera_effects.dark_current_scale" = [1.0, 2.0]', base=base,
                        extra="", name="noisy.toml")
    code, stdout, _ = _run(capsys, noisy, "--output", tmp_path / "out", "--scheduler", scheduler, "--baseline", out)
    assert code == 4, stdout            # a regression's own exit code (1: failed cases, a held lock)
    assert _verdict(stdout).startswith("gate: REGRESSION: ") and " of 2 points, " in _verdict(stdout)
    table = stdout[stdout.index(f"regressions against {out}:"):].splitlines()[1:]
    assert table[0].split() == ["point", "class", "estimator", "metric", "baseline", "candidate", "test", "why"]
    assert any("p000 (scene.camera_effects.dark_current_scale=1)" in line for line in table)
    assert any("p001 (scene.camera_effects.dark_current_scale=2)" in line for line in table)
    verdict = json.loads((tmp_path / "out" / "gate.json").read_text())
    assert verdict["verdict"] == "regression" and verdict["compared_points"] == 2
    assert verdict["regressions"] == sum(row["decision"] == "regression" for row in verdict["rows"]) == len(
        [line for line in table[1:] if line.startswith("p0")])


def _plugin_campaign(directory: Path, bias_east_mps: float) -> Path:
    """Gusev with one estimator, ``probe``: the IMU velocity minus a bias (tests/plugins/python_estimators.py)."""
    directory.mkdir(parents=True, exist_ok=True)
    for sub in ("cameras", "trajectories"):
        (directory / sub).symlink_to(REPO / "sitedata" / sub)
    path = directory / "gusev_probe.toml"
    path.write_text(GUSEV.read_text() + '\n[[estimators]]\nname = "probe"\nkind = "python"\n'
                    'callable = "plugins.python_estimators:imu_minus_bias"\n'
                    f'[estimators.parameters]\nbias = [{bias_east_mps}, 0.0]\n')
    return path


@pytest.mark.cluster
@pytest.mark.slow
def test_added_false_valid_cases_fail_the_gate_whatever_the_error_tolerance(tmp_path, scheduler, capsys):
    """Baseline: the IMU velocity, valid. An identical sweep into a fresh directory recomputes every case
    and passes; a candidate whose estimator is 30 m/s off (every valid case false-valid) fails with exit 1
    although its error tolerance (1000 m/s) forgives any growth."""
    axis, quick = '"scene.camera_effects.dark_current_scale" = [1.0]', ("--cases-scale", 0.3)   # gcp 3 -> 1, gdcp 2 -> 1
    honest = _sweep_file(tmp_path / "honest", axis, base=_plugin_campaign(tmp_path / "honest", 0.0))
    code, stdout, _ = _run(capsys, honest, "--output", tmp_path / "baseline", "--scheduler", scheduler, *quick)
    assert code == 0 and "cases per point {'gcp': 1, 'gdcp': 1, 'gkep': 0}" in stdout, stdout
    code, stdout, _ = _run(capsys, honest, "--output", tmp_path / "again", "--scheduler", scheduler, *quick,
                           "--baseline", tmp_path / "baseline")
    assert code == 0 and "1 points, 0 reused; 2 cases done" in stdout, stdout
    assert _verdict(stdout).startswith("gate: PASS: no regression in ") and f"against {tmp_path / 'baseline'}" in stdout
    biased = _sweep_file(tmp_path / "biased", axis, base=_plugin_campaign(tmp_path / "biased", 30.0),
                         extra="[tolerances]\nerror_increase_mps = 1000.0")
    code, stdout, _ = _run(capsys, biased, "--output", tmp_path / "candidate", "--scheduler", scheduler, *quick,
                           "--baseline", tmp_path / "baseline")
    assert code == 4, stdout
    baseline = pd.read_parquet(tmp_path / "baseline" / "results.parquet")
    expected = {name: int((members["valid"] & (members["velocity_error_mps"] > 5.0)).sum())
                for name, members in baseline.groupby("class_name")}
    table = stdout[stdout.index("regressions against"):].splitlines()
    rows = [line for line in table[2:] if line.startswith("p0")]        # heading, column names, rows, counts
    assert len(rows) == 3 and all(" probe " in row and " false-valid " in row for row in rows), table
    assert {row.split(" probe ")[0].split(")")[-1].strip() for row in rows} == {"gcp", "gdcp", "Gusev weighted"}
    for name, count in (("gcp", 1), ("gdcp", 1)):               # every valid case is now false-valid
        assert any(f" {name} " in row and f" {expected[name]} of {count} valid  {count} of {count} valid " in row
                   for row in rows), table
    assert _verdict(stdout).startswith("gate: REGRESSION: 3 of ") and "in 1 of 1 points" in _verdict(stdout)


# --- issue 7, done when: the estimator degrades with lens dust and with the angular rate multiplier ----
@pytest.mark.cluster
@pytest.mark.slow
def test_estimator_degrades_with_dust_and_rate_multiplier(tmp_path, scheduler, capsys):
    """Nominal vs 300 dust particles (their shadows cover much of the frame) and vs 100x angular rates
    (tens of pixels of blur in 5.1 ms): each must lose >= 30 points of % valid or gain >= 1 m/s of error."""
    path = tmp_path / "effects.toml"
    path.write_text(f'''[sweep]
base = "{GUSEV}"
mode = "list"
[sweep.cases]
gcp = 6
gdcp = 0
gkep = 0
[axes]
"scene.off_nominal.dust_particle_count" = [0, 300, 0]
"scene.off_nominal.angular_rate_multiplier" = [1.0, 1.0, 100.0]
''')
    out = tmp_path / "out"
    code, stdout, _ = _run(capsys, path, "--output", out, "--scheduler", scheduler)
    assert code == 0, stdout
    table = pd.read_csv(out / "sensitivity.csv").set_index(["point_id", "class"])
    nominal, dusty, blurred = (table.loc[(point, "gcp")] for point in ("p000", "p001", "p002"))
    for label, degraded in (("dust", dusty), ("rate multiplier", blurred)):
        drop = nominal["pct_valid"] - degraded["pct_valid"]
        rise = degraded["error_mean_3sigma_mps"] - nominal["error_mean_3sigma_mps"]
        assert drop >= 30.0 or rise >= 1.0, f"{label}: % valid {nominal['pct_valid']} -> {degraded['pct_valid']}, " \
                                             f"error {nominal['error_mean_3sigma_mps']} -> {degraded['error_mean_3sigma_mps']}"
    for metric in ("pct_valid", "error_mean_3sigma_mps"):
        for axis in ("dust_particle_count", "angular_rate_multiplier"):
            assert (out / "plots" / f"{metric}-vs-scene.off_nominal.{axis}.png").is_file()
