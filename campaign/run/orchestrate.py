"""Running campaign stores: the one locked-run path of ``campaign submit`` (one store), ``campaign sweep``
(one store per point, a batch of points at a time) and the campaign benchmark (:func:`run_store_points`):
check the stores, lock them, connect to the cluster (:func:`cluster_session`: the caller's client hook,
then the estimators shipped), prepare the stores, run their missing cases and compact them.

Tables, plan maps and sweep outputs are written by :mod:`campaign.report` after the run (``campaign.cli``).
"""
from __future__ import annotations

import functools
import importlib.metadata
import os
import platform
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from distributed import Client

from campaign.case.inputs import shippable_inputs
from campaign.configuration.campaign_file import CampaignConfig
from campaign.configuration.execution import ExecutionConfig
from campaign.run.batch_jobs import SUBMIT_COMMANDS, require_submit_command
from campaign.run.cluster import connected_client, require_backend
from campaign.run.dask_runner import (
    RunSummary,
    Watch,
    balanced_tail,
    batch_cases,
    cluster_workers,
    expected_workers,
    run_batches,
)
from campaign.run.faults import RunStopped, is_infrastructure, storage_problem
from campaign.run.interrupts import held, remove_temporary_files
from campaign.run.planning import plan_campaign
from campaign.run.plugin_setup import PluginSetupError, ship_plugin_code
from campaign.run.security import require_secure_transport
from campaign.run.worker import CampaignContext
from campaign.run.worker_startup import ShippedInputs
from campaign.store.campaign_store import CampaignStore
from campaign.store.lock import StoreBusy
from estimators.entries import EstimatorSpec

PACKAGES = ("moc2dimes", "numpy", "scipy", "dask", "distributed", "pandas", "pyarrow",
            "opencv-contrib-python-headless")

ClientHook = Callable[[Client], AbstractContextManager[Any]]
"""Called with the connected client before the estimators are shipped; its context is left after the run,
before the cluster closes (the campaign benchmark registers a worker plug-in and reads the workers' usage)."""


def _print_note(line: str) -> None:
    print(line, flush=True)


@functools.lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """The versions of :data:`PACKAGES` (read once per process: a sweep records them in every point's manifest)."""
    versions = {}
    for package in PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def manifest_for(config: CampaignConfig) -> dict:
    """What a store records of ``config`` in its manifest.json (before sealing)."""
    versions = dict(package_versions())
    return {
        "config_file": str(config.source), "working_directory": os.getcwd(), "config_hash": config.config_hash, "config": config.resolved,
        "hash_inputs": config.hash_inputs,        # file and code digests: a refused change names them
        "seed": config.seed, "site": config.site.name, "cases_per_class": config.cases_per_class,
        "estimators": config.estimator_names,     # what every case file records (campaign.store.case_identity)
        "ellipse_fractions": {entry.name: entry.ellipse_fraction for entry in config.site.classes},
        "python": platform.python_version(), "packages": versions,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


@dataclass(frozen=True)
class StorePoint:
    """One campaign configuration, the store its cases go to, and what that store records of it."""

    config: CampaignConfig
    manifest: dict          # the store's manifest.json content (before sealing)
    plan: pd.DataFrame      # every planned case of the configuration

    @property
    def store_dir(self) -> Path:
        return Path(self.config.output_dir)


@dataclass(frozen=True)
class PreparedPoint:
    """A store brought up to date under its lock, and the plan rows it still has to run."""

    point: StorePoint
    store: CampaignStore
    todo: list[dict]


@dataclass(frozen=True)
class StoresRun:
    """What :func:`run_store_points` did: every point's prepared store, and the cases of this run."""

    prepared: list[PreparedPoint]
    done: int
    failed: int

    @property
    def submitted(self) -> int:
        return sum(len(entry.todo) for entry in self.prepared)


def run_store_points(points: list[StorePoint], execution: ExecutionConfig, *, client: Client | None = None,
                     fresh: bool = False, progress: bool = True, wait: bool = False,
                     on_note: Callable[[str], None] = _print_note, client_hook: ClientHook | None = None,
                     quiet: bool = False) -> StoresRun:
    """Run every missing case of every point's store and compact the stores: the one locked-run path of
    ``campaign submit`` (one point), ``campaign sweep`` (a batch of points at a time, on the sweep's
    ``client``) and the campaign benchmark.

    Order (so that a refusal changes nothing; the caller has planned and checked the cluster settings
    with :func:`~campaign.run.cluster.require_backend`): check every store read-only (StoreError: another
    configuration, corrupt manifest, ... unless ``fresh``), take every store's lock in path order
    (:class:`~campaign.store.lock.StoreBusy` when another writer holds one, unless ``wait``), check again
    under the locks (when every store has every planned case already, :meth:`CampaignStore.has_every_case`, no
    cluster is started: the stores are only prepared and, if out of date, compacted), start or connect to the
    cluster unless a ``client`` is given (:func:`cluster_session`:
    ``client_hook``, then the python plug-ins' code shipped to the workers; a worker that cannot import one
    stops the run before any store changes; the inputs every worker would load alike and planning loaded here,
    :func:`~campaign.case.inputs.shippable_inputs`, are shipped as the cluster is up), and only
    then prepare the stores (with ``fresh``: move an old store aside to ``DIR.previous-<UTC time>``;
    ``on_note`` gets one line per action), reject bad case files
    and run all missing cases together (:func:`run_locked_points`). The locks are released on return.

    Parameters
    ----------
    points : list of StorePoint
        The configurations with their manifests and plans (distinct store directories).
    execution : ExecutionConfig
        Where the cases run (the command line's overrides applied).
    client : distributed.Client, optional
        A connected client whose workers have the estimators already (a sweep's); default: a cluster is
        started or connected to for this run and closed after it.
    fresh, progress, wait
        As for :func:`submit`.
    on_note : callable
        Receives each line a store's preparation reports.
    client_hook : callable, optional
        See :data:`ClientHook` (only when the run starts its own cluster).
    quiet : bool
        Start an embedded cluster without its start-up lines (benchmarks).

    Returns
    -------
    StoresRun
        Per point, its store and the plan rows that were still to run; done and failed cases of this run.

    Raises
    ------
    RunStopped
        One line, when the run could not go on: the finished cases are compacted first (a cluster that
        cannot start leaves every store untouched).
    """
    stores = [CampaignStore(point.store_dir) for point in points]
    for point, store in zip(points, stores):
        store.check(point.manifest, point.plan, fresh=fresh)
    with ExitStack() as stack:
        new_lock_files = [store.lock_path for store in stores if not store.lock_path.exists()]
        lock_stores(points, stores, stack, fresh=fresh, wait=wait)
        if client is None and not fresh and all(store.has_every_case(point.manifest, point.plan)
                                                for point, store in zip(points, stores)):
            for store in stores:
                on_note(f"{store.root}: every planned case is done; no cluster started")
            return run_locked_points(None, points, stores, execution, on_note=on_note)
        if client is None:
            specs = [spec for point in points for spec in point.config.estimators]
            # the inputs every worker would load alike (planning loaded them here), pickled while the cluster starts
            shipped = InBackground(shippable_inputs, [point.config for point in points])
            try:
                client = stack.enter_context(cluster_session(execution, specs, client_hook=client_hook, quiet=quiet))
            except BaseException:           # refused before any store changed: leave nothing behind
                for path in new_lock_files:
                    path.unlink(missing_ok=True)        # still held: a waiter is refused by the directory lock
                shipped.wait()                  # no thread left computing while the interpreter exits
                raise
            client.register_plugin(ShippedInputs(shipped.result()))    # present and future workers
        return run_locked_points(client, points, stores, execution, fresh=fresh, progress=progress,
                                 on_note=on_note)


class InBackground:
    """``function(*arguments)`` run in a daemon thread from now on; :meth:`result` waits for it."""

    def __init__(self, function: Callable[..., Any], *arguments: Any):
        self._outcome: dict[str, Any] = {}
        self._thread = threading.Thread(target=self._run, args=(function, arguments), daemon=True,
                                        name=f"moc2dimes-{function.__name__}")
        self._thread.start()

    def _run(self, function: Callable[..., Any], arguments: tuple) -> None:
        try:
            self._outcome["value"] = function(*arguments)
        except BaseException as exc:    # handed to the caller of result(), raised there
            self._outcome["error"] = exc

    def wait(self) -> None:
        """Wait for the function to end (its value or exception is kept for :meth:`result`)."""
        self._thread.join()

    def result(self) -> Any:
        """The function's value, or its exception raised here."""
        self._thread.join()
        if "error" in self._outcome:
            raise self._outcome["error"]
        return self._outcome["value"]


@contextmanager
def cluster_session(execution: ExecutionConfig, specs: list[EstimatorSpec], *, client_hook: ClientHook | None = None,
                    quiet: bool = False) -> Iterator[Client]:
    """A connected client (:func:`~campaign.run.cluster.connected_client`) whose workers have the python
    plug-ins' code (RunStopped, one line, when a worker cannot import one: nothing changed); ``client_hook``'s
    context is entered first and left after the caller's block, before the cluster closes."""
    stores: set[Path] = set()
    _SESSION_STORES.append(stores)
    try:
        with connected_client(execution, quiet=quiet) as client:
            with client_hook(client) if client_hook is not None else nullcontext():
                try:
                    ship_plugin_code(client, specs)
                except PluginSetupError as problem:
                    raise RunStopped(f"run stopped before any case ran: {problem}") from None
                yield client
    finally:
        _SESSION_STORES.remove(stores)
        _remove_temporary_files(stores)       # the workers are stopped: a write they began will not end


_SESSION_STORES: list[set[Path]] = []
"""Per open :func:`cluster_session`, the stores its cases were submitted to (their temporary files are removed
when the session's cluster has closed: a run stopped or interrupted mid-write leaves none)."""
_LOCKED_HERE: set[Path] = set()
"""The stores whose writer lock this process holds (:func:`lock_stores`)."""


def _remove_temporary_files(stores: set[Path]) -> None:
    """Remove the ``cases/.tmp-*`` files of ``stores`` under their writer lock (held here already, or taken
    now; a store another writer has locked meanwhile is left to it)."""
    for root in sorted(stores):
        if root in _LOCKED_HERE:
            remove_temporary_files([root])
            continue
        try:
            with CampaignStore(root).lock(wait=False):
                remove_temporary_files([root])
        except (StoreBusy, OSError):
            pass


def lock_stores(points: list[StorePoint], stores: list[CampaignStore], locks: ExitStack, *, fresh: bool = False,
                wait: bool = False) -> None:
    """Take every store's lock in path order (held until ``locks`` closes; StoreBusy when another writer
    holds one, unless ``wait``), then check every store again under its lock (StoreError)."""
    for store in sorted(stores, key=lambda store: str(store.root)):
        try:
            locks.enter_context(store.lock(wait=wait, on_wait=lambda line: print(line, file=sys.stderr, flush=True)))
        except OSError as exc:
            if not is_infrastructure(exc):
                raise
            raise RunStopped(f"run stopped before any case ran: "
                             f"{storage_problem(exc, store.lock_path, 'writing the store lock')}") from None
        root = store.root
        _LOCKED_HERE.add(root)
        locks.callback(_LOCKED_HERE.discard, root)
    for point, store in zip(points, stores):
        store.check(point.manifest, point.plan, fresh=fresh)


def run_locked_points(client, points: list[StorePoint], stores: list[CampaignStore], execution: ExecutionConfig, *,
                      fresh: bool = False, progress: bool = True,
                      on_note: Callable[[str], None] = _print_note) -> StoresRun:
    """With the stores locked (:func:`lock_stores`) and the plug-ins shipped: prepare each store and cut its
    missing cases into tasks (:func:`~campaign.run.dask_runner.batch_cases`), run them all and compact
    the stores (RunStopped: the finished cases compacted first, as :func:`run_store_points` says)."""
    prepared: list[PreparedPoint] = []
    tasks: list = []
    done = failed = 0
    try:
        for point, store in zip(points, stores):
            for line in store.prepare(point.manifest, point.plan, fresh=fresh):
                on_note(line)
            finished = store.finished_case_ids()
            todo = [row for row in store.plan().to_dict("records") if int(row["case_id"]) not in finished]
            prepared.append(PreparedPoint(point, store, todo))
            if todo and client is None:
                raise RuntimeError(f"{store.root}: {len(todo)} cases to run and no cluster")  # has_every_case said none
            if todo:
                for session in _SESSION_STORES:
                    session.add(store.root)
                tasks += batch_cases(client, CampaignContext.from_config(point.config, store.root), todo, store)
        if tasks:
            tasks = balanced_tail(tasks, cluster_workers(client) or expected_workers(execution))
            done, failed = run_batches(client, tasks, Watch.from_execution(execution), progress)
    except RunStopped as stop:
        problems = {compact_after_stop(entry.store) for entry in prepared} - {""}
        raise RunStopped(f"{stop}{min(problems, default='')}") from None
    for entry in prepared:
        if entry.todo or entry.store.results_problem() is not None:
            compact_store(entry.store)
    return StoresRun(prepared, done, failed)


def compact_store(store: CampaignStore) -> None:
    """Compact ``store`` (results.parquet, timings.parquet, results.json) whole, a stop signal meanwhile
    raised after it; a full disk or another storage error is the machine's fault, not bad input:
    RunStopped (one line: the file, the cause, the fix; the finished cases stay in cases/)."""
    with held():
        try:
            store.compact()             # a failed write removes its own temporary file (store_files)
        except OSError as exc:
            if not is_infrastructure(exc):
                raise
            raise RunStopped(f"run stopped: {storage_problem(exc, store.results_path, 'writing results.parquet')}; "
                             f"the finished cases are kept in {store.root / 'cases'} and the next submit compacts "
                             "them") from None


def submit(config: CampaignConfig, scheduler: str | None = None, workers: int | None = None,
           fresh: bool = False, progress: bool = True, wait: bool = False) -> RunSummary:
    """Plan ``config`` and run its missing cases (:func:`run_store_points` with one point); return the run's
    summary (the caller writes the table: :func:`campaign.report.table.write_table`).

    Raises
    ------
    ConfigError
        Cluster settings or a class whose terrain cannot hold the footprints (nothing written).
    StoreError, StoreBusy, RunStopped
        As :func:`run_store_points`.
    """
    start = time.perf_counter()
    execution = config.execution.with_overrides(scheduler, workers)
    require_backend(execution, str(config.source))
    require_secure_transport(execution, str(config.source))
    if execution.cluster in SUBMIT_COMMANDS:
        require_submit_command(execution.cluster)       # before any lock or directory is made
    _, plan = plan_campaign(config)
    point = StorePoint(config, manifest_for(config), plan)
    run = run_store_points([point], execution, fresh=fresh, progress=progress, wait=wait)
    return RunSummary(run.submitted, run.done, run.failed, time.perf_counter() - start)


def compact_after_stop(store: CampaignStore) -> str:
    """Compact the finished cases of a stopped run; "" or the reason it could not (e.g. the disk is full)."""
    try:
        with held():
            store.compact()             # a failed write removes its own temporary file (store_files)
    except OSError as exc:
        return f" ({store.results_path} not rewritten: {exc.strerror or type(exc).__name__})"
    return ""
