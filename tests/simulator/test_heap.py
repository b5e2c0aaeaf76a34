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


def _page_faults(mode: str) -> int:
    env_free = {"PYTHONPATH": ":".join(sys.path), "PATH": "/usr/bin:/bin", "NUMPY_MADVISE_HUGEPAGE": "0"}
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


def test_user_settings_stand(monkeypatch):
    monkeypatch.setattr(heap, "_state", {})
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "131072")
    assert heap.keep_freed_buffers() is False
