"""Cases run in batched tasks with a bounded window in flight, and the no-op case mode: the scheduler sees
far fewer tasks than cases and never more than the window at once, the driver keeps no future after a
run, and a no-op campaign writes schema-valid rows through the real store that cannot be mistaken for
results (its own configuration hash, ``reason = "no_op"``, a banner on ``table`` and ``report``)."""
from __future__ import annotations

import contextlib
import io
import json
import math

import pandas as pd
import pyarrow.parquet as pq
import pytest
from distributed.diagnostics.plugin import SchedulerPlugin

from campaign.cli import main
from campaign.configuration.campaign_file import load_campaign_config
from campaign.configuration.execution import NO_OP_BANNER, ExecutionConfig
from campaign.run.dask_runner import IN_FLIGHT_PER_WORKER, MAX_CASES_PER_TASK, MIN_IN_FLIGHT, cases_per_task
from campaign.run.planning import plan_campaign
from campaign.store.result_schema import CASE_FILE_SCHEMA, RESULTS_SCHEMA
from config_tables.models import parse
from service_campaigns import campaign_file


def _execution(**fields) -> ExecutionConfig:
    return parse(ExecutionConfig, fields, "campaign.toml", prefix="execution")


@pytest.mark.parametrize("cases, workers, mode", [(10**5, 8, "no_op"), (10**6, 8, "no_op"), (10**6, 64, "no_op"),
                                                  (10**6, 8, "compute"), (38, 2, "compute")])
def test_tasks_are_batches_far_fewer_than_cases(cases, workers, mode):
    size = cases_per_task(cases, workers, _execution(case_mode=mode))
    tasks = math.ceil(cases / size)
    assert 1 <= size <= MAX_CASES_PER_TASK[mode]
    # every worker has several tasks (the last ones short next to the run), unless the cap bounds the size
    assert tasks >= min(cases, 4 * workers) or size == MAX_CASES_PER_TASK[mode]
    if cases >= 10**5:
        assert tasks <= cases / MAX_CASES_PER_TASK["compute"]      # the cap: computed tasks that large at 10^5+
    if cases >= 10**5 and mode == "no_op":
        assert tasks <= cases / 100


def test_cases_per_task_of_the_execution_table_wins():
    assert cases_per_task(10**5, 8, _execution(cases_per_task=7)) == 7
    assert cases_per_task(3, 8, _execution()) == 1


def test_no_op_mode_has_its_own_configuration_hash_and_other_execution_fields_none(tmp_path):
    compute = load_campaign_config(campaign_file(tmp_path / "a", execution="workers = 1"))
    other_execution = load_campaign_config(campaign_file(tmp_path / "b", execution="workers = 2\ncases_per_task = 5"))
    no_op = load_campaign_config(campaign_file(tmp_path / "c", execution='case_mode = "no_op"'))
    assert compute.config_hash == other_execution.config_hash
    assert no_op.config_hash != compute.config_hash


def _cli(*args) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = main([str(arg) for arg in args])
    return code, out.getvalue()


class WindowWatch(SchedulerPlugin):
    """A scheduler plug-in (the embedded scheduler runs in this process): the most tasks the scheduler held
    at once, and how many ``cases`` tasks it saw."""

    name = "window-watch"

    def __init__(self) -> None:
        super().__init__()
        self.most = 0
        self.keys: set = set()

    def transition(self, key, start, finish, *args, **kwargs) -> None:
        if str(key).startswith("cases-"):
            self.keys.add(key)

    def update_graph(self, scheduler, *args, **kwargs) -> None:
        self.most = max(self.most, sum(1 for key in scheduler.tasks if str(key).startswith("cases-")))


@pytest.mark.cluster
@pytest.mark.slow
def test_no_op_campaign_is_batched_windowed_and_marked_everywhere(tmp_path):
    from campaign.run import orchestrate
    from campaign.run.cluster import connected_client

    cases = {"gcp": 600, "gdcp": 300, "gkep": 100}
    path = campaign_file(tmp_path, cases=cases, execution='case_mode = "no_op"\nworkers = 2\ncases_per_task = 10')
    out = tmp_path / "out"
    config = load_campaign_config(path, output_dir=out)
    watch = WindowWatch()
    _, plan = plan_campaign(config)
    with connected_client(config.execution, quiet=True) as client:
        client.cluster.scheduler.add_plugin(watch)         # this very object: the scheduler runs in this process
        summary_before = len(client.futures)
        point = orchestrate.StorePoint(config, orchestrate.manifest_for(config), plan)
        run = orchestrate.run_store_points([point], config.execution, client=client, progress=False)
        assert len(client.futures) == summary_before == 0          # no future left in the driver
    total = sum(cases.values())
    assert run.done == total and run.failed == 0
    assert len(watch.keys) == total // 10                          # one task per 10 cases
    # the window (plus tasks released by the driver that the scheduler has not forgotten yet), never the run
    window = max(MIN_IN_FLIGHT, IN_FLIGHT_PER_WORKER * 2)
    assert watch.most <= 2 * window < len(watch.keys)

    # the rows: every declared column, one per case, status ok, invalid, reason no_op, no truth
    results = pq.read_table(out / "results.parquet")
    assert results.schema.names == RESULTS_SCHEMA.names
    frame = results.to_pandas()
    assert sorted(frame["case_id"]) == sorted(plan["case_id"]) and frame["case_id"].is_unique
    assert set(frame["status"]) == {"ok"} and set(frame["reason"]) == {"no_op"} and not frame["valid"].any()
    assert frame["truth_velocity_east_mps"].isna().all() and frame["estimate_velocity_east_mps"].isna().all()
    timings = pd.read_parquet(out / "timings.parquet")
    assert set(timings.columns) <= set(CASE_FILE_SCHEMA.names)
    # the manifest records the mode; table and report say it first
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["execution"]["case_mode"] == "no_op"
    code, table = _cli("table", out)
    assert code == 0 and table.splitlines()[0] == NO_OP_BANNER, table
    assert (out / "table.md").read_text().splitlines()[0] == NO_OP_BANNER
    code, text = _cli("report", out)
    assert code == 0, text
    report = (out / "report" / "report.md").read_text()
    assert NO_OP_BANNER in report.split("##")[0]

    # a real campaign of the same file is another configuration: the no-op store is refused, not resumed
    real = campaign_file(tmp_path / "real", cases=cases, execution="workers = 2")
    code, text = _cli("submit", real, "--output", out, "--no-progress")
    assert code != 0 and "another configuration" in text, text
    # the no-op campaign again: nothing left to run
    code, text = _cli("submit", path, "--output", out, "--no-progress")
    assert code == 0 and "(0 done, 0 failed this run)" in text, text


@pytest.mark.cluster
@pytest.mark.slow
def test_a_worker_killed_mid_batch_keeps_its_written_cases_and_the_rerun_duplicates_nothing(tmp_path):
    """One task of 60000 no-op cases writes its cases in batches of ``FLUSH_CASES``; after the first, its
    worker process is killed: dask reruns the task on a worker, the cases written before stay, the rerun's own write
    of them supersedes them, and the store counts every case once. Slow by design (about 60 s in a loaded suite
    run): its own scheduler and worker processes, one of them killed mid-task."""
    import os
    import signal
    import subprocess
    import time

    import pyarrow.dataset as ds

    from campaign.run.worker import FLUSH_CASES
    from campaign.store.campaign_store import CampaignStore
    from service_campaigns import REPO, DaskProcesses, campaign_command

    cases = {"gcp": 30000, "gdcp": 20000, "gkep": 10000}
    total = sum(cases.values())
    processes = DaskProcesses(tmp_path, workers=2)
    try:
        processes.import_case_code()
        path = campaign_file(tmp_path, cases=cases,
                             execution=f'case_mode = "no_op"\ncases_per_task = {total}\nscheduler = "{processes.address}"')
        out = tmp_path / "out"
        submit = subprocess.Popen(campaign_command("submit", path, "--output", out, "--no-progress"), cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started = time.monotonic()
        first: list = []
        while not first and submit.poll() is None and time.monotonic() - started < 300:
            time.sleep(0.1)
            first = sorted((out / "cases").glob("*/batch-*.parquet")) if (out / "cases").is_dir() else []
        assert first, submit.communicate()
        written = pq.read_table(first[0], columns=["case_id", "worker"])
        assert written.num_rows == FLUSH_CASES < total       # a part of the task
        assert set(written.column("worker").to_pylist()) == {written.column("worker")[0].as_py()}
        worker_pid = int(written.column("worker")[0].as_py().rsplit(":", 1)[1])
        os.kill(worker_pid, signal.SIGKILL)                  # the worker process running the task
        stdout, stderr = submit.communicate(timeout=600)
        assert submit.returncode == 0, stderr
        assert f"({total} done, 0 failed this run)" in stdout
    finally:
        processes.close()
    status = CampaignStore(out).status()
    assert (status.done, status.failed, status.missing) == (total, 0, 0)
    case_ids = ds.dataset(out / "results.parquet", format="parquet").to_table(columns=["case_id"]).column("case_id")
    assert sorted(case_ids.to_pylist()) == sorted(CampaignStore(out).plan()["case_id"].tolist())
    # the cases of the killed worker's first write were written again by the rerun, which counts
    timings = ds.dataset(out / "timings.parquet", format="parquet").to_table(columns=["case_id", "worker"]).to_pandas()
    first_cases = timings[timings["case_id"].isin(set(written.column("case_id").to_pylist()))]
    assert len(first_cases) == FLUSH_CASES
    assert not first_cases["worker"].str.endswith(f":{worker_pid}").any()
