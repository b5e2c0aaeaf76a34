"""Running cases on a worker process: the task's context, estimator set-up, retries, and writing cases'
rows (ok or failed) and example PNGs to the store.

A task (:func:`execute_batch`) carries only the small :class:`CampaignContext` and a batch of plan rows; the
big read-only inputs are loaded once per worker process (:func:`campaign.case.inputs.campaign_inputs`). A
case is computed by :func:`campaign.case.compute.compute_case` (or, in a no-op campaign, not at all:
:func:`campaign.case.compute.no_op_case`) and turned into rows by :func:`campaign.case.result_rows.case_rows`;
the batch's finished cases are written together (:func:`write_cases`).
"""
from __future__ import annotations

import functools
import os
import pickle
import socket
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from campaign.case.compute import EstimatorResult, compute_case, no_op_case
from campaign.case.inputs import CampaignInputs, PlanRow, campaign_inputs
from campaign.case.result_rows import case_rows
from campaign.configuration.campaign_file import CampaignConfig
from campaign.run.faults import InfrastructureError, describe, is_infrastructure
from campaign.run.plugin_setup import PluginSetupError, worker_address
from campaign.store.case_files import write_case_batch, write_case_rows
from campaign.store.case_identity import StoreIdentity
from estimators.plugins import EstimatorSetupError, build_estimator
from file_formats.descent_images import write_preview_png


def set_up_estimators(resources: CampaignInputs) -> None:
    """Build the campaign's estimators in this process once (``resources.built_estimators``).

    Raises
    ------
    PluginSetupError
        One line naming the estimator, this worker's address, the error and the fix, when one cannot be
        built here (:class:`estimators.plugins.EstimatorSetupError`); nothing is cached, the next task tries again.
    """
    if resources.built_estimators is not None:
        return
    built = []
    for spec in resources.config.estimators:
        try:
            built.append((spec, build_estimator(spec)))
        except EstimatorSetupError as exc:
            raise PluginSetupError(_on_worker(str(exc))) from None
    resources.built_estimators = built


def _on_worker(line: str) -> str:
    """A set-up error's line with this worker's address after the estimator's name."""
    head, _, rest = line.partition(": cannot be set up: ")
    return f"{head} cannot be set up on worker {worker_address()}: {rest}" if rest else f"{line} (worker {worker_address()})"


@dataclass(frozen=True)
class CampaignContext:
    """What every task needs besides its plan row (small and picklable).

    Attributes
    ----------
    config : CampaignConfig
        The validated campaign.
    config_hash : str
        Its configuration hash (the key of its inputs in the worker cache).
    store_root : str
        The campaign store's directory.
    """

    config: CampaignConfig
    config_hash: str
    store_root: str

    @classmethod
    def from_config(cls, config: CampaignConfig, store_root: Path) -> CampaignContext:
        return cls(config=config, config_hash=config.config_hash, store_root=str(store_root))

    def __reduce__(self):
        """Pickled as its fields' pickle, made once per object; a worker rebuilds the context once per process
        (:func:`context_from_pickle`) instead of once per task (about 2 ms of a loaded worker per case)."""
        return context_from_pickle, (self._fields_pickle,)

    @functools.cached_property
    def _fields_pickle(self) -> bytes:
        return pickle.dumps((self.config, self.config_hash, self.store_root), protocol=pickle.HIGHEST_PROTOCOL)


_CONTEXTS: dict[bytes, CampaignContext] = {}
"""The contexts this process has unpickled, by their fields' pickle (a campaign or sweep point each)."""


MAX_CONTEXTS = 32
"""Contexts kept per process: a sweep runs its points a batch at a time, so older ones are not needed again."""


def context_from_pickle(fields_pickle: bytes) -> CampaignContext:
    """The :class:`CampaignContext` of ``fields_pickle``, unpickled on its first use in this process (the
    :data:`MAX_CONTEXTS` most recently made are kept: a 10^4-point sweep must not grow a worker)."""
    context = _CONTEXTS.get(fields_pickle)
    if context is None:
        while len(_CONTEXTS) >= MAX_CONTEXTS:
            del _CONTEXTS[next(iter(_CONTEXTS))]
        context = _CONTEXTS[fields_pickle] = CampaignContext(*pickle.loads(fields_pickle))
    return context


def execute_case(context: CampaignContext, record: Mapping[str, Any]) -> str:
    """Run one case (a plan record) with retries and write its rows (ok or failed) to the store; return
    the status.

    First the campaign's estimators are built in this process (:func:`set_up_estimators`): a plug-in that
    cannot be loaded or started here raises :class:`~campaign.run.plugin_setup.PluginSetupError` and nothing
    is recorded for the case (the driver stops the run; the next submit runs the case again), as when a
    command's program cannot be started during the case.

    Only an exception of the case's own computation (:func:`~campaign.case.compute.compute_case`) is retried
    and then recorded ``failed``. A storage error (``OSError`` such as ENOSPC, EDQUOT, EROFS, EIO) or
    ``MemoryError``, in the computation or while writing the case file, is the machine's fault: nothing
    is recorded, the writes remove their own temporary files and
    :class:`~campaign.run.faults.InfrastructureError` is raised (the driver stops the run; the next
    submit runs the case again).

    A no-op campaign (``[execution] case_mode = "no_op"``) computes nothing: :func:`~campaign.case.compute.no_op_case`."""
    plan = PlanRow.from_record(record)
    rows, ok = case_result(context, plan)
    write_case(context, plan.case_id, rows, ok)
    return "ok" if ok else "failed"


FLUSH_S = 10.0
"""A task writes its finished cases to the store (one batch file) at least this often (s), every
:data:`FLUSH_CASES` cases and when it ends: a worker that dies loses at most this much computed work, a
store gets about one file per task, and a worker holds the rows of at most :data:`FLUSH_CASES` cases."""
FLUSH_CASES = 2000


def execute_batch(context: CampaignContext, rows: pa.Table | Sequence[Mapping[str, Any]]) -> tuple[int, int]:
    """Run a batch of cases (plan rows of one campaign, a table or records) one after the other, as :func:`execute_case`
    does each, and return (ok, failed) counts: the one task the driver submits
    (:mod:`campaign.run.dask_runner`).

    Finished cases are written together (:func:`write_cases`, one batch file) every :data:`FLUSH_S` seconds
    or :data:`FLUSH_CASES` cases and when the batch ends, and before an exception leaves the batch (an infrastructure error, a
    plug-in that cannot be set up): a batch that dies half-way keeps the cases it wrote; its other cases are
    not recorded and a rerun of the batch (dask's after a worker died, or the next submit's) writes them. A
    case written twice (the batch rerun after its worker died) supersedes its earlier record: same bits,
    except the run-dependent columns (worker, timings)."""
    records = rows.to_pylist() if isinstance(rows, pa.Table) else rows
    done = failed = 0
    finished: list[tuple[int, list[dict[str, Any]], bool]] = []
    oldest = time.monotonic()
    try:
        for record in records:
            plan = PlanRow.from_record(record)
            rows, ok = case_result(context, plan)
            if not finished:
                oldest = time.monotonic()
            finished.append((plan.case_id, rows, ok))
            done += ok
            failed += not ok
            if time.monotonic() - oldest >= FLUSH_S or len(finished) >= FLUSH_CASES:
                flushed, finished = finished, []
                write_cases(context, flushed)
    finally:
        if finished:            # also when a case raised: the cases before it are kept
            flushed, finished = finished, []
            write_cases(context, flushed)
    return done, failed


def case_result(context: CampaignContext, plan: PlanRow) -> tuple[list[dict[str, Any]], bool]:
    """A case's result rows (one per estimator) and whether it was simulated (False: recorded failed after
    its retries), computed with the retries of :func:`execute_case` (which says what is raised)."""
    config = context.config
    worker = f"{socket.gethostname()}:{os.getpid()}"
    started = time.perf_counter()
    if config.execution.case_mode == "no_op":
        rows = case_rows(plan, config.seed, no_op_case(config.estimator_names), None, attempts=1, worker=worker,
                         t_case_ms=1e3 * (time.perf_counter() - started))
        return rows, True
    attempts = config.execution.retries + 1
    error = ""
    computation = None
    for attempt in range(1, attempts + 1):
        try:
            resources = campaign_inputs(config)
            set_up_estimators(resources)
            computation = compute_case(resources, plan)
            if plan.case_in_class == 0:
                save_examples(Path(context.store_root), plan, computation.images_dn)
            attempts_used = attempt
            break
        except PluginSetupError:
            raise
        except EstimatorSetupError as exc:      # a command's program could not be started: set-up, not the case
            raise PluginSetupError(_on_worker(str(exc))) from None
        except Exception as exc:  # the case's own failure is recorded in its rows; the campaign goes on
            if is_infrastructure(exc):
                raise InfrastructureError(describe(exc, plan.case_id, "computing", worker, context.store_root)) from None
            where = [line.strip() for line in traceback.format_exc().splitlines() if line.strip().startswith("File ")]
            error = f"{type(exc).__name__}: {exc} | {where[-1] if where else ''}"
            attempts_used = attempt
    t_case_ms = 1e3 * (time.perf_counter() - started)
    if computation is None:
        estimates, truth = tuple(EstimatorResult.of_failed_case(name, error) for name in config.estimator_names), None
    else:
        estimates, truth = computation.estimates, computation.truth
    rows = case_rows(plan, config.seed, estimates, truth, attempts=attempts_used, worker=worker, t_case_ms=t_case_ms)
    return rows, computation is not None


def write_case(context: CampaignContext, case_id: int, rows: list[dict[str, Any]], ok: bool) -> None:
    """Durably write one case's rows to the store (:func:`~campaign.store.case_files.write_case_rows`);
    a storage error or ``MemoryError`` is :class:`~campaign.run.faults.InfrastructureError` (nothing recorded)."""
    config = context.config
    try:
        identity = StoreIdentity(context.config_hash, config.seed, tuple(config.estimator_names))
        write_case_rows(Path(context.store_root) / "cases", case_id, rows, ok=ok, identity=identity)
    except (OSError, MemoryError) as exc:       # the failed write removed its own temporary file
        worker = f"{socket.gethostname()}:{os.getpid()}"
        raise InfrastructureError(describe(exc, case_id, "writing its result", worker, context.store_root)) from None


def write_cases(context: CampaignContext, finished: Sequence[tuple[int, list[dict[str, Any]], bool]]) -> None:
    """Durably write finished cases, (case id, rows, ok) each, in one batch file
    (:func:`~campaign.store.case_files.write_case_batch`); a storage error or ``MemoryError`` is
    :class:`~campaign.run.faults.InfrastructureError` naming the first case (nothing of the batch recorded)."""
    config = context.config
    try:
        identity = StoreIdentity(context.config_hash, config.seed, tuple(config.estimator_names))
        write_case_batch(Path(context.store_root) / "cases", finished, identity)
    except (OSError, MemoryError) as exc:       # the failed write removed its own temporary file
        worker = f"{socket.gethostname()}:{os.getpid()}"
        what = "writing its result" if len(finished) == 1 else f"writing its result with {len(finished) - 1} more"
        raise InfrastructureError(describe(exc, finished[0][0], what, worker, context.store_root)) from None


def save_examples(store_root: Path, plan: PlanRow, images_dn: tuple[np.ndarray, ...]) -> None:
    """PNG examples of the first case of each class (for the report), written atomically."""
    directory = store_root / "examples"
    directory.mkdir(exist_ok=True)
    for index, image in enumerate(images_dn):
        target = directory / f"{plan.class_name}-case{plan.case_id:06d}-image{index + 1}.png"
        temporary = directory / f".tmp-{os.getpid()}-{target.name}"
        try:
            write_preview_png(temporary, image)
            os.replace(temporary, target)
        except BaseException:                  # e.g. a full disk: leave no temporary file behind
            temporary.unlink(missing_ok=True)
            raise
