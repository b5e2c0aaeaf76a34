"""Failure is loud, and no stored value breaks an output (issue 20), on a real store: a command estimator
answering ``"valid": "yes"`` beside the reference makes `campaign submit` exit 1 with one stderr line naming
it, its count and its reason, and the table counts its failed rows; then the store's rows are rewritten
through the store's own writer with extreme values (1e30, inf, NaN, negative uncertainty, an empty class)
and `campaign table` and `campaign report` still exit 0 without a traceback.

The submit is a `campaign` process; table and report are ``campaign.cli.main`` in this process with its
file descriptors captured (``service_campaigns.campaign_in_process``: no interpreter start and imports each)."""
from __future__ import annotations

import math
import shutil

import pandas as pd
import pytest

from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import write_case_rows
from service_campaigns import campaign_in_process, campaign_with_command_estimator, run_campaign

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

YES_ESTIMATOR = '''import json, sys
json.dump({"velocity_east_mps": 1.0, "velocity_north_mps": 0.0, "valid": "yes", "reason": "ok"},
          open(sys.argv[1], "w"))
'''


@pytest.fixture(scope="module")
def yes_store(tmp_path_factory):
    """A submitted Gusev campaign of 3 cases (gcp 2, gdcp 1, gkep 0) with the reference and `yes_man`."""
    directory = tmp_path_factory.mktemp("loud")
    config = campaign_with_command_estimator(directory, "yes_man", YES_ESTIMATOR)
    out = directory / "out"
    return out, run_campaign("submit", config, "--output", out, "--no-progress")


def test_failing_command_estimator_exits_1_with_one_stderr_line_and_counts_in_the_table(yes_store, capfd):
    out, submit = yes_store
    assert submit.returncode == 1, submit.stdout + submit.stderr
    assert "Traceback" not in submit.stderr
    lines = [line for line in submit.stderr.splitlines() if "estimator" in line]
    assert len(lines) == 2, submit.stderr             # the estimator's count, then its one kind of failure
    assert lines[0].startswith("campaign: estimator yes_man: 3 of 3 rows failed, 1 kind ")
    assert lines[1].startswith("campaign:   3 x contract violation, e.g. case ")
    assert "'valid'" in lines[1] and "yes" in lines[1], lines[1]
    assert "estimator rows: dimes " in submit.stdout and "yes_man 0 valid, 0 invalid, 3 failed" in submit.stdout
    assert "failed this run); estimator rows failed: yes_man 3 (every kind on stderr)" in submit.stdout
    results = pd.read_parquet(out / "results.parquet")
    assert set(results.loc[results["estimator"] == "dimes", "status"]) == {"ok"}
    table = campaign_in_process(capfd, "table", out)
    assert table.returncode == 0 and "yes_man 0 valid, 0 invalid, 3 failed" in table.stdout
    section = table.stdout.split("estimator yes_man:")[1].split("estimators side by side:")[0]
    site_row = [line for line in section.splitlines() if line.strip().startswith("Gusev")][0]
    assert site_row.split()[1:4] == ["3", "0", "3"], site_row      # cases, valid, failed
    assert "% valid = valid / (cases - failed)" in table.stdout
    csv = pd.read_csv(out / "table.csv")
    assert csv.loc[(csv["estimator"] == "yes_man") & (csv["class"] == "gcp"), "failed"].item() == 2
    assert "yes_man 0 valid, 0 invalid, 3 failed" in (out / "table.md").read_text()


EXTREMES = [  # (valid, velocity error, uncertainty, estimate east) per row of the rewritten store
    (True, 1e30, 1e30, 1e30), (True, math.inf, -1.0, math.inf), (True, math.nan, math.nan, math.nan),
    (True, 1e30, -5.0, -1e30), (False, math.nan, 0.0, math.nan), (True, 1.0 + 1e-15, 0.5, -math.inf),
]


def test_table_and_report_survive_extreme_stored_values(yes_store, tmp_path, capfd):
    source, _ = yes_store
    out = tmp_path / "extreme"
    shutil.copytree(source, out)
    store = CampaignStore(out)
    extremes = iter(EXTREMES * 2)
    for case_id in sorted(store.finished_case_ids()):
        rows = store.read_case_table(case_ids=[case_id]).to_pylist()
        for row in rows:             # both estimators' rows made ok and valid with extreme numbers
            valid, error, uncertainty, east = next(extremes)
            row.update(status="ok", error="", valid=valid, reason="ok" if valid else "too_few_features",
                       velocity_error_mps=error, velocity_uncertainty_mps=uncertainty,
                       estimate_velocity_east_mps=east, estimate_velocity_north_mps=-east)
        write_case_rows(store.cases_dir, case_id, rows, ok=True)
    store.compact()
    table = campaign_in_process(capfd, "table", out)
    assert table.returncode == 0 and "Traceback" not in table.stderr, table.stderr
    assert "dimes 2 valid, 1 invalid, 0 failed; yes_man 3 valid, 0 invalid, 0 failed" in table.stdout
    assert "1e+30" in table.stdout and "inf" in table.stdout
    report = campaign_in_process(capfd, "report", out)
    assert report.returncode == 0 and "Traceback" not in report.stderr, report.stderr
    text = (out / "report" / "report.md").read_text()
    assert "False-valid cases" in text and (out / "report" / "error_histograms-dimes.png").exists()
