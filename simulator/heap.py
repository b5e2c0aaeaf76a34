"""Keep freed frame-sized buffers in the process heap instead of returning them to the kernel.

A descent image allocates and frees a few dozen megapixel arrays (4 MiB float32 fields, 1 MiB masks,
work arrays of the camera chain). With glibc's default dynamic thresholds such arrays alternate between
``mmap`` and a heap top that is trimmed back to the kernel as soon as more than twice the last array is
free, so nearly every new array starts on fresh pages: a page fault per 4 KiB (and a transparent huge
page compaction where numpy asks for huge pages), paid again on every image. Measured on the fidelity
bench cases (default preset, 18 images, old and new alternated in fresh processes): the scene stage
takes 0.70-0.72 x the time with the thresholds below, with the same bits (only where memory comes from
changes).

:func:`keep_freed_buffers` sets, once per process, glibc's ``M_MMAP_THRESHOLD`` to
:data:`MMAP_THRESHOLD_BYTES` (arrays below it come from the heap; the largest a frame stage allocates,
a (1024, 1024, 3) float32 ray array, is 12 MiB) and ``M_TRIM_THRESHOLD`` to :data:`TRIM_THRESHOLD_BYTES`
(at most that much free memory at the heap top is kept for the next image). It does nothing on a C
library without ``mallopt`` (macOS, musl) or when the process was started with glibc's own
``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_`` (or ``GLIBC_TUNABLES`` malloc) settings (the user's choice stands).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024   # glibc's largest allowed value (HEAP_MAX_SIZE / 2 on 64-bit)
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
_M_TRIM_THRESHOLD = -1                     # glibc malloc.h parameter numbers
_M_MMAP_THRESHOLD = -3
_USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")

_state: dict[str, bool] = {}


def keep_freed_buffers() -> bool:
    """Set the heap thresholds of the module doc, once per process.

    Returns
    -------
    bool
        True when the thresholds are (now or already) set by this module; False when the C library has
        no ``mallopt`` or the process environment already sets glibc's malloc thresholds.
    """
    if "done" in _state:
        return _state["done"]
    _state["done"] = False
    if any(name in os.environ for name in _USER_SETTINGS) or "malloc." in os.environ.get("GLIBC_TUNABLES", ""):
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
