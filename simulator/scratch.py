"""Per-thread scratch arrays: reusable work arrays for full-frame intermediates that die inside one call.

The scene stage writes intermediates such as the upsampled planes of the ground map before their
division, an upsampled photometric ratio or flow before it is applied, and a supersampling sample's
field before it is summed, into these arrays instead of new allocations. A fresh 4 MiB array costs page
faults on first touch (measured ~1.5 ms here, more on a loaded machine), as much as the arithmetic.
Same operations, same bits.

A scratch array belongs to the thread and to its name, shape and dtype: the next request with the same
key returns the same memory, so a caller must be done with the contents before that key is asked for
again. The pool keeps :data:`SCRATCH_ARRAYS_KEPT` arrays per thread, least recently used dropped.

Each new array starts at its own 64-byte cache line within a 4 KiB page (:func:`staggered_empty`). Arrays
allocated one after another otherwise start at the same place in a page (their sizes are whole pages), and
a compiled pass that reads and writes several of them at the same index then maps them all onto the same
sets of the core's first-level cache and trips its 4 KiB store-to-load aliasing: measured 6 % of the
binned blur's rate-sum pass over three fields, 1-4 % of a moving camera image and 0-1 % of a still one.
"""
from __future__ import annotations

import threading

import numpy as np
from numpy.typing import DTypeLike

SCRATCH_ARRAYS_KEPT = 40         # per thread (least recently used dropped): the scene's and the camera chain's uses
CACHE_LINE_BYTES = 64
PAGE_BYTES = 4096
STAGGER_STEP_LINES = 8           # cache lines from one new array's start to the next one's (mod 63, coprime: all 63 used)
_scratch_pools = threading.local()


def scratch(name: str, shape: tuple[int, ...], dtype: DTypeLike = np.float32) -> np.ndarray:
    """A reusable work array of this thread for ``name``.

    Parameters
    ----------
    name : str
        What the array holds (e.g. ``"map_col"``); callers of one name share its memory.
    shape : tuple of int
        Shape of the array.
    dtype : numpy dtype, optional
        Element type (default float32).

    Returns
    -------
    ndarray, shape ``shape``
        Contents undefined, overwritten by the next caller of the same name, shape and dtype: for
        intermediates that never leave the function using them.
    """
    pool = getattr(_scratch_pools, "pool", None)
    if pool is None:
        pool = _scratch_pools.pool = {}
        _scratch_pools.made = 0
    key = (name, tuple(shape), np.dtype(dtype).str)
    array = pool.pop(key, None)
    if array is None:
        while len(pool) >= SCRATCH_ARRAYS_KEPT:
            del pool[next(iter(pool))]      # a caller still holding it keeps it alive
        array = staggered_empty(shape, dtype, _scratch_pools.made)
        _scratch_pools.made += 1
    pool[key] = array                       # most recently used last
    return array


def staggered_empty(shape: tuple[int, ...], dtype: DTypeLike, serial: int) -> np.ndarray:
    """A new C-contiguous array whose data starts at cache line ``1 + (8 serial mod 63)`` of a 4 KiB page.

    Parameters
    ----------
    shape : tuple of int
        Shape of the array.
    dtype : numpy dtype
        Element type (its size divides 64 bytes).
    serial : int
        Which array of the thread this is (0, 1, ...): consecutive ones start 8 cache lines apart, all 63 in turn.

    Returns
    -------
    ndarray, shape ``shape``
        Contents undefined; a view of a byte buffer one page longer than the data, 64-byte aligned.
    """
    element = np.dtype(dtype)
    size = int(np.prod(shape, dtype=np.int64)) * element.itemsize
    lines = PAGE_BYTES // CACHE_LINE_BYTES - 1
    offset = CACHE_LINE_BYTES * (1 + (STAGGER_STEP_LINES * serial) % lines)
    buffer = np.empty(size + PAGE_BYTES, dtype=np.uint8)
    start = (offset - buffer.ctypes.data) % PAGE_BYTES
    return buffer[start:start + size].view(element).reshape(shape)
