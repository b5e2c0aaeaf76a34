"""The Gusev and Meridiani campaigns end to end on the embedded 2-worker cluster, and the parallel efficiency.

``campaign/gusev+meridiani``: both full campaigns (630 cases) planned and run together on one embedded
LocalCluster of 2 single-threaded workers, by the run path of ``campaign submit``
(:func:`campaign.run.orchestrate.run_store_points`, with a client hook that registers the CPU clock and asks
the workers' usage before the cluster closes): wall time from planning to the compacted stores,
cluster start included (target <= 35 s, issue #33), and each worker process's peak RSS (``ru_maxrss``, asked of
the workers before the cluster closes; target <= 1 GiB).

``campaign/parallel_efficiency``: every ``EVERY``-th case of each campaign is run again in this process, one thread,
by the workers' own function (:func:`campaign.run.worker.execute_case`, into a scratch store), half of them
before the cluster run and half after, so that a change of load on the machine hits both alike.
Efficiency = the one-thread median case wall time (``t_case_ms``, the same timer the workers record) /
the median on the 2 workers of the same cases (target >= 95 %). On a machine with other work the 2
workers share the cores with it, so the wall-time ratio also shows that load; the median thread CPU time
per case (``cpu_ms_*``: on the workers the CPU clock of the executing thread around each task,
:class:`TaskCpuClock`; here around the same calls) does not, and ``cpu_efficiency`` (one thread / workers)
tells extra work in the workers from waiting for a core. ``load_average`` is the machine's 1-minute
load average at the end.
"""
from __future__ import annotations

import os
import resource
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pandas as pd
from distributed import WorkerPlugin

from benchmarks.targets import CAMPAIGNS_WALL_S, PARALLEL_EFFICIENCY, WORKER_RSS_MIB, target_columns

REPO = Path(__file__).resolve().parents[1]
SITES = ("gusev", "meridiani")
WORKERS = 2
EVERY = 8                       # one case in EVERY is also run in this process
CASES_SCALE: float | None = None    # the campaigns' own case counts (a smaller scale: a quick look, not the target)


class TaskCpuClock(WorkerPlugin):
    """Thread CPU time of each task a worker runs: the CPU clock of the worker's one executing thread read
    when the task starts and ends executing (the thread does nothing else meanwhile)."""

    name = "bench-task-cpu-clock"

    def setup(self, worker) -> None:
        self.worker = worker
        self.started: dict = {}
        self.cpu_s: dict = {}

    def _clock(self) -> float | None:
        threads = list(getattr(self.worker.executors.get("default"), "_threads", ()))
        if len(threads) != 1 or threads[0].ident is None:
            return None
        return time.clock_gettime(time.pthread_getcpuclockid(threads[0].ident))

    def transition(self, key, start, finish, **kwargs) -> None:
        if finish == "executing":
            self.started[key] = self._clock()
        elif start == "executing" and self.started.get(key) is not None:
            end = self._clock()
            if end is not None:
                self.cpu_s[key] = end - self.started[key]


def _worker_usage(dask_worker) -> dict:
    """Peak RSS (MiB) of this worker process and its tasks' thread CPU s by key, run inside it."""
    clock = dask_worker.plugins.get(TaskCpuClock.name)
    return {"peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "task_cpu_s": dict(clock.cpu_s) if clock is not None else {}}


def _run_campaigns(root: Path) -> tuple[float, int, list[float], dict]:
    """Plan and run both campaigns on one embedded cluster: (wall s, cases run, peak RSS MiB per worker,
    thread CPU ms per case by (site, case_id))."""
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.orchestrate import StorePoint, manifest_for, run_store_points
    from campaign.run.planning import plan_campaign

    usage: list[dict] = []

    @contextmanager
    def measured(client) -> Iterator[None]:
        """The workers' task CPU clock from the start, their usage read before the cluster closes."""
        client.register_plugin(TaskCpuClock())
        yield
        usage.extend(client.run(_worker_usage).values())

    start = time.perf_counter()
    points = []
    for site in SITES:
        config = load_campaign_config(REPO / "sitedata" / f"{site}.toml", output_dir=root / site,
                                     cases_scale=CASES_SCALE)
        points.append(StorePoint(config, manifest_for(config), plan_campaign(config)[1]))
    execution = points[0].config.execution.with_overrides(None, WORKERS)
    run = run_store_points(points, execution, progress=False, on_note=lambda line: None, client_hook=measured,
                           quiet=True)
    keys = {point.config.config_hash[:12]: site for point, site in zip(points, SITES)}
    task_cpu_ms = {(keys[key.split("-")[1]], int(key.split("-")[2])): 1e3 * cpu_s      # keys case-<hash>-<case id>
                   for worker in usage for key, cpu_s in worker["task_cpu_s"].items() if str(key).startswith("case-")}
    return time.perf_counter() - start, run.done + run.failed, [worker["peak_rss_mib"] for worker in usage], task_cpu_ms


def _one_thread(root: Path, sample: list[tuple[str, dict]]) -> pd.DataFrame:
    """Run the ``sample`` cases ((site, plan record)) in this process as a worker runs them, into scratch stores
    under ``root``: t_case_ms (as recorded) and thread CPU ms per case, indexed by (site, case_id)."""
    from campaign.case.compute import compute_case
    from campaign.case.inputs import PlanRow, campaign_inputs
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.worker import CampaignContext, execute_case, set_up_estimators
    from campaign.store.case_files import read_case_table

    rows = []
    for site in dict.fromkeys(site for site, _ in sample):
        config = load_campaign_config(REPO / "sitedata" / f"{site}.toml", output_dir=root / site,
                                     cases_scale=CASES_SCALE)
        (root / site / "cases").mkdir(parents=True, exist_ok=True)
        resources = campaign_inputs(config)                    # per-process inputs, as a worker's first case
        set_up_estimators(resources)
        records = [record for name, record in sample if name == site]
        compute_case(resources, PlanRow.from_record(records[0]))  # warm: terrain strip and caches
        context = CampaignContext.from_config(config, root / site)
        cpu_ms = {}
        for record in records:
            start = time.thread_time()
            execute_case(context, record)
            cpu_ms[int(record["case_id"])] = 1e3 * (time.thread_time() - start)
        for path in sorted((root / site / "cases").glob("??/batch-*.parquet")):   # a batch file per case here
            for case in read_case_table(path).to_pandas().drop_duplicates("case_id").itertuples():
                rows.append({"site": site, "case_id": int(case.case_id), "t_case_ms": float(case.t_case_ms),
                             "cpu_ms": cpu_ms[int(case.case_id)]})
    return pd.DataFrame(rows).set_index(["site", "case_id"])


def run() -> list[dict]:
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.planning import plan_campaign

    root = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    try:
        sample = [(site, record) for site in SITES
                  for record in plan_campaign(load_campaign_config(REPO / "sitedata" / f"{site}.toml", cases_scale=CASES_SCALE))[1]
                  .to_dict("records")[::EVERY]]
        before = _one_thread(root / "one-thread-before", sample[0::2])
        wall_s, cases, peak_rss_mib, task_cpu_ms = _run_campaigns(root)
        after = _one_thread(root / "one-thread-after", sample[1::2])
        one_thread = pd.concat([before, after])
        timings = pd.concat([pd.read_parquet(root / site / "timings.parquet").drop_duplicates("case_id").assign(site=site)
                             for site in SITES]).set_index(["site", "case_id"])
        on_workers = timings.loc[one_thread.index, "t_case_ms"]
        workers_cpu = pd.Series([task_cpu_ms.get(index, float("nan")) for index in one_thread.index])
        one_thread_ms, workers_ms = float(one_thread["t_case_ms"].median()), float(on_workers.median())
        one_thread_cpu_ms, workers_cpu_ms = float(one_thread["cpu_ms"].median()), float(workers_cpu.median())
        return [
            {"name": "campaign/gusev+meridiani", "cases": cases, "workers": WORKERS, "wall_s": wall_s,
             "ms_per_case_median": float(timings["t_case_ms"].median()),
             "scene_ms_median": float(timings["t_scene_ms"].median()),
             "camera_ms_median": float(timings["t_camera_ms"].median()),
             "estimator_ms_median": float(timings["t_estimator_ms"].median()),
             **target_columns(wall_s, CAMPAIGNS_WALL_S, "s")},
            {"name": "campaign/worker_peak_rss", "workers": WORKERS,
             **target_columns(max(peak_rss_mib), WORKER_RSS_MIB, "MiB")},
            {"name": "campaign/parallel_efficiency", "cases": len(one_thread),
             "case_ms_one_thread": one_thread_ms, "case_ms_2_workers": workers_ms,
             "cpu_ms_one_thread": one_thread_cpu_ms, "cpu_ms_2_workers": workers_cpu_ms,
             "cpu_efficiency": one_thread_cpu_ms / workers_cpu_ms, "load_average": os.getloadavg()[0],
             **target_columns(one_thread_ms / workers_ms, PARALLEL_EFFICIENCY, "x", at_most=False)},
        ]
    finally:
        shutil.rmtree(root, ignore_errors=True)

