"""Run a planned campaign on dask.distributed and watch it (backends: :mod:`campaign.run.cluster`).

Cases go to the workers in batches (:func:`batch_cases`): one task runs several cases one after the other
(:func:`campaign.run.worker.execute_batch`, :func:`cases_per_task` of them), so the scheduler sees far fewer
tasks than cases; the last tasks of a run are cut shorter (:func:`balanced_tail`), so that the workers
finish together instead of one running a whole batch while the others idle. The driver keeps a bounded
window of tasks in flight (:func:`run_batches`: about :data:`IN_FLIGHT_PER_WORKER` per worker, submitted as
others finish, told by the futures' done callbacks), so neither the driver nor the scheduler holds a future
or a task per case: their memory does not grow with the campaign.

Tasks are pure functions of small, picklable inputs (the :class:`~campaign.run.worker.CampaignContext` and
the batch's plan rows); each worker loads terrain, camera and trajectories once (see
:mod:`campaign.case.inputs`) and writes every case's result rows durably itself as the case finishes, so the
driver can die at any time without losing one. A task returns only its counts of ok and failed cases (for
progress); what a case became is in the store.

The driver stops the run (:class:`~campaign.run.faults.RunStopped`, one line: cause and fix) when it
cannot progress: a task raised an infrastructure error or killed its workers (``KilledWorker``), the
scheduler is lost, no worker for ``[execution] no_workers_timeout_s``, every worker paused at its memory
limit for ``paused_timeout_s``, or no task finished for ``stall_timeout_s``. The remaining tasks are
cancelled; finished cases stay in the store and the next submit runs the rest. A worker that dies while
running a batch loses no written case: dask reruns the batch elsewhere (its cases written again supersede
the earlier files, same bits but the run-dependent columns).
"""
from __future__ import annotations

import functools
import math
import queue
import secrets
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import CancelledError
from dataclasses import dataclass

import pyarrow as pa
from dask.distributed import Client
from distributed import Future
from distributed.comm.core import CommClosedError

from campaign.configuration.execution import ExecutionConfig
from campaign.run.faults import CASE_MEMORY_MIB, InfrastructureError, RunStopped
from campaign.run.progress import ProgressBar
from campaign.run.worker import CampaignContext, execute_batch
from campaign.store.campaign_store import CampaignStore

POLL_S = 0.25             # the longest the driver waits for a finished task before it checks the cluster
SCHEDULER_POLL_S = 1.0    # the scheduler's worker list, asked this often
SCHEDULER_CALL_TIMEOUT_S = 20.0
LOST_CONNECTION_GRACE_S = 10.0   # the client reconnects by itself within this time, or the scheduler is lost
IN_FLIGHT_PER_WORKER = 2
"""Tasks submitted and not finished, per worker: one running and one queued, so a worker never waits for
the driver; at least :data:`MIN_IN_FLIGHT` (before the first worker has joined)."""
MIN_IN_FLIGHT = 8
TASKS_PER_WORKER = 4
"""Automatic batch size (:func:`cases_per_task`): a point's cases cut into about this many tasks per worker
(:func:`balanced_tail` then cuts the last ones of a run short)."""
MAX_CASES_PER_TASK = {"compute": 64, "no_op": 2000}
"""Automatic batch size cap per ``[execution] case_mode``. A computed case takes about 60 ms on the 2-core
machine (seconds with the heaviest off-nominal effects), so 64 of them keep a task to a few seconds: the
progress moves per task, and the stall watch also counts the cases a task writes every :data:`FLUSH_S`.
Each task costs the run a scheduler round trip, about 7 ms of the driver's CPU (measured: the driver used
2.8 % of a core during the Gusev campaign on 2 workers with 16-case tasks, 2.05 % with 48-case ones) and a
batch file. With every core computing that cost comes out of the cases: Gusev + Meridiani on 2 workers, 16
cases a task at most and 8 tasks per worker against these sizes, three alternations on the idle machine
(2026-11-27): median case 59.1-62.1 against 56.9-59.9 ms, parallel efficiency 0.90-0.95 against 0.96-1.01.
A no-op case takes about a millisecond."""
TAIL_SHARES = 2
""":func:`balanced_tail`: a task near the end of a run takes at most 1 / (this x workers) of the cases left."""
TAIL_MIN_CASES = 2
""":func:`balanced_tail`: the fewest cases of a task it cuts (one task more costs a scheduler round trip and a
batch file)."""

__all__ = ["CaseBatch", "RunSummary", "Watch", "balanced_tail", "batch_cases", "cases_per_task", "run_batches"]


@dataclass(frozen=True)
class RunSummary:
    submitted: int
    done: int
    failed: int
    wall_time_s: float


@dataclass(frozen=True)
class CaseBatch:
    """Cases of one store run by one task (:func:`campaign.run.worker.execute_batch`): its plan rows, the
    store their files go to, the task's context and key.

    The plan rows travel as an Arrow table of their own (columns in a few buffers): the scheduler
    deserializes every task it is given, and a list of row dicts made it allocate a dozen Python objects per
    case, whose fragments grew its heap (with the embedded cluster, the driver's) by about 1 kB per case of
    the run (measured: 95 MiB after 10^5 no-op cases; 3 MiB with the tables)."""

    context: CampaignContext
    store: CampaignStore
    rows: pa.Table
    key: str

    @property
    def case_ids(self) -> list[int]:
        return self.rows.column("case_id").to_pylist()

    def describe(self) -> str:
        """"case 12" or "cases 12..40 (one task of 8)", for a stop line."""
        ids = self.case_ids
        if len(ids) == 1:
            return f"case {ids[0]}"
        return f"cases {ids[0]}..{ids[-1]} (one task of {len(ids)})"


@dataclass(frozen=True)
class Watch:
    """When the driver gives up on a run (``[execution]`` fields) and what it tells the user."""

    stall_timeout_s: float = 900.0
    no_workers_timeout_s: float = 300.0
    paused_timeout_s: float = 20.0
    cluster: str = "local"
    memory_limit: str = "1.5GiB"

    @classmethod
    def from_execution(cls, execution: ExecutionConfig) -> Watch:
        return cls(execution.stall_timeout_s, execution.no_workers_timeout_s, execution.paused_timeout_s,
                   execution.cluster, execution.memory_limit)

    def memory_fix(self) -> str:
        """How to give a worker more memory, for this backend."""
        if self.cluster == "local":
            return f"raise [execution] memory_limit (now {self.memory_limit})"
        if self.cluster in ("slurm", "pbs"):
            return f"raise [execution.{self.cluster}] memory (per job, shared by its cores)"
        if self.cluster == "kubernetes":
            return "raise [execution.kubernetes] memory"
        return "start the workers with a larger --memory-limit"


def expected_workers(execution: ExecutionConfig) -> int:
    """The workers a campaign's ``[execution]`` table asks for (when none has joined yet): ``workers``, else
    the batch jobs' ``jobs x cores`` or the Kubernetes pods, else 1."""
    if execution.workers:
        return execution.workers
    if execution.cluster in ("slurm", "pbs"):
        jobs = getattr(execution, execution.cluster)
        return jobs.jobs * jobs.cores
    if execution.cluster == "kubernetes":
        return execution.kubernetes.workers
    return 1


def cases_per_task(cases: int, workers: int, execution: ExecutionConfig) -> int:
    """Cases per task: ``[execution] cases_per_task``, or (0) ``cases`` cut into about
    :data:`TASKS_PER_WORKER` tasks per worker, at most :data:`MAX_CASES_PER_TASK` of the case mode."""
    if execution.cases_per_task:
        return execution.cases_per_task
    wanted = math.ceil(cases / (max(workers, 1) * TASKS_PER_WORKER))
    return max(1, min(MAX_CASES_PER_TASK[execution.case_mode], wanted))


def cluster_workers(client: Client) -> int:
    """Workers the scheduler has now (0 when it cannot say)."""
    try:
        return len(client.scheduler_info(n_workers=-1).get("workers", {}))
    except (OSError, CommClosedError, TimeoutError, TypeError):
        return 0


def batch_cases(client: Client, context: CampaignContext, rows: Sequence[dict], store: CampaignStore) -> list[CaseBatch]:
    """The plan rows of one store cut into :class:`CaseBatch` tasks of :func:`cases_per_task` cases (the
    workers the scheduler has now, or the campaign's :func:`expected_workers`); nothing is submitted yet
    (:func:`run_batches` does).

    The context (a few kB) travels inside each task rather than being scattered: scattered data lives
    only on workers, and a killed worker would take it along and cancel every case waiting for it."""
    execution = context.config.execution
    size = cases_per_task(len(rows), cluster_workers(client) or expected_workers(execution), execution)
    return [_case_batch(context, store, rows[start:start + size]) for start in range(0, len(rows), size)]


def _case_batch(context: CampaignContext, store: CampaignStore, rows: Sequence[dict]) -> CaseBatch:
    """One task of the plan rows ``rows`` (at least one), keyed by the campaign, its first case, its size and a
    random token.

    The token makes every key unique on the scheduler: dask takes a key it already holds for the same result,
    so two runs of one configuration into two stores on a shared cluster (two users, or a resumed run while
    the old one's tasks are still known) would otherwise share tasks, and the second store would get no
    files (or wait on a key being forgotten). The key names no result: the cases' bits depend on the seed only.
    """
    # a table of its own: a pickled slice of a larger table carries the whole of its buffers
    part = pa.Table.from_pylist(list(rows))
    first = int(rows[0]["case_id"])
    return CaseBatch(context, store, part,
                     f"cases-{context.config_hash[:12]}-{first:07d}-{len(part)}-{secrets.token_hex(6)}")


def balanced_tail(batches: Sequence[CaseBatch], workers: int) -> list[CaseBatch]:
    """``batches`` (in run order) with the ones near the end cut shorter, so that the workers finish together.

    The driver hands tasks out as workers free up (:func:`run_batches`), so a run ends when its last task
    does: with batches of :func:`cases_per_task` cases, a worker can be left running a whole batch while the
    others idle (up to 64 computed cases, about 4 s at 60 ms a case). Here each task takes at most
    1 / (:data:`TAIL_SHARES` x ``workers``) of the cases left from its start to the end of the run (at least
    :data:`TAIL_MIN_CASES`): the sizes fall towards the end (guided self-scheduling), and only the last few
    batches of a run are cut (their cases re-cut as one run per store, so the sizes fall steadily). A batch
    sized by ``[execution] cases_per_task`` is kept as it is; the cases, their order and what each computes
    are unchanged (a case's result does not depend on its task)."""
    shares = TAIL_SHARES * max(workers, 1)
    left = sum(len(batch.rows) for batch in batches)
    cut: list[CaseBatch] = []
    pending: list[dict] = []            # plan rows of the tail, of one campaign and store, not yet cut
    owner: CaseBatch | None = None      # the batch whose context and store they have

    def cut_pending() -> None:
        nonlocal left
        if owner is None:
            return
        start = 0
        while start < len(pending):
            size = min(len(pending) - start, max(TAIL_MIN_CASES, math.ceil(left / shares)))
            cut.append(_case_batch(owner.context, owner.store, pending[start:start + size]))
            start += size
            left -= size
        pending.clear()

    for batch in batches:
        count = len(batch.rows)
        in_tail = owner is not None or math.ceil(left / shares) < count
        if not in_tail or batch.context.config.execution.cases_per_task:
            cut_pending()
            cut.append(batch)
            left -= count
            continue
        if owner is not None and (owner.context is not batch.context or owner.store is not batch.store):
            cut_pending()
        owner = batch
        pending.extend(batch.rows.to_pylist())     # consecutive batches of a store are cut as one run of cases
    cut_pending()
    return cut


def run_batches(client: Client, batches: Sequence[CaseBatch], watch: Watch = Watch(), progress: bool = True,
                stream=None) -> tuple[int, int]:
    """Run the batches, a bounded window of them in flight, with progress; return (done, failed) cases of
    these batches (as their tasks counted them).

    Raises RunStopped (remaining tasks cancelled, none submitted any more) when the run cannot progress
    (module docstring)."""
    total = sum(len(batch.rows) for batch in batches)
    stores = list({id(batch.store): batch.store for batch in batches}.values())
    monitor = _Monitor(client, watch, lambda: sum(len(store.finished_case_ids()) for store in stores))
    bar = ProgressBar(total, enabled=progress, stream=stream)
    waiting = deque(batches)
    running: dict[Future, CaseBatch] = {}
    ended: queue.Queue[tuple[Future, tuple[int, int] | None]] = queue.Queue()
    done = failed = 0
    try:
        monitor.check()
        while waiting or running:
            window = max(MIN_IN_FLIGHT, IN_FLIGHT_PER_WORKER * monitor.workers)
            while waiting and len(running) < window:
                batch = waiting.popleft()
                future = client.submit(execute_batch, batch.context, batch.rows, key=batch.key, pure=False)
                running[future] = batch
                future.add_done_callback(functools.partial(_report_end, ended))
            for future, result in _ended_tasks(ended, POLL_S):
                if future.status in ("error", "cancelled"):      # cancelled with the rest
                    raise RunStopped(monitor.task_problem(running[future], future))
                if result is None:
                    # its result went with its worker (dask computes it again) or the connection dropped (the
                    # monitor stops the run when the scheduler is lost): wait for it again
                    future.add_done_callback(functools.partial(_report_end, ended))
                    continue
                ok, bad = result
                del running[future]
                future.release()
                done += ok
                failed += bad
                monitor.case_finished()
            monitor.check()
            bar.update(done + failed, failed)
    except RunStopped as stop:
        _cancel(client, list(running))
        on_disk = {id(store): store.finished_case_ids() for store in stores}
        left = sum(1 for batch in batches for case_id in batch.case_ids if case_id not in on_disk[id(batch.store)])
        raise RunStopped(f"run stopped: {stop}; {total - left} cases of this run finished and kept, {left} left "
                         "for the next submit") from None
    finally:
        bar.close(done + failed, failed)
    return done, failed


def _report_end(ended: queue.Queue, future: Future) -> None:
    """Run by dask in its callback thread when a task ends: put (future, its (ok, failed) counts) on
    ``ended``; counts None when the task did not finish or its result could not be fetched. The fetch
    happens here, not in the driver's loop, so a hung worker or a lost scheduler never delays the watch."""
    result = None
    if future.status == "finished":
        try:
            result = future.result(timeout=SCHEDULER_CALL_TIMEOUT_S)
        except (OSError, CommClosedError, TimeoutError, CancelledError):
            result = None
    ended.put((future, result))


def _ended_tasks(ended: queue.Queue, timeout_s: float) -> list[tuple[Future, tuple[int, int] | None]]:
    """The tasks that ended since the last call, waiting at most ``timeout_s`` for one."""
    try:
        first = [ended.get(timeout=timeout_s)]
    except queue.Empty:
        return []
    rest = []
    while True:
        try:
            rest.append(ended.get_nowait())
        except queue.Empty:
            return first + rest


def _cancel(client: Client, futures: list[Future]) -> None:
    if not futures or client.status != "running":
        return
    try:
        client.cancel(futures, force=True)
    except (OSError, CommClosedError, TimeoutError, RuntimeError):
        pass


class _Monitor:
    """The driver's view of the cluster: when a case last finished, since when no worker, all paused."""

    def __init__(self, client: Client, watch: Watch, cases_on_disk: Callable[[], int] | None = None):
        self.client = client
        self.watch = watch
        # a task's cases are written before its result reaches the driver (a paused worker does not serve
        # results; a long task flushes its cases every few seconds): before it stops a run that seems not to
        # progress, the driver counts the cases in the store
        self.cases_on_disk = cases_on_disk
        self.cases_seen = cases_on_disk() if cases_on_disk is not None else 0
        self.address = getattr(client.scheduler, "address", "?")
        now = time.monotonic()
        self.last_finish = now
        self.last_scheduler_poll = 0.0
        self.no_workers_since: float | None = None
        self.paused_since: float | None = None
        self.disconnected_since: float | None = None
        self.workers = 0

    def case_finished(self) -> None:
        self.last_finish = time.monotonic()
        self.paused_since = None

    def store_progressed(self) -> bool:
        """True (and a case counted as finished now) when the store holds more cases than at the last look."""
        if self.cases_on_disk is None:
            return False
        count = self.cases_on_disk()
        if count <= self.cases_seen:
            return False
        self.cases_seen = count
        self.case_finished()
        return True

    def check(self) -> None:
        now = time.monotonic()
        if now - self.last_scheduler_poll >= SCHEDULER_POLL_S:
            self.last_scheduler_poll = now
            self._check_scheduler(now)
        if self.workers and now - self.last_finish > self.watch.stall_timeout_s and not self.store_progressed():
            raise RunStopped(f"no case finished in {now - self.last_finish:.0f} s with {self.workers} workers up "
                             f"([execution] stall_timeout_s = {self.watch.stall_timeout_s:g}); check the workers on the "
                             f"dashboard ({self.client.dashboard_link}), or raise stall_timeout_s if a case takes longer")

    def _lost(self, cause: str) -> RunStopped:
        return RunStopped(f"lost the dask scheduler at {self.address} ({cause}); restart it (or the embedded "
                          "cluster) and submit again")

    def _check_scheduler(self, now: float) -> None:
        if self.client.status in ("closing", "closed"):
            raise self._lost("the connection closed")
        try:
            identity = self.client.sync(self.client.scheduler.identity, n_workers=-1,
                                        callback_timeout=SCHEDULER_CALL_TIMEOUT_S)
        except (OSError, CommClosedError, TimeoutError) as exc:
            self.disconnected_since = self.disconnected_since or now
            if now - self.disconnected_since >= LOST_CONNECTION_GRACE_S or isinstance(exc, TimeoutError):
                raise self._lost(f"{type(exc).__name__}: {exc}".strip().rstrip(":")) from None
            return
        self.disconnected_since = None
        workers = identity.get("workers", {})
        self.workers = len(workers)
        if not workers:
            self.no_workers_since = self.no_workers_since or now
            if now - self.no_workers_since > self.watch.no_workers_timeout_s:
                raise RunStopped(self._no_workers_text(now - self.no_workers_since))
            return
        self.no_workers_since = None
        if all(info.get("status") == "paused" for info in workers.values()):
            self.paused_since = self.paused_since or now
            since = max(self.paused_since, self.last_finish)
            if now - since > self.watch.paused_timeout_s and not self.store_progressed():
                limits = sorted({int(info.get("memory_limit") or 0) for info in workers.values()})
                limit = ", ".join(f"{value / 2**20:.0f}MiB" for value in limits)
                raise RunStopped(f"all {len(workers)} workers paused at memory_limit {limit} for {now - since:.0f} s "
                                 f"with no case finishing; {self.watch.memory_fix()} to at least 1GiB (a case needs "
                                 f"about {CASE_MEMORY_MIB} MiB and a worker pauses at 80 % of its limit)")
        else:
            self.paused_since = None

    def _no_workers_text(self, waited_s: float) -> str:
        fixes = {"local": "the embedded workers could not start or keep running: check memory and the machine",
                 "scheduler": f"start workers (dask worker {self.address})",
                 "slurm": "the SLURM jobs have not started or have ended: check squeue, [execution.slurm] walltime",
                 "pbs": "the PBS jobs have not started or have ended: check qstat, [execution.pbs] walltime",
                 "kubernetes": "the worker pods are not running: check kubectl get pods"}
        return (f"no dask worker for {waited_s:.0f} s (scheduler {self.address}); {fixes[self.watch.cluster]}, "
                f"or raise [execution] no_workers_timeout_s = {self.watch.no_workers_timeout_s:g}")

    def task_problem(self, batch: CaseBatch, future: Future) -> str:
        """The one-line cause of a task that ended without finishing (its exception is held by this
        client: the scheduler forwards it; no worker is asked)."""
        if future.status == "error":
            try:
                exc = future.exception(timeout=SCHEDULER_CALL_TIMEOUT_S)
            except (OSError, CommClosedError, TimeoutError) as problem:
                raise self._lost(f"{type(problem).__name__}: {problem}") from None
            if isinstance(exc, InfrastructureError):
                return str(exc)
            if type(exc).__name__ == "KilledWorker":
                allowed = getattr(exc, "allowed_failures", None)
                count = f"{allowed + 1} workers" if isinstance(allowed, int) else "its workers"
                return (f"{batch.describe()} killed {count} (KilledWorker: a worker process died running it, "
                        f"most often at its memory limit); {self.watch.memory_fix()} (a case needs about "
                        f"{CASE_MEMORY_MIB} MiB), or read the worker logs")
            text = " ".join(str(exc).split())
            return f"{batch.describe()}: its task raised {type(exc).__name__}: {text[:300]}; see the worker logs"
        if self.client.status != "running":
            raise self._lost("the connection closed")
        return (f"{batch.describe()}: its task was {future.status} by the scheduler (another client cancelled it or "
                "the scheduler restarted); submit again")
