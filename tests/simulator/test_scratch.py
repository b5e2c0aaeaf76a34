"""Per-thread scratch arrays: reuse by key, and the placement of new arrays within a memory page."""
import threading

import numpy as np

from simulator import scratch as scratch_module
from simulator.scratch import CACHE_LINE_BYTES, PAGE_BYTES, scratch, staggered_empty


def _line_in_page(array: np.ndarray) -> int:
    return (array.ctypes.data % PAGE_BYTES) // CACHE_LINE_BYTES


def test_the_same_key_gives_the_same_memory_and_another_key_other_memory():
    first = scratch("test_reuse", (256, 1024))
    first[:] = 3.0
    again = scratch("test_reuse", (256, 1024))
    assert again is first
    other = scratch("test_reuse", (256, 1023))
    assert not np.shares_memory(other, first)
    assert scratch("test_reuse", (256, 1024), np.float64).dtype == np.float64


def test_new_arrays_start_on_distinct_cache_lines_of_a_page():
    """63 arrays of whole pages made one after another: 63 different cache lines, none at a page's start, each
    64-byte aligned, C-contiguous, writeable and of the asked shape and type."""
    arrays = [staggered_empty((256, 1024), np.float32, serial) for serial in range(63)]
    lines = [_line_in_page(array) for array in arrays]
    assert sorted(lines) == list(range(1, 64))
    for array in arrays:
        assert array.ctypes.data % CACHE_LINE_BYTES == 0
        assert array.shape == (256, 1024) and array.dtype == np.float32
        assert array.flags.c_contiguous and array.flags.writeable
    arrays[5][:] = 7.0                      # the arrays do not overlap
    assert all(not np.shares_memory(arrays[5], array) for index, array in enumerate(arrays) if index != 5)
    assert np.all(arrays[5] == 7.0)
    assert staggered_empty((0, 4), np.uint16, 3).shape == (0, 4)


def test_a_threads_consecutive_scratch_arrays_are_staggered():
    """Through :func:`scratch`: the arrays a fresh thread makes start 8 cache lines apart in turn."""
    found: list[int] = []

    def make() -> None:
        for index in range(5):
            found.append(_line_in_page(scratch(f"test_thread_{index}", (64, 1024))))
        found.append(int(scratch_module._scratch_pools.made))

    worker = threading.Thread(target=make)
    worker.start()
    worker.join()
    assert found[:5] == [1, 9, 17, 25, 33] and found[5] == 5
