"""Tuning a process for cases (glibc's malloc thresholds, one OpenCV thread), once per process.

Light on purpose (ctypes and OpenCV, 0.2 s): a dask worker runs :func:`tune_once` as it starts
(:class:`campaign.run.worker_startup.CaseWorkerSetup`), before it loads the simulator and the estimators
with its first case; :func:`campaign.case.inputs.campaign_inputs` tunes any other process that computes
cases (``campaign export``, the report's gallery, benchmarks).
"""
from __future__ import annotations

import cv2

from simulator.heap import keep_freed_buffers

_tuned = False


def keep_freed_memory_for_reuse() -> bool:
    """Ask glibc to recycle freed image buffers instead of returning them to the kernel at once.

    dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also freezes glibc's
    mmap threshold at 128 KiB: every 1024 x 1024 array is then a fresh ``mmap`` whose pages the
    kernel zero-fills on first touch, and a case runs 2.5 times slower (measured: 311 vs 125 ms),
    most of it as system time. :func:`simulator.heap.keep_freed_buffers` raises both thresholds (mmap
    32 MiB, the largest glibc accepts; trim 64 MiB), keeping a case's image buffers (4-12 MiB each) in the
    heap for reuse while larger scratch (terrain generation) is still returned at once, so a worker stays
    well under its memory limit; dask's value counts as unset, a user's own malloc setting stands. Returns
    False where there is no glibc (the setting is then simply not needed) or the user's setting stands.
    """
    return keep_freed_buffers()


def tune_process() -> None:
    """Tune this process for cases: keep freed image buffers for reuse, one OpenCV thread (one worker
    process per core: OpenCV's own threads would only contend)."""
    keep_freed_memory_for_reuse()
    cv2.setNumThreads(1)


def tune_once() -> None:
    """:func:`tune_process` unless this process is tuned already."""
    global _tuned
    if not _tuned:
        tune_process()
        _tuned = True
