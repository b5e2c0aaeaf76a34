"""What the runner costs per case, apart from the cases: ``orchestration/<cluster>`` rows.

A no-op campaign (``[execution] case_mode = "no_op"``: nothing rendered or estimated, every case still
planned, dispatched in batched tasks and written through the real store by the workers) of
``BENCH_ORCHESTRATION_CASES`` cases (default 10^5: Gusev's classes in its proportions) runs

- ``orchestration/embedded``: on the embedded LocalCluster (:data:`EMBEDDED_WORKERS` worker processes; its
  scheduler lives in the driver process),
- ``orchestration/scheduler``: on a real ``dask scheduler`` process with :data:`EXTERNAL_WORKERS` ``dask
  worker`` processes (one thread each) on loopback: 8 as the issue asks, on a 2-core machine (the
  workers share the cores; the figures per case are CPU time, which sharing does not inflate much).

Timed is :func:`campaign.run.dask_runner.run_batches` alone, the run of the prepared store's cases (the
store's resume scan and compaction are ``store/`` rows of ``benchmarks/bench_store.py``), with the workers
started and the case code imported beforehand. Columns:

- ``measured``: scheduler and driver overhead per case (ms): the CPU time (user + system) of the driver
  process (with the embedded cluster it holds the scheduler too) plus, for ``scheduler``, that of the
  scheduler process, during the run, over the cases; target :data:`~benchmarks.targets.ORCHESTRATION_MS_PER_CASE`;
- ``tasks``: tasks the scheduler ran (its task prefix ``cases``: transitions to memory, reruns included)
  and ``cases_per_task``;
- ``worker_ms_per_case``: the tasks' compute time over the cases (a no-op case: its rows built and
  written, in batches, through :func:`campaign.store.case_files.write_case_batch`);
- ``wall_s`` and ``wall_ms_per_case``;
- ``driver_rss_start_mib``, ``driver_rss_peak_mib`` (sampled every 0.1 s during the run) and
  ``driver_rss_growth_mib``: flat means no per-case state in the driver (no future per case).
  The plan rows the driver holds before the run are counted in the start.

Environment: ``BENCH_ORCHESTRATION_CASES`` (default 100000), ``BENCH_ORCHESTRATION_CLUSTERS`` (default
``embedded,scheduler``).
"""
from __future__ import annotations

import contextlib
import importlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import psutil

from benchmarks.targets import ORCHESTRATION_MS_PER_CASE, target_columns

REPO = Path(__file__).resolve().parents[1]
SITEDATA = REPO / "sitedata"
GUSEV_CASES = {"gcp": 186, "gdcp": 112, "gkep": 78}
"""Cases per class of the Gusev site file."""
EMBEDDED_WORKERS = 2
"""Worker processes of the embedded cluster: one per core of the 2-core machine."""
EXTERNAL_WORKERS = 8
RSS_SAMPLE_S = 0.1


def no_op_campaign(directory: Path, cases: int, extra_execution: str = "") -> Path:
    """The Gusev site file with absolute input paths, about ``cases`` cases in its classes' proportions
    (``[campaign] cases``) and ``[execution] case_mode = "no_op"`` (plus ``extra_execution`` lines),
    written in ``directory``."""
    text = (SITEDATA / "gusev.toml").read_text()
    for relative in ('"cameras/mer_a.toml"', '"trajectories/gusev.parquet"'):
        text = text.replace(relative, f'"{SITEDATA / relative.strip(chr(34))}"')
    total = sum(GUSEV_CASES.values())
    counts = ", ".join(f"{name} = {max(1, round(cases * count / total))}" for name, count in GUSEV_CASES.items())
    text += f'\n[campaign]\ncases = {{ {counts} }}\n\n[execution]\ncase_mode = "no_op"\n{extra_execution}\n'
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "gusev-no-op.toml"
    path.write_text(text)
    return path


class RssSampler:
    """The peak RSS of this process while in use (sampled every :data:`RSS_SAMPLE_S` s in a thread), MiB."""

    def __init__(self) -> None:
        self.process = psutil.Process()
        self.start_mib = self.peak_mib = self.process.memory_info().rss / 2**20
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.wait(RSS_SAMPLE_S):
            self.peak_mib = max(self.peak_mib, self.process.memory_info().rss / 2**20)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.peak_mib = max(self.peak_mib, self.process.memory_info().rss / 2**20)


def _cpu_s(process: psutil.Process) -> float:
    times = process.cpu_times()
    return times.user + times.system


@contextlib.contextmanager
def external_cluster(directory: Path, workers: int) -> Iterator[tuple[str, psutil.Process]]:
    """A ``dask scheduler`` and ``workers`` one-thread ``dask worker`` processes on loopback; yields the
    scheduler's address and process."""
    dask = Path(sys.executable).with_name("dask")
    command = [str(dask)] if dask.exists() else [sys.executable, "-m", "distributed.cli.dask_spec"]
    scheduler_file = directory / "scheduler.json"
    environment = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    scheduler = subprocess.Popen([*command, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address",
                                  "127.0.0.1:0", "--scheduler-file", str(scheduler_file)], env=environment,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    processes = [scheduler]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        processes += [subprocess.Popen([*command, "worker", address, "--nthreads", "1", "--nworkers", "1", "--host",
                                        "127.0.0.1", "--no-dashboard", "--memory-limit", "1.5GiB"], cwd=REPO,
                                       env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                       start_new_session=True)
                      for _ in range(workers)]
        yield address, psutil.Process(scheduler.pid)
    finally:
        for process in processes:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, 9)
            process.wait()


def _scheduler_tasks(dask_scheduler) -> dict:
    """Run on the scheduler: the ``cases`` tasks it ran (transitions to memory) and their compute seconds."""
    prefix = dask_scheduler.task_prefixes.get("cases")
    if prefix is None:
        return {"tasks": 0, "compute_s": float("nan")}
    return {"tasks": int(prefix.state_counts.get("memory", 0)),
            "compute_s": float(prefix.all_durations.get("compute", float("nan")))}


def measure(cluster: str, cases: int, directory: Path) -> dict:
    """Run a no-op campaign of about ``cases`` cases on ``cluster`` ("embedded" or "scheduler"); its row."""
    from contextlib import ExitStack

    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.cluster import connected_client
    from campaign.run.dask_runner import Watch, batch_cases, run_batches
    from campaign.run.orchestrate import StorePoint, lock_stores, manifest_for
    from campaign.run.planning import plan_campaign
    from campaign.run.worker import CampaignContext
    from campaign.store.campaign_store import CampaignStore

    workers = EMBEDDED_WORKERS if cluster == "embedded" else EXTERNAL_WORKERS
    with ExitStack() as stack:
        if cluster == "embedded":
            path = no_op_campaign(directory, cases, f"workers = {workers}")
            scheduler_process = None
        else:
            address, scheduler_process = stack.enter_context(external_cluster(directory, workers))
            path = no_op_campaign(directory, cases, f'scheduler = "{address}"')
        config = load_campaign_config(path, output_dir=directory / f"store-{cluster}")
        _, plan = plan_campaign(config)
        point = StorePoint(config, manifest_for(config), plan)
        store = CampaignStore(point.store_dir)
        client = stack.enter_context(connected_client(config.execution, quiet=True))
        client.wait_for_workers(workers, timeout=120)
        client.run(importlib.import_module, "campaign.run.worker")      # the case code, as after a first case
        lock_stores([point], [store], stack)
        list(store.prepare(point.manifest, point.plan))
        finished = store.finished_case_ids()
        todo = [row for row in store.plan().to_dict("records") if int(row["case_id"]) not in finished]
        batches = batch_cases(client, CampaignContext.from_config(config, store.root), todo, store)
        driver = psutil.Process()
        driver_cpu, scheduler_cpu = _cpu_s(driver), _cpu_s(scheduler_process) if scheduler_process else 0.0
        started = time.perf_counter()
        with RssSampler() as rss:
            done, failed = run_batches(client, batches, Watch.from_execution(config.execution), progress=False)
        wall_s = time.perf_counter() - started
        driver_cpu = _cpu_s(driver) - driver_cpu
        scheduler_cpu = (_cpu_s(scheduler_process) - scheduler_cpu) if scheduler_process else 0.0
        tasks = client.run_on_scheduler(_scheduler_tasks)
    count = len(todo)
    overhead_ms = 1e3 * (driver_cpu + scheduler_cpu) / count
    return {"name": f"orchestration/{cluster}", "cases": count, "workers": workers, "done": done, "failed": failed,
            "tasks": tasks["tasks"], "batches": len(batches), "cases_per_task": len(batches[0].rows),
            **target_columns(overhead_ms, ORCHESTRATION_MS_PER_CASE, "ms"),
            "driver_cpu_ms_per_case": 1e3 * driver_cpu / count, "scheduler_cpu_ms_per_case": 1e3 * scheduler_cpu / count,
            "worker_ms_per_case": 1e3 * tasks["compute_s"] / count,
            "wall_s": wall_s, "wall_ms_per_case": 1e3 * wall_s / count,
            "driver_rss_start_mib": rss.start_mib, "driver_rss_peak_mib": rss.peak_mib,
            "driver_rss_growth_mib": rss.peak_mib - rss.start_mib}


def run() -> list[dict]:
    cases = int(os.environ.get("BENCH_ORCHESTRATION_CASES", "100000"))
    clusters = os.environ.get("BENCH_ORCHESTRATION_CLUSTERS", "embedded,scheduler").split(",")
    rows = []
    for cluster in clusters:
        directory = Path(tempfile.mkdtemp(prefix=f"bench-orchestration-{cluster}-"))
        try:
            rows.append(measure(cluster.strip(), cases, directory))
        finally:
            shutil.rmtree(directory, ignore_errors=True)
    return rows
