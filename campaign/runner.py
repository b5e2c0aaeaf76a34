"""Run a planned campaign on dask.distributed: embedded LocalCluster or an existing scheduler.

Tasks are pure functions of small, picklable inputs (the :class:`~campaign.case.CampaignContext` and
one plan row); each worker loads terrain, camera and trajectories once (see :mod:`campaign.case`)
and writes every result row durably itself, so the driver can die at any time without losing one.
"""
from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import pandas as pd
from dask.distributed import Client, LocalCluster, as_completed

from .case import CampaignContext, execute_case
from .store import CampaignStore


@dataclass(frozen=True)
class RunSummary:
    submitted: int
    done: int
    failed: int
    wall_time_s: float


def default_worker_count() -> int:
    return max(1, os.cpu_count() or 1)


def start_client(scheduler: str | None, workers: int | None, memory_limit: str = "1.5GiB",
                 quiet: bool = False) -> tuple[Client, LocalCluster | None]:
    """Connect to ``scheduler`` or start an embedded LocalCluster of single-threaded worker processes."""
    for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(variable, "1")  # one thread per worker process: idle BLAS threads stall on 2 cores
    if scheduler:
        client = Client(scheduler, timeout="30s")
        cluster = None
    else:
        cluster = LocalCluster(n_workers=workers or default_worker_count(), threads_per_worker=1,
                               processes=True, memory_limit=memory_limit, dashboard_address="127.0.0.1:0",
                               host="127.0.0.1", silence_logs=40)
        client = Client(cluster)
    if not quiet:
        print(f"dask dashboard: {client.dashboard_link}  scheduler: {client.scheduler.address}", flush=True)
    return client, cluster


@contextmanager
def connected_client(scheduler: str | None, workers: int | None, memory_limit: str = "1.5GiB",
                     quiet: bool = False) -> Iterator[Client]:
    """:func:`start_client` for the duration of a ``with`` block; an embedded cluster is stopped after."""
    client, cluster = start_client(scheduler, workers, memory_limit, quiet)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def submit_cases(client: Client, context: CampaignContext, rows: list[dict]) -> list:
    """Submit one :func:`~campaign.case.execute_case` task per plan row (context scattered once)."""
    context_future = client.scatter(context, broadcast=True)
    return client.map(execute_case, [context_future] * len(rows), rows,
                      key=[f"case-{context.config_hash[:12]}-{int(row['case_id']):06d}" for row in rows],
                      pure=False)


def wait_for_cases(futures: list, progress: bool = True) -> tuple[int, int]:
    """Wait for case tasks as they finish, with a progress bar; return (done, failed) counts."""
    bar = ProgressBar(len(futures), enabled=progress)
    done = failed = 0
    for future in as_completed(futures):
        if future.result() == "ok":
            done += 1
        else:
            failed += 1
        bar.update(done + failed, failed)
        future.release()
    bar.close()
    return done, failed


def run_cases(context: CampaignContext, store: CampaignStore, plan: pd.DataFrame, client: Client,
              progress: bool = True) -> RunSummary:
    """Submit every planned case that has no row in the store yet; wait for all of them."""
    start = time.perf_counter()
    finished = store.finished_case_ids()
    todo = [row for row in plan.to_dict("records") if int(row["case_id"]) not in finished]
    done, failed = wait_for_cases(submit_cases(client, context, todo), progress) if todo else (0, 0)
    return RunSummary(len(todo), done, failed, time.perf_counter() - start)


class ProgressBar:
    """A one-line text progress bar with rate and ETA (plain lines when not on a terminal)."""

    def __init__(self, total: int, enabled: bool = True, stream=None):
        self.total = total
        self.enabled = enabled and total > 0
        self.stream = sys.stderr if stream is None else stream   # looked up now, not at import
        self.start = time.perf_counter()
        self.last_print = 0.0
        self.tty = hasattr(stream, "isatty") and stream.isatty()

    def update(self, count: int, failed: int = 0) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if not self.tty and count < self.total and now - self.last_print < 5.0:
            return
        self.last_print = now
        elapsed = max(now - self.start, 1e-9)
        rate = count / elapsed
        eta = (self.total - count) / rate if rate > 0 else float("inf")
        width = 30
        filled = int(width * count / self.total)
        line = (f"[{'#' * filled}{'.' * (width - filled)}] {count}/{self.total} cases, "
                f"{failed} failed, {rate:.1f} cases/s, ETA {eta:.0f} s")
        self.stream.write(("\r" + line) if self.tty else (line + "\n"))
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
