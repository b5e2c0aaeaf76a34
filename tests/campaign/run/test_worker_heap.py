"""A campaign worker's heap (simulator.heap): a real worker of the embedded cluster, and the same worker after
its nanny restarts it, reports the malloc settings it started with and how its case thread's memory behaves:
freed frame-sized arrays reused without page faults, one malloc arena. The user's own settings stand."""
from __future__ import annotations

import ctypes
import os
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import dask
import numpy as np
import pytest

from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import case_worker_pre_spawn_environ, connected_client
from simulator import heap

REPO = Path(__file__).resolve().parents[3]
GLIBC = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc settings")
FRAME_ROUNDS = 10
PAGES_PER_ROUND = 3 * 1024        # three 4 MiB arrays of 4 KiB pages


def _frame_round() -> None:
    arrays = [np.empty((1024, 1024), dtype=np.float32) for _ in range(3)]   # as an image's stages allocate
    for array in arrays:
        array.fill(1.0)           # touch every page


def _malloc_arenas() -> int:
    """How many malloc arenas this process has (glibc's malloc_info report: one <heap nr=...> per arena)."""
    libc = ctypes.CDLL("libc.so.6")
    libc.open_memstream.restype = ctypes.c_void_p
    buffer, size = ctypes.c_void_p(), ctypes.c_size_t()
    stream = ctypes.c_void_p(libc.open_memstream(ctypes.byref(buffer), ctypes.byref(size)))
    libc.malloc_info(0, stream)
    libc.fclose(stream)
    report = ctypes.string_at(buffer.value, size.value).decode()
    libc.free(buffer)
    return report.count("<heap nr=")


def _case_thread_report() -> dict:
    """Run in a task (the worker's case thread): its environment, arenas and page faults over frame rounds."""
    _frame_round()
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    for _ in range(FRAME_ROUNDS):
        _frame_round()
    faults = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before
    return {"environment": {name: os.environ.get(name) for name in heap.CASE_PROCESS_ENVIRONMENT},
            "arenas": _malloc_arenas(), "page_faults": faults, "pid": os.getpid()}


@pytest.mark.cluster
@GLIBC
def test_embedded_workers_and_restarted_ones_keep_freed_frames_in_one_arena(monkeypatch):
    for name in (*heap.CASE_PROCESS_ENVIRONMENT, "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", heap.DASK_NANNY_TRIM_THRESHOLD)   # as an earlier nanny leaves it
    with connected_client(ExecutionConfig(workers=1), quiet=True) as client:
        first = client.submit(_case_thread_report, pure=False).result()
        assert os.environ.get("MALLOC_ARENA_MAX") is None                     # the driver's own is put back
        assert os.environ["MALLOC_TRIM_THRESHOLD_"] == heap.DASK_NANNY_TRIM_THRESHOLD
        client.restart()                                                      # the nanny spawns a new process
        second = client.submit(_case_thread_report, pure=False).result()
    assert second["pid"] != first["pid"]
    for report in (first, second):
        assert report["environment"] == heap.CASE_PROCESS_ENVIRONMENT
        assert report["arenas"] == 1                     # the case thread allocates from the main heap
        # the default thresholds (dask's 64 KiB trim) fault every round's pages in afresh: 30 720 faults
        assert report["page_faults"] < PAGES_PER_ROUND // 6


@GLIBC
def test_a_task_thread_with_its_own_arena_faults_its_frames_in_afresh():
    """The control of the test above, without a cluster: dask's trim threshold and a thread's own arena."""
    script = textwrap.dedent("""
        import threading, sys
        from tests.campaign.run.test_worker_heap import _case_thread_report
        out = []
        thread = threading.Thread(target=lambda: out.append(_case_thread_report()))
        thread.start(); thread.join()
        print(out[0]["page_faults"], out[0]["arenas"])
    """)
    environment = {"PYTHONPATH": ":".join(sys.path), "PATH": "/usr/bin:/bin", "NUMPY_MADVISE_HUGEPAGE": "0",
                   "MALLOC_TRIM_THRESHOLD_": heap.DASK_NANNY_TRIM_THRESHOLD}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=environment,
                            check=True, cwd=REPO)
    faults, arenas = map(int, result.stdout.split())
    assert faults > FRAME_ROUNDS * PAGES_PER_ROUND * 0.9 and arenas >= 2


def test_dask_nanny_trim_threshold_is_dasks_default():
    """The value simulator.heap counts as dask's, not a user's, is the one dask ships."""
    shipped = [defaults["distributed"]["nanny"]["pre-spawn-environ"] for defaults in dask.config.defaults
               if "pre-spawn-environ" in defaults.get("distributed", {}).get("nanny", {})]
    assert [str(values["MALLOC_TRIM_THRESHOLD_"]) for values in shipped] == [heap.DASK_NANNY_TRIM_THRESHOLD]


def test_the_users_settings_stand_in_the_workers_environment():
    with dask.config.set({"distributed.nanny.pre-spawn-environ": {"MALLOC_TRIM_THRESHOLD_": 65536,
                                                                  "OMP_NUM_THREADS": 1}}):
        ours = case_worker_pre_spawn_environ({})
        assert ours == {"OMP_NUM_THREADS": 1, **heap.CASE_PROCESS_ENVIRONMENT}
        users_shell = case_worker_pre_spawn_environ({"MALLOC_MMAP_THRESHOLD_": "131072", "MALLOC_ARENA_MAX": "4"})
        assert users_shell == {"MALLOC_TRIM_THRESHOLD_": 65536, "OMP_NUM_THREADS": 1}   # the nanny passes theirs on
        tunables = case_worker_pre_spawn_environ({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"})
        assert tunables == {"MALLOC_TRIM_THRESHOLD_": 65536, "OMP_NUM_THREADS": 1}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": {"MALLOC_TRIM_THRESHOLD_": 1 << 20}}):
        assert case_worker_pre_spawn_environ({}) == {"MALLOC_TRIM_THRESHOLD_": 1 << 20, "MALLOC_ARENA_MAX": "1"}
