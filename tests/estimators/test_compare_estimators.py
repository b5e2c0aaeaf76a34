"""Several estimators in one campaign, with real parts (dask LocalCluster worker processes, Parquet
stores): the shipped example runs both estimators on every case, resumes, and `campaign table` prints
both; with one worker and two more estimators (one failing) the failing plugin's rows are failed with
its error while the example's estimators' rows are bit for bit those of the two-worker run (render
once, estimate N times: neither the worker count nor an added estimator changes them).

The runs are `campaign` processes; the rerun and the tables are ``campaign.cli.main`` in this process with
its file descriptors captured (``service_campaigns.campaign_in_process``: no interpreter start, imports and
code digest for each). The example's two-worker run and its rerun use the test process's warm two-worker cluster
(``warm_scheduler``, tests/conftest.py); the one-worker run starts its own."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from service_campaigns import campaign_in_process

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "sitedata" / "examples" / "compare_estimators.toml"
PLUGINS = Path(__file__).resolve().parents[1] / "plugins"
SCALE = "0.005"         # one case per class: gcp, gdcp, gkep


def _campaign(*args, env=None, check=True):
    return subprocess.run([sys.executable, "-m", "campaign.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=900, check=check, cwd=REPO, env=env)


@pytest.fixture(scope="module")
def example_run(tmp_path_factory, warm_scheduler):
    out = tmp_path_factory.mktemp("compare2")
    result = _campaign("submit", EXAMPLE, "--output", out, "--cases-scale", SCALE, "--scheduler", warm_scheduler,
                       "--no-progress")
    assert "phase_correlation" in result.stdout, result.stdout + result.stderr
    return out


def test_example_has_both_estimators_for_every_case_and_table_prints_both(example_run, capfd):
    results = pd.read_parquet(example_run / "results.parquet")
    per_case = results.groupby("case_id")["estimator"].apply(list)
    assert len(per_case) == 3 and all(names == ["dimes", "phase_correlation"] for names in per_case)
    assert set(results["status"]) == {"ok"}
    timings = pd.read_parquet(example_run / "timings.parquet")
    assert list(timings.columns[:2]) == ["case_id", "estimator"] and len(timings) == len(results)
    table = campaign_in_process(capfd, "table", example_run).stdout
    assert "estimator dimes:" in table and "estimator phase_correlation:" in table
    side_by_side = table.split("estimators side by side:")[1]      # estimator names head their column groups
    assert "dimes (worst, err: m/s)" in side_by_side and "phase_correlation (worst, err: m/s)" in side_by_side
    assert side_by_side.splitlines()[2].split().count("false-valid") == 2
    csv = pd.read_csv(example_run / "table.csv")
    assert set(csv["estimator"]) == {"dimes", "phase_correlation"} and "false_valid" in csv.columns


def test_example_rerun_resumes_with_nothing_to_do(example_run, capfd, warm_scheduler):
    rerun = campaign_in_process(capfd, "submit", EXAMPLE, "--output", example_run, "--cases-scale", SCALE,
                                "--scheduler", warm_scheduler, "--no-progress")
    assert rerun.returncode == 0 and "(0 done, 0 failed this run)" in rerun.stdout, rerun.stdout + rerun.stderr


def test_failing_plugin_is_recorded_and_the_other_estimators_rows_are_unchanged(example_run, tmp_path, capfd):
    """One worker, four estimators (two of the example, a failing command, a Python callable) against the
    example's two workers: the example's estimators' rows are the same bits (worker count and added
    estimators change nothing)."""
    script = PLUGINS / "command_estimator.py"
    config = tmp_path / "three.toml"
    text = EXAMPLE.read_text().replace('"../cameras/', f'"{REPO}/sitedata/cameras/').replace(
        '"../trajectories/', f'"{REPO}/sitedata/trajectories/')
    config.write_text(text + f'''
[[estimators]]
name = "broken_flight_code"
kind = "command"
argv = ["{{python}}", "{script}", "exit", "{{measurements}}", "{{flat_field}}", "{{parameters}}", "{{output}}", "{{images}}"]
timeout_s = 60

[[estimators]]
name = "imu_only"
kind = "python"
callable = "python_estimators:imu_minus_bias"
''')
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(PLUGINS), str(REPO), os.environ.get("PYTHONPATH")]))}
    submit = _campaign("submit", config, "--output", tmp_path / "out", "--cases-scale", SCALE, "--workers", 1,
                       "--no-progress", env=env, check=False)
    assert submit.returncode == 1, submit.stdout + submit.stderr          # a failed estimator row is loud
    assert "campaign: estimator broken_flight_code: 3 of 3 rows failed, 1 kind " in submit.stderr
    assert "campaign:   3 x exit status 3, e.g. case 0: estimator broken_flight_code: exit status 3" in submit.stderr
    results = pd.read_parquet(tmp_path / "out" / "results.parquet")
    assert results.groupby("case_id")["estimator"].apply(list).map(len).eq(4).all()
    broken = results[results["estimator"] == "broken_flight_code"]
    assert set(broken["status"]) == {"failed"} and set(broken["reason"]) == {"estimator_failed"}
    assert broken["error"].str.contains("exit status 3: flight estimator: cannot lock the camera model").all()
    imu = results[results["estimator"] == "imu_only"]
    assert set(imu["status"]) == {"ok"} and imu["valid"].all()
    first = pd.read_parquet(example_run / "results.parquet")
    for name in ("dimes", "phase_correlation"):
        kept = results[results["estimator"] == name].reset_index(drop=True)
        alone = first[first["estimator"] == name].reset_index(drop=True)
        pd.testing.assert_frame_equal(kept[alone.columns], alone, check_exact=True)
    table = campaign_in_process(capfd, "table", tmp_path / "out").stdout
    assert "broken_flight_code" in table and "imu_only" in table
