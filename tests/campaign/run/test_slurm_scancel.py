"""A no-op campaign on a real single-node SLURM cluster (tests/slurm_node.py) with three one-core worker jobs,
one of them cancelled with ``scancel`` while cases run: the run finishes on the other jobs (or stops
with one line), nothing is lost or duplicated, and a resumed submit completes it. The 10^5-case version
of this run, with its figures, is in docs/scaling.md."""
from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pyarrow.dataset as ds
import pytest
from slurm_node import SlurmNode, install_reason

from campaign.store.campaign_store import CampaignStore
from service_campaigns import REPO, campaign_command, campaign_file, stderr_line

pytestmark = [pytest.mark.cluster, pytest.mark.slurm, pytest.mark.slow]

# 600 no-op cases of one case per task: the job is cancelled once 20 case files are written, with over 500 tasks
# (seconds of work for the other jobs even on an idle machine) still to run
CASES = {"gcp": 300, "gdcp": 180, "gkep": 120}
JOBS = 3          # on a 2-CPU node two run at a time; the third starts when one ends


@pytest.fixture(scope="module")
def slurm():
    reason = install_reason()
    if reason:
        pytest.skip(f"no SLURM cluster for the tests: {reason}")
    node = SlurmNode()
    yield node
    node.stop()


def _execution(tmp_path: Path) -> str:
    settings = {"queue": SlurmNode.partition, "cores": 1, "memory": "1500MiB", "jobs": JOBS, "interface": "lo",
                "walltime": "00:20:00", "job_extra": [f"--output={tmp_path}/slurm-%j.out"]}
    lines = [f"{key} = {json.dumps(value)}" for key, value in settings.items()]
    # one case per task: 600 tasks, so that the run lasts long enough to cancel a job in the middle of it
    return ('case_mode = "no_op"\ncases_per_task = 1\ncluster = "slurm"\nno_workers_timeout_s = 120\n'
            "[execution.slurm]\n" + "\n".join(lines))


def _written_cases(out: Path) -> int:
    cases = out / "cases"
    return sum(1 for _ in cases.glob("*/*.parquet")) if cases.is_dir() else 0


def test_a_cancelled_worker_job_loses_and_duplicates_nothing_and_resume_completes(slurm, tmp_path):
    """Slow by design (over 60 s in a loaded suite run): a `campaign submit` process whose worker jobs run on the
    private SLURM node, one of them cancelled with scancel mid-run, then the resume; the batch jobs and the
    cancelled one are what is tested."""
    config = campaign_file(tmp_path, cases=CASES, execution=_execution(tmp_path))
    out = tmp_path / "out"
    environment = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONUNBUFFERED": "1", **slurm.environment}
    stdout_path = tmp_path / "submit.out"
    with stdout_path.open("w") as stdout, (tmp_path / "submit.err").open("w") as stderr:
        process = subprocess.Popen(campaign_command("submit", config, "--output", out, "--no-progress"), stdout=stdout,
                                   stderr=stderr, cwd=tmp_path, env=environment)
    cancelled, written_at_cancel, cancelled_at = None, 0, 0.0
    deadline = time.monotonic() + 600
    while process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
        if cancelled is None and _written_cases(out) >= 20:
            jobs = [line.removeprefix("slurm jobs: ").split(", ") for line in stdout_path.read_text().splitlines()
                    if line.startswith("slurm jobs: ")]
            states = slurm.jobs()
            running = [job for job in (jobs[0] if jobs else []) if states.get(job, ("", "", ""))[1] == "RUNNING"]
            if running:
                cancelled, written_at_cancel, cancelled_at = running[0], _written_cases(out), time.monotonic()
                slurm.run("scancel", cancelled)
    process.wait(timeout=max(1.0, deadline - time.monotonic()))
    run_after_cancel_s = time.monotonic() - cancelled_at
    total = sum(CASES.values())
    assert cancelled is not None, stdout_path.read_text()
    assert written_at_cancel < total                     # the job was cancelled in the middle of the run
    assert slurm.jobs()[cancelled][1] == "CANCELLED"
    if process.returncode != 0:                          # stopped: one line, then the next submit runs the rest
        result = subprocess.CompletedProcess(process.args, process.returncode, stdout_path.read_text(),
                                             (tmp_path / "submit.err").read_text())
        line = stderr_line(result)
        assert "left for the next submit" in line, line
    status = CampaignStore(out).status()
    assert status.failed == 0 and status.done + status.missing == total
    left = status.missing
    resume = subprocess.run(campaign_command("submit", config, "--output", out, "--no-progress"), capture_output=True,
                            text=True, timeout=600, cwd=tmp_path, env=environment)
    assert resume.returncode == 0, resume.stderr
    assert f"({left} done, 0 failed this run)" in resume.stdout, resume.stdout
    status = CampaignStore(out).status()
    assert (status.done, status.failed, status.missing) == (total, 0, 0)
    results = ds.dataset(out / "results.parquet", format="parquet").to_table(columns=["case_id", "reason"])
    case_ids = results.column("case_id").to_pylist()
    planned = CampaignStore(out).plan()["case_id"].tolist()
    assert sorted(case_ids) == sorted(planned)           # every case once: none lost, none twice
    assert set(results.column("reason").to_pylist()) == {"no_op"}
    print(f"\nscancel {cancelled} with {written_at_cancel} of {total} case files written; first submit exit "
          f"{process.returncode} {run_after_cancel_s:.1f} s later, resume ran {left} cases")
