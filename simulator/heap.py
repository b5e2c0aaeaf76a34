"""Keep freed frame-sized buffers in the process heap instead of returning them to the kernel.

A descent image allocates and frees a few dozen megapixel arrays (4 MiB float32 fields, 1 MiB masks,
work arrays of the camera chain). With glibc's default dynamic thresholds such arrays alternate between
``mmap`` and a heap top that is trimmed back to the kernel as soon as more than twice the last array is
free, so nearly every new array starts on fresh pages: a page fault per 4 KiB (and a transparent huge
page compaction where numpy asks for huge pages), paid again on every image. Measured on the fidelity
bench cases (default preset, 18 images, old and new alternated in fresh processes): the scene stage
takes 0.70-0.72 x the time with the thresholds below, with the same bits (only where memory comes from
changes).

Two ways to the same thresholds, glibc's ``M_MMAP_THRESHOLD`` = :data:`MMAP_THRESHOLD_BYTES` (arrays below it
come from the heap; the largest a frame stage allocates, a (1024, 1024, 3) float32 ray array, is 12 MiB) and
``M_TRIM_THRESHOLD`` = :data:`TRIM_THRESHOLD_BYTES` (at most that much free memory at the heap top is kept for
the next image):

- in a running process, :func:`keep_freed_buffers` sets them with ``mallopt``, once per process (the first
  image; a campaign worker as it starts);
- a process started for cases (a dask worker) gets them in its environment, :func:`case_process_environment`:
  glibc reads ``MALLOC_MMAP_THRESHOLD_`` and ``MALLOC_TRIM_THRESHOLD_`` when the process starts, so they hold
  from its first allocation. The same environment asks for one malloc arena (``MALLOC_ARENA_MAX=1``): glibc
  gives every new thread (a dask worker computes its cases in a thread of its own) an arena of its own, made
  of 64 MiB heaps that are unmapped whole as soon as they are free, whatever the trim threshold; with one
  arena the case thread allocates from the main heap like a one-thread process. Measured on the idle machine
  (2026-11-27, ``python -m benchmarks campaign``, single runs): the workers' median case 98-108 ms with their
  own arenas, 84-93 ms with one.

**Whose setting stands.** A glibc malloc setting of the user's (``MALLOC_MMAP_THRESHOLD_``,
``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_ARENA_MAX``, or ``malloc.`` tunables in ``GLIBC_TUNABLES``) is never
overridden: neither function touches the thresholds when either threshold variable or a malloc tunable is
set, and the environment leaves out ``MALLOC_ARENA_MAX`` when it is set. One value is not a user's:
dask's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536``
(:data:`DASK_NANNY_TRIM_THRESHOLD`, dask's default of ``distributed.nanny.pre-spawn-environ``) and, in the
process that runs an embedded cluster, writes it into that process's own environment; that value alone (no
mmap threshold beside it) counts as unset. A user who sets exactly 65536 themselves and nothing else gets
these thresholds instead (set ``MALLOC_MMAP_THRESHOLD_`` as well to keep glibc's own). Where the C library has
no ``mallopt`` (macOS, musl) :func:`keep_freed_buffers` does nothing; the environment variables are then
ignored by the C library.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
from collections.abc import Mapping

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024   # glibc's largest allowed value (HEAP_MAX_SIZE / 2 on 64-bit)
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
#: the trim threshold dask's nanny gives every worker process (``distributed.nanny.pre-spawn-environ``)
DASK_NANNY_TRIM_THRESHOLD = "65536"
_M_TRIM_THRESHOLD = -1                     # glibc malloc.h parameter numbers
_M_MMAP_THRESHOLD = -3
THRESHOLD_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
ARENA_VARIABLE = "MALLOC_ARENA_MAX"
#: the environment of a process started for cases (:func:`case_process_environment` leaves out the user's)
CASE_PROCESS_ENVIRONMENT = {"MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD_BYTES),
                            "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD_BYTES), ARENA_VARIABLE: "1"}

_state: dict[str, bool] = {}


def users_thresholds(environ: Mapping[str, str]) -> bool:
    """Tell whether ``environ`` holds malloc thresholds (or malloc tunables) of the user's (module doc).

    Any threshold variable or ``malloc.`` tunable counts, except dask's nanny trim threshold alone.

    Parameters
    ----------
    environ : mapping of str to str
        A process environment.

    Returns
    -------
    bool
        True when the user's malloc settings must stand.
    """
    if "malloc." in environ.get("GLIBC_TUNABLES", ""):
        return True
    given = {name: environ[name] for name in THRESHOLD_VARIABLES if name in environ}
    return bool(given) and given != {"MALLOC_TRIM_THRESHOLD_": DASK_NANNY_TRIM_THRESHOLD}


def thresholds_in_environment(environ: Mapping[str, str]) -> bool:
    """Tell whether ``environ`` sets exactly this module's thresholds (glibc applied them at the process's start).

    Parameters
    ----------
    environ : mapping of str to str
        A process environment.

    Returns
    -------
    bool
        True when both threshold variables hold :data:`CASE_PROCESS_ENVIRONMENT`'s values.
    """
    return all(environ.get(name) == CASE_PROCESS_ENVIRONMENT[name] for name in THRESHOLD_VARIABLES)


def case_process_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """Give the glibc malloc variables to start a process for cases with (module doc).

    Parameters
    ----------
    environ : mapping of str to str, optional
        The environment the process would otherwise inherit (default: this process's).

    Returns
    -------
    dict
        Name -> value, a subset of :data:`CASE_PROCESS_ENVIRONMENT`: both thresholds unless the user set
        thresholds or malloc tunables (:func:`users_thresholds`); ``MALLOC_ARENA_MAX`` unless set in
        ``environ`` or a malloc tunable is. The thresholds replace dask's nanny trim threshold.
    """
    environ = os.environ if environ is None else environ
    tunables = "malloc." in environ.get("GLIBC_TUNABLES", "")
    chosen = {}
    if not users_thresholds(environ):
        chosen.update({name: CASE_PROCESS_ENVIRONMENT[name] for name in THRESHOLD_VARIABLES})
    if ARENA_VARIABLE not in environ and not tunables:
        chosen[ARENA_VARIABLE] = CASE_PROCESS_ENVIRONMENT[ARENA_VARIABLE]
    return chosen


def keep_freed_buffers() -> bool:
    """Set the heap thresholds of the module doc in this process, once per process.

    Returns
    -------
    bool
        True when the thresholds are in effect (set now or before by this function, or given in the
        environment the process started with); False when the C library has no ``mallopt`` or the user set
        glibc malloc thresholds or tunables (:func:`users_thresholds`: theirs stand).
    """
    if "done" in _state:
        return _state["done"]
    _state["done"] = False
    if thresholds_in_environment(os.environ):      # glibc read them at start (a case process, e.g. a worker)
        _state["done"] = True
        return True
    if users_thresholds(os.environ):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _state["done"] = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                          and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _state["done"]
