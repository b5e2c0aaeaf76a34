"""simulator.heap: freed frame-sized arrays are reused from the heap instead of faulted in afresh."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from simulator import heap

_SCRIPT = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from simulator.heap import keep_freed_buffers
    if sys.argv[1] == "keep":
        assert keep_freed_buffers()
    if sys.argv[1] == "refused":
        assert not keep_freed_buffers()
    def frame_round():          # three 4 MiB fields alive at once, then all freed (as one image's stages do)
        arrays = [np.empty((1024, 1024), dtype=np.float32) for _ in range(3)]
        for array in arrays:
            array.fill(1.0)     # touch every page
    frame_round()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(10):
        frame_round()
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
""")


def _page_faults(mode: str, **environment: str) -> int:
    env_free = {"PYTHONPATH": ":".join(sys.path), "PATH": "/usr/bin:/bin", "NUMPY_MADVISE_HUGEPAGE": "0",
                **environment}
    result = subprocess.run([sys.executable, "-c", _SCRIPT, mode], capture_output=True, text=True, env=env_free,
                            check=True)
    return int(result.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt thresholds")
def test_freed_frames_are_reused_without_page_faults():
    # 10 rounds x 3 arrays x 1024 pages of 4 KiB: the default thresholds trim the 12 MiB freed at the heap
    # top after every round and fault it in again; with the thresholds set the rounds reuse the same pages
    default, kept = _page_faults("default"), _page_faults("keep")
    assert default > 10 * 1024
    assert kept < 500


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc settings")
def test_dasks_trim_threshold_is_replaced_and_the_case_environment_works_from_the_start():
    # a dask worker's environment (the nanny's 64 KiB trim threshold) faults every round in afresh ...
    assert _page_faults("default", MALLOC_TRIM_THRESHOLD_=heap.DASK_NANNY_TRIM_THRESHOLD) > 10 * 1024
    # ... keep_freed_buffers counts it as unset; the case environment needs no call at all
    assert _page_faults("keep", MALLOC_TRIM_THRESHOLD_=heap.DASK_NANNY_TRIM_THRESHOLD) < 500
    assert _page_faults("default", **heap.case_process_environment({})) < 500
    assert _page_faults("keep", **heap.case_process_environment({})) < 500


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc settings")
def test_a_users_thresholds_stand():
    # the user's 64 KiB trim threshold beside their mmap threshold: not dask's, so kept (and so are its faults)
    users = {"MALLOC_TRIM_THRESHOLD_": heap.DASK_NANNY_TRIM_THRESHOLD, "MALLOC_MMAP_THRESHOLD_": "131072"}
    assert _page_faults("refused", **users) > 10 * 1024


@pytest.mark.parametrize("environ, chosen", [
    ({}, heap.CASE_PROCESS_ENVIRONMENT),
    ({"MALLOC_TRIM_THRESHOLD_": "65536"}, heap.CASE_PROCESS_ENVIRONMENT),        # dask's nanny, not a user
    ({"MALLOC_TRIM_THRESHOLD_": "131072"}, {"MALLOC_ARENA_MAX": "1"}),
    ({"MALLOC_MMAP_THRESHOLD_": "65536"}, {"MALLOC_ARENA_MAX": "1"}),
    ({"MALLOC_ARENA_MAX": "8"}, {"MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "67108864"}),
    ({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1"}, {}),
    ({"GLIBC_TUNABLES": "glibc.rtld.nns=8"}, heap.CASE_PROCESS_ENVIRONMENT),
])
def test_case_process_environment_leaves_the_users_settings(environ, chosen):
    assert heap.case_process_environment(environ) == chosen


def test_user_settings_stand(monkeypatch):
    monkeypatch.setattr(heap, "_state", {})
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "131072")
    assert heap.keep_freed_buffers() is False
