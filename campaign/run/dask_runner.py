"""Run a planned campaign on dask.distributed and watch it (backends: :mod:`campaign.run.cluster`).

Tasks are pure functions of small, picklable inputs (the :class:`~campaign.run.worker.CampaignContext` and
one plan row); each worker loads terrain, camera and trajectories once (see :mod:`campaign.case.inputs`)
and writes every result row durably itself, so the driver can die at any time without losing one.

The driver never asks a worker for a result: a finished task's status (``ok`` / ``failed``) is read
from its case file in the store. It polls the tasks and the scheduler and stops the run
(:class:`~campaign.run.faults.RunStopped`, one line: cause and fix) when it cannot progress: a task raised
an infrastructure error or killed its workers (``KilledWorker``), the scheduler is lost, no worker for
``[execution] no_workers_timeout_s``, every worker paused at its memory limit for ``paused_timeout_s``,
or no case finished for ``stall_timeout_s``. The remaining tasks are cancelled; finished cases stay in
the store and the next submit runs the rest.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from dask.distributed import Client
from distributed import Future
from distributed.comm.core import CommClosedError

from campaign.configuration.execution import ExecutionConfig
from campaign.run.faults import CASE_MEMORY_MIB, InfrastructureError, RunStopped
from campaign.run.progress import ProgressBar
from campaign.run.worker import CampaignContext, execute_case
from campaign.store.campaign_store import CampaignStore

POLL_S = 0.25             # task states are local to the client: polling them costs nothing
#: Reading the store (listing and stat-ing every case file) costs the driver CPU that grows with the cases
#: written; on a machine whose cores all run workers that CPU is taken from the cases. The driver reads the
#: store at most this share of its time (and at once when no task is left running).
STORE_READ_SHARE = 0.02
SCHEDULER_POLL_S = 1.0    # the scheduler's worker list, asked this often
SCHEDULER_CALL_TIMEOUT_S = 20.0
LOST_CONNECTION_GRACE_S = 10.0   # the client reconnects by itself within this time, or the scheduler is lost

__all__ = ["CaseTask", "RunSummary", "Watch", "submit_cases", "wait_for_cases"]


@dataclass(frozen=True)
class RunSummary:
    submitted: int
    done: int
    failed: int
    wall_time_s: float


@dataclass
class CaseTask:
    """One submitted case: its future, the store its file goes to, and its id."""

    future: Future
    store: CampaignStore
    case_id: int


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


def submit_cases(client: Client, context: CampaignContext, rows: list[dict], store: CampaignStore) -> list[CaseTask]:
    """Submit one :func:`~campaign.run.worker.execute_case` task per plan row.

    The context (a few kB) travels inside each task rather than being scattered: scattered data lives
    only on workers, and a killed worker would take it along and cancel every case waiting for it."""
    case_ids = [int(row["case_id"]) for row in rows]
    futures = client.map(execute_case, [context] * len(rows), rows,
                         key=[f"case-{context.config_hash[:12]}-{case_id:06d}" for case_id in case_ids], pure=False)
    return [CaseTask(future, store, case_id) for future, case_id in zip(futures, case_ids)]


def wait_for_cases(client: Client, tasks: list[CaseTask], watch: Watch = Watch(), progress: bool = True,
                   stream=None) -> tuple[int, int]:
    """Wait for the case tasks, with progress; return (done, failed) of these tasks, read from the store.

    Raises RunStopped (remaining tasks cancelled) when the run cannot progress (module docstring)."""
    monitor = _Monitor(client, watch, len(tasks))
    bar = ProgressBar(len(tasks), enabled=progress, stream=stream)
    pending = list(tasks)
    unread: list[tuple[CaseTask, str | None]] = []       # ended tasks whose case files were not read yet
    next_read = 0.0
    done = failed = 0
    try:
        while pending or unread:
            time.sleep(POLL_S)
            states = [(task, task.future.status) for task in pending]      # one snapshot: states change meanwhile
            pending = [task for task, state in states if state == "pending"]
            unread += [(task, state) for task, state in states if state != "pending"]
            if unread and (not pending or time.monotonic() >= next_read):
                ended, unread = unread, []
                read_start = time.monotonic()
                # the store says what a case became (a finished result may already be "lost" with its worker)
                stores = {id(task.store): task.store for task, _ in ended}
                on_disk = {key: store.finished_case_ids() for key, store in stores.items()}
                written = [task for task, _ in ended if task.case_id in on_disk[id(task.store)]]
                for task in written:
                    state = on_disk[id(task.store)][task.case_id]
                    done += state == "ok"
                    failed += state == "failed"
                    task.future.release()
                if written:
                    monitor.case_finished()
                written_ids = {id(task) for task in written}
                # "lost" (its worker died) or finished without a file: left for the next submit
                broken = [task for task, state in ended if id(task) not in written_ids and state not in ("lost", "finished")]
                if broken:
                    pending += broken          # cancelled with the rest when the run stops
                    raise RunStopped(monitor.task_problem(broken[0]))
                next_read = time.monotonic() + (time.monotonic() - read_start) / STORE_READ_SHARE
            monitor.check()
            bar.update(done + failed, failed)
    except RunStopped as stop:
        _cancel(client, pending)
        stores = {id(task.store): task.store for task in tasks}
        on_disk = {key: store.finished_case_ids() for key, store in stores.items()}
        left = sum(1 for task in tasks if task.case_id not in on_disk[id(task.store)])
        raise RunStopped(f"run stopped: {stop}; {len(tasks) - left} cases of this run finished and kept, {left} left "
                         "for the next submit") from None
    finally:
        bar.close(done + failed, failed)
    return done, failed


def _cancel(client: Client, pending: list[CaseTask]) -> None:
    if not pending or client.status != "running":
        return
    try:
        client.cancel([task.future for task in pending], force=True)
    except (OSError, CommClosedError, TimeoutError, RuntimeError):
        pass


class _Monitor:
    """The driver's view of the cluster: when a case last finished, since when no worker, all paused."""

    def __init__(self, client: Client, watch: Watch, total: int):
        self.client = client
        self.watch = watch
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

    def check(self) -> None:
        now = time.monotonic()
        if now - self.last_scheduler_poll >= SCHEDULER_POLL_S:
            self.last_scheduler_poll = now
            self._check_scheduler(now)
        if self.workers and now - self.last_finish > self.watch.stall_timeout_s:
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
            if now - since > self.watch.paused_timeout_s:
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

    def task_problem(self, task: CaseTask) -> str:
        """The one-line cause of a task that ended without finishing (its exception is held by this
        client: the scheduler forwards it; no worker is asked)."""
        future = task.future
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
                return (f"case {task.case_id} killed {count} (KilledWorker: a worker process died running it, "
                        f"most often at its memory limit); {self.watch.memory_fix()} (a case needs about "
                        f"{CASE_MEMORY_MIB} MiB), or read the worker logs")
            text = " ".join(str(exc).split())
            return f"case {task.case_id}: its task raised {type(exc).__name__}: {text[:300]}; see the worker logs"
        if self.client.status != "running":
            raise self._lost("the connection closed")
        return (f"case {task.case_id}: its task was {future.status} by the scheduler (another client cancelled it or "
                "the scheduler restarted); submit again")
