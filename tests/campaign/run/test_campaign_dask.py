"""The campaign service with real parts: dask LocalCluster, `dask scheduler` / `dask worker`
processes on loopback, real Parquet stores; killing workers and the driver loses and duplicates nothing.

Commands whose process is not under test (the reference runs, reruns, status and table) run as
``campaign.cli.main`` in this process: the same exit code, stdout and files as a `campaign` process, without
an interpreter start, imports and code digest each; the driver that is killed, the submit on the external
cluster and the refused submit (its whole stderr is one line) are `campaign` processes."""
from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from campaign.cli import main
from campaign.store.campaign_store import CampaignStore
from service_campaigns import scheduler_address, site_copy

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[3]
SITE = REPO / "sitedata" / "gusev.toml"
SCALE = "0.03"  # gcp 6, gdcp 3, gkep 2 cases



def _campaign(*args, timeout=600, check=True):
    return subprocess.run([sys.executable, "-m", "campaign.cli", *args], capture_output=True, text=True,
                          timeout=timeout, check=check, cwd=REPO)


def _in_process(*args) -> str:
    """``campaign ARGS`` as ``campaign.cli.main`` in this process, asserted to exit 0; returns its stdout."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(arg) for arg in args])
    assert code == 0, out.getvalue() + err.getvalue()
    return out.getvalue()


def _submit_args(out: Path, *extra):
    return ["submit", str(SITE), "--output", str(out), "--cases-scale", SCALE, "--no-progress", *extra]


def _results(out: Path) -> pd.DataFrame:
    return pq.read_table(out / "results.parquet").to_pandas()


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("reference")
    stdout = _in_process(*_submit_args(out, "--workers", "2"))
    assert "wall time" in stdout and "Gusev" in stdout, stdout
    return out


def test_reference_run_is_complete_and_printed(reference_run):
    results = _results(reference_run)
    plan = CampaignStore(reference_run).plan()
    assert sorted(results["case_id"]) == sorted(plan["case_id"])
    assert results["case_id"].is_unique
    assert set(results["status"]) <= {"ok", "failed"}
    status = _in_process("status", reference_run)
    assert f"{len(plan)} planned, {int((results.status == 'ok').sum())} done" in status
    table = _in_process("table", reference_run)
    assert "gcp" in table and "weighted" in table           # class rows and the ellipse-weighted site row
    assert (reference_run / "table.md").exists() and (reference_run / "table.csv").exists()


def test_one_worker_gives_the_same_bits(reference_run, tmp_path):
    _in_process(*_submit_args(tmp_path, "--workers", "1"))
    pd.testing.assert_frame_equal(_results(tmp_path), _results(reference_run), check_exact=True)


def test_rerun_runs_nothing_and_changed_config_is_refused(reference_run, tmp_path):
    before = {p.name: p.stat().st_mtime_ns for p in (reference_run / "cases").iterdir()}
    rerun = _in_process(*_submit_args(reference_run, "--workers", "1"))
    assert "(0 done, 0 failed this run)" in rerun
    assert "no cluster started" in rerun and "dask dashboard" not in rerun      # nothing to run: no cluster
    assert {p.name: p.stat().st_mtime_ns for p in (reference_run / "cases").iterdir()} == before
    other_seed = site_copy(tmp_path, "\n[campaign]\nseed = 2\n")
    changed = _campaign("submit", str(other_seed), "--output", str(reference_run), "--cases-scale", SCALE,
                        "--no-progress", check=False)
    assert changed.returncode == 2 and "another configuration" in changed.stderr
    assert len(changed.stderr.strip().splitlines()) == 1


def _wait_for_cases(out: Path, count: int, process: subprocess.Popen, limit_s: float = 300.0) -> None:
    deadline = time.time() + limit_s
    while time.time() < deadline:
        # cases written (one estimator: one row each) in the batch files of the worker tasks
        done = sum(pq.read_metadata(path).num_rows for path in (out / "cases").glob("*/batch-*.parquet"))
        if done >= count:
            return
        if process.poll() is not None:
            raise AssertionError(f"campaign ended early: {process.returncode}")
        time.sleep(0.2)
    raise AssertionError("timed out waiting for cases")


def test_killed_driver_then_rerun_equals_uninterrupted_run(reference_run, tmp_path):
    """Slow by design (over 60 s in a loaded suite run): a `campaign submit` process with its own two-worker
    cluster is killed mid-run (SIGKILL to its process group), then rerun; the killed driver and its cluster
    are what is tested."""
    process = subprocess.Popen([sys.executable, "-m", "campaign.cli", *_submit_args(tmp_path, "--workers", "2")],
                               cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_for_cases(tmp_path, 3, process)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the driver and its embedded cluster
        process.wait()
    partial = CampaignStore(tmp_path).status()
    assert partial.done + partial.failed < partial.planned, "the kill came too late to test resuming"
    rerun = _in_process(*_submit_args(tmp_path, "--workers", "2"))
    assert f"({partial.missing} done, 0 failed this run)" in rerun or "failed this run" in rerun
    pd.testing.assert_frame_equal(_results(tmp_path), _results(reference_run), check_exact=True)


@pytest.fixture()
def dask_cluster(tmp_path):
    """A real `dask scheduler` and two `dask worker` processes on loopback."""
    scheduler_file = tmp_path / "scheduler.json"
    dask_bin = Path(sys.executable).with_name("dask")
    command = [str(dask_bin)] if dask_bin.exists() else [sys.executable, "-m", "distributed.cli.dask_spec"]
    scheduler = subprocess.Popen([*command, "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(scheduler_file)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    address = scheduler_address(scheduler_file)
    workers = [subprocess.Popen([*command, "worker", address, "--nthreads", "1", "--nworkers", "1",
                                 "--host", "127.0.0.1", "--no-dashboard", "--memory-limit", "1.5GiB"],
                                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
               for _ in range(2)]
    from dask.distributed import Client

    with Client(address, timeout="30s") as client:
        client.wait_for_workers(2, timeout=60)
    yield address, workers
    for process in [*workers, scheduler]:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait()


def test_external_cluster_survives_a_killed_worker(reference_run, tmp_path, dask_cluster):
    """Slow by design (over 60 s in a loaded suite run): a `campaign submit` process on its own external
    scheduler and workers, one worker killed mid-run; the killed worker is what is tested, so the cluster
    cannot be a shared one."""
    address, workers = dask_cluster
    out = tmp_path / "external"
    process = subprocess.Popen([sys.executable, "-m", "campaign.cli", *_submit_args(out, "--scheduler", address)],
                               cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_cases(out, 2, process)
    os.killpg(workers[0].pid, signal.SIGKILL)   # a worker dies mid-run
    stdout, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr
    assert "wall time" in stdout
    results = _results(out)
    assert results["case_id"].is_unique
    pd.testing.assert_frame_equal(results, _results(reference_run), check_exact=True)
    assert CampaignStore(out).status().done == len(results)
