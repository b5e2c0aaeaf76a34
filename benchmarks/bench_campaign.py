"""The Gusev and Meridiani campaigns end to end on the embedded 2-worker cluster, and the parallel efficiency.

``campaign/gusev+meridiani``: both full campaigns (630 cases) planned and run together on one embedded
LocalCluster of 2 single-threaded workers, by the run path of ``campaign submit``
(:func:`campaign.run.orchestrate.run_store_points`, with a client hook that registers the CPU clock and asks
the workers' usage before the cluster closes): wall time from planning to the compacted stores,
cluster start included (target <= 35 s, issue #33), and each worker process's peak RSS (``ru_maxrss``, asked of
the workers before the cluster closes; target <= 1 GiB).

``campaign/parallel_efficiency``: every ``EVERY``-th case of each campaign is run again, one case at a time, on an
embedded cluster of ONE worker started by the same code as the campaign's two
(:func:`campaign.run.cluster.connected_client`), by the workers' own function
(:func:`campaign.run.worker.execute_case`, into a scratch store), half of them before the cluster run and half
after, so that a change of load on the machine hits both alike. Protocol: both sides are worker processes
spawned the same way, so they compute in the same heap (:mod:`simulator.heap`: the same malloc thresholds
and arena, set by the environment the nanny spawns them with) in the same kind of thread (the worker's task
thread), with the same imports; the one-worker side runs a warm-up case of each campaign first (terrain strip,
caches, as a campaign worker's first case). A one-thread side in this process instead (main thread, main
arena, this process's own heap settings) compared unlike heaps: 76-87 against 108 ms a case on the workers on
2026-11-27. Efficiency = the one-worker median case wall time (``t_case_ms``, the same timer the workers
record) / the median on the 2 workers of the same cases (target >= 95 %). On a machine with other work the 2
workers share the cores with it, so the wall-time ratio also shows that load; the median thread CPU time
per case (``cpu_ms_*``: the CPU clock of the executing thread; around each case on the one worker, around each
task on the two, a batch of cases, divided by its cases: the median over all tasks, whose few first ones per
worker and campaign also load the inputs) does not, and
``cpu_efficiency`` (one worker / two) tells extra work in the workers from waiting for a core. The two CPU
columns are not measured quite alike: the one worker's includes a batch file written per case, the two's one
per task of up to 64 cases, so ``cpu_efficiency`` is flattered by about that write's CPU; the wall-time target
compares ``t_case_ms`` on both sides: the case's computation without its case file (a class's first case also
writes its example PNGs, on both sides alike).
``load_average`` is the machine's 1-minute load average at the end.
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


def _run_campaigns(root: Path) -> tuple[float, int, list[float], list[float]]:
    """Plan and run both campaigns on one embedded cluster: (wall s, cases run, peak RSS MiB per worker,
    thread CPU ms per case of each task, a batch of cases)."""
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
    # a task is a batch of cases, keyed cases-<hash>-<first case id>-<cases>-<token>: its CPU per case
    case_cpu_ms = [1e3 * cpu_s / int(str(key).split("-")[3])
                   for worker in usage for key, cpu_s in worker["task_cpu_s"].items() if str(key).startswith("cases-")]
    return time.perf_counter() - start, run.done + run.failed, [worker["peak_rss_mib"] for worker in usage], case_cpu_ms


def _cases_one_at_a_time(root: str, site: str, records: list[dict]) -> list[dict]:
    """Run ``records`` of ``site``'s campaign here (a worker's task thread) as a worker runs them, into a scratch
    store under ``root``, after a warm-up case: t_case_ms (as recorded) and thread CPU ms per case."""
    from campaign.case.compute import compute_case
    from campaign.case.inputs import PlanRow, campaign_inputs
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.worker import CampaignContext, execute_case, set_up_estimators
    from campaign.store.case_files import read_case_table

    store = Path(root) / site
    config = load_campaign_config(REPO / "sitedata" / f"{site}.toml", output_dir=store, cases_scale=CASES_SCALE)
    (store / "cases").mkdir(parents=True, exist_ok=True)
    resources = campaign_inputs(config)                    # per-process inputs, as a worker's first case
    set_up_estimators(resources)
    compute_case(resources, PlanRow.from_record(records[0]))  # warm: terrain strip and caches
    context = CampaignContext.from_config(config, store)
    cpu_ms = {}
    for record in records:
        start = time.thread_time()
        execute_case(context, record)
        cpu_ms[int(record["case_id"])] = 1e3 * (time.thread_time() - start)
    rows = []
    for path in sorted((store / "cases").glob("??/batch-*.parquet")):   # a batch file per case here
        for case in read_case_table(path).to_pandas().drop_duplicates("case_id").itertuples():
            rows.append({"site": site, "case_id": int(case.case_id), "t_case_ms": float(case.t_case_ms),
                         "cpu_ms": cpu_ms[int(case.case_id)]})
    return rows


def _one_worker(root: Path, sample: list[tuple[str, dict]]) -> pd.DataFrame:
    """Run the ``sample`` cases ((site, plan record)) one at a time on an embedded cluster of one worker, started
    as the campaign's (module doc: the protocol), into scratch stores under ``root``: t_case_ms (as recorded)
    and thread CPU ms per case, indexed by (site, case_id)."""
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.cluster import connected_client

    execution = load_campaign_config(REPO / "sitedata" / f"{SITES[0]}.toml").execution.with_overrides(None, 1)
    rows: list[dict] = []
    with connected_client(execution, quiet=True) as client:
        for site in dict.fromkeys(site for site, _ in sample):
            records = [record for name, record in sample if name == site]
            rows += client.submit(_cases_one_at_a_time, str(root), site, records, pure=False).result()
    return pd.DataFrame(rows).set_index(["site", "case_id"])


def run() -> list[dict]:
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.planning import plan_campaign

    root = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    try:
        sample = [(site, record) for site in SITES
                  for record in plan_campaign(load_campaign_config(REPO / "sitedata" / f"{site}.toml", cases_scale=CASES_SCALE))[1]
                  .to_dict("records")[::EVERY]]
        before = _one_worker(root / "one-worker-before", sample[0::2])
        wall_s, cases, peak_rss_mib, case_cpu_ms = _run_campaigns(root)
        after = _one_worker(root / "one-worker-after", sample[1::2])
        one_worker = pd.concat([before, after])
        timings = pd.concat([pd.read_parquet(root / site / "timings.parquet").drop_duplicates("case_id").assign(site=site)
                             for site in SITES]).set_index(["site", "case_id"])
        on_workers = timings.loc[one_worker.index, "t_case_ms"]
        one_worker_ms, workers_ms = float(one_worker["t_case_ms"].median()), float(on_workers.median())
        one_worker_cpu_ms, workers_cpu_ms = float(one_worker["cpu_ms"].median()), float(pd.Series(case_cpu_ms).median())
        return [
            {"name": "campaign/gusev+meridiani", "cases": cases, "workers": WORKERS, "wall_s": wall_s,
             "ms_per_case_median": float(timings["t_case_ms"].median()),
             "scene_ms_median": float(timings["t_scene_ms"].median()),
             "camera_ms_median": float(timings["t_camera_ms"].median()),
             "estimator_ms_median": float(timings["t_estimator_ms"].median()),
             **target_columns(wall_s, CAMPAIGNS_WALL_S, "s")},
            {"name": "campaign/worker_peak_rss", "workers": WORKERS,
             **target_columns(max(peak_rss_mib), WORKER_RSS_MIB, "MiB")},
            {"name": "campaign/parallel_efficiency", "cases": len(one_worker),
             "case_ms_one_worker": one_worker_ms, "case_ms_2_workers": workers_ms,
             "cpu_ms_one_worker": one_worker_cpu_ms, "cpu_ms_2_workers": workers_cpu_ms,
             "cpu_efficiency": one_worker_cpu_ms / workers_cpu_ms, "load_average": os.getloadavg()[0],
             **target_columns(one_worker_ms / workers_ms, PARALLEL_EFFICIENCY, "x", at_most=False)},
        ]
    finally:
        shutil.rmtree(root, ignore_errors=True)

