"""Shared timing helper for the benchmarks."""
from __future__ import annotations

import time

import numpy as np


def median_ms(function, repeats: int = 9) -> float:
    """Median wall time of ``function()`` in ms over ``repeats`` calls, after one warm-up call."""
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))
