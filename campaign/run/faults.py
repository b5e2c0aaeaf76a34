"""What stops a campaign run, as opposed to what fails one case.

A case *fails* (recorded ``failed`` after its retries, never retried by a later submit) only when its own
computation raises: the simulation of its images and measurements. Everything else is *infrastructure*
and never becomes a case's permanent record: the run stops, keeps every finished case, and the next
``campaign submit`` runs the unfinished ones:

- on the worker, :class:`InfrastructureError` (raised by :func:`campaign.run.worker.execute_case`): the case
  file could not be written (``OSError``: ENOSPC, EDQUOT, EROFS, EIO, ...), the computation hit a
  storage error of that kind, or ran out of memory (``MemoryError``);
- on the driver, :class:`RunStopped` (raised by :func:`campaign.run.dask_runner.run_batches`): a worker died
  running a case too often (``KilledWorker``), the scheduler was lost, no worker for
  ``no_workers_timeout_s``, every worker paused at its memory limit, or no case finished for
  ``stall_timeout_s``; or a storage error of the driver's own writes: the store's lock record and the
  compaction of ``results.parquet`` (:func:`campaign.run.orchestrate.compact_store`). Its message is one
  line: the cause, the file and the fix.
"""
from __future__ import annotations

import errno
import os

#: errno values of a storage or resource problem (never the case's own fault).
INFRASTRUCTURE_ERRNOS = frozenset(getattr(errno, name) for name in (
    "ENOSPC", "EDQUOT", "EROFS", "EIO", "ENOMEM", "EMFILE", "ENFILE", "ESTALE", "EFBIG", "ENOLCK", "ETIMEDOUT",
    "EREMOTEIO", "ENOTCONN", "EHOSTDOWN", "EHOSTUNREACH", "ENETDOWN", "ENETUNREACH") if hasattr(errno, name))

#: errno values of a full disk or an exhausted quota: exit 1 with the file and the fix wherever they happen
#: (a case write, the compaction of results.parquet, the store lock, a table), never "bad input"
FULL_DISK_ERRNOS = frozenset(getattr(errno, name) for name in ("ENOSPC", "EDQUOT") if hasattr(errno, name))

#: Peak memory of one case in a worker process (MiB), measured on Gusev (1024 x 1024 frames, optics PSF on: 576 MiB on 2026-11-25).
CASE_MEMORY_MIB = 600

_STORAGE_FIX = {
    errno.ENOSPC: "free space there or submit with another --output",
    errno.EROFS: "the file system is read-only: remount it read-write or submit with another --output",
    errno.EIO: "the disk reports I/O errors: check it, or submit with another --output",
}
if hasattr(errno, "EDQUOT"):
    _STORAGE_FIX[errno.EDQUOT] = "the disk quota is exhausted: free space or submit with another --output"


class InfrastructureError(RuntimeError):
    """Raised by a case task when storage or memory, not the case, failed (message: one line, cause and fix)."""


class RunStopped(RuntimeError):
    """The driver stopped the run: finished cases are kept; the message is one line, the cause and the fix."""


def storage_fix(exc: OSError) -> str:
    """What to do about the storage error ``exc`` (e.g. "free space there or submit with another --output")."""
    return _STORAGE_FIX.get(exc.errno or 0, "check the store's file system, or submit with another --output")


def storage_problem(exc: OSError, path: str | os.PathLike, what: str) -> str:
    """One line for a storage error ``exc`` while ``what`` (e.g. "writing results.parquet") at ``path``:
    the file, the cause and the fix."""
    return f"{exc.strerror or type(exc).__name__} while {what} ({os.fspath(path)}); {storage_fix(exc)}"


def is_infrastructure(exc: BaseException) -> bool:
    """True for an exception of the machine rather than of the case's computation."""
    return isinstance(exc, MemoryError) or (isinstance(exc, OSError) and exc.errno in INFRASTRUCTURE_ERRNOS)


def describe(exc: BaseException, case_id: int, what: str, worker: str, store: str = "") -> str:
    """One line for an infrastructure exception of case ``case_id`` while ``what`` (e.g. "computing",
    "writing its result") on ``worker``, whose store is ``store``."""
    if isinstance(exc, MemoryError):
        return (f"case {case_id} ran out of memory (MemoryError) on worker {worker}; raise [execution] memory_limit "
                f"or give the workers more memory (a case needs about {CASE_MEMORY_MIB} MiB)")
    if isinstance(exc, OSError):
        place = exc.filename or store
        text = exc.strerror or type(exc).__name__
        fix = storage_fix(exc)
        return f"case {case_id}: {text} while {what} on worker {worker} ({place}); {fix}"
    return f"case {case_id}: {type(exc).__name__} while {what} on worker {worker}: {exc}"
