"""Per-thread scratch arrays: reusable work arrays for full-frame intermediates that die inside one call.

The scene stage writes intermediates such as the upsampled planes of the ground map before their
division, an upsampled photometric ratio or flow before it is applied, and a supersampling sample's
field before it is summed, into these arrays instead of new allocations. A fresh 4 MiB array costs page
faults on first touch (measured ~1.5 ms here, more on a loaded machine), as much as the arithmetic.
Same operations, same bits.

A scratch array belongs to the thread and to its name, shape and dtype: the next request with the same
key returns the same memory, so a caller must be done with the contents before that key is asked for
again. The pool keeps :data:`SCRATCH_ARRAYS_KEPT` arrays per thread, least recently used dropped.
"""
from __future__ import annotations

import threading

import numpy as np
from numpy.typing import DTypeLike

SCRATCH_ARRAYS_KEPT = 40         # per thread (least recently used dropped): the scene's and the camera chain's uses
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
    key = (name, tuple(shape), np.dtype(dtype).str)
    array = pool.pop(key, None)
    if array is None:
        while len(pool) >= SCRATCH_ARRAYS_KEPT:
            del pool[next(iter(pool))]      # a caller still holding it keeps it alive
        array = np.empty(shape, dtype=dtype)
    pool[key] = array                       # most recently used last
    return array
