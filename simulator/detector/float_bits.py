"""Exact extremes and finiteness of float32 fields from their bit patterns, in compiled passes that vectorise.

For float32 values whose sign bit is clear (``+0.0``, positive numbers, ``+inf`` and NaNs without a sign),
the order of the values is the order of their bit patterns read as unsigned 32-bit integers, and a value
is not finite exactly when its pattern is at least that of ``+inf`` (``0x7F800000``). So the smallest and
largest pattern of a field, and the OR of all its patterns (whose top bit says whether any sign bit is
set), give the field's minimum, maximum and finiteness exactly: three integer reductions per value, which
the compiler vectorises (the float ``min`` / ``max`` it does not: ~0.6 ms against ~0.1 ms a 1024 x 1024
field here). A field with a sign bit somewhere (a negative value, ``-0.0``, ``-inf`` or a NaN with its
sign) is left to numpy (:func:`extremes`): rare, and the chain refuses a negative field anyway.

The running state of a field is a uint32 array of three entries (:func:`new_state`): smallest pattern,
largest pattern, OR of the patterns.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: The bit pattern of +inf: a pattern without a sign bit is not finite when at least this.
INF_BITS = 0x7F800000
SIGN_BIT = 0x80000000


def new_state(fields: int = 1) -> np.ndarray:
    """The running state of ``fields`` fields before any value.

    Parameters
    ----------
    fields : int, optional
        How many fields.

    Returns
    -------
    ndarray, uint32, shape (fields, 3)
        Per field: smallest pattern ``0xFFFFFFFF``, largest 0, OR 0.
    """
    state = np.zeros((fields, 3), dtype=np.uint32)
    state[:, 0] = 0xFFFFFFFF
    return state


@njit(cache=True, nogil=True, boundscheck=False)
def add_row(values, state):
    """Fold one C-contiguous float32 row into a field's state.

    Parameters
    ----------
    values : ndarray, shape (n,), float32
        The row (C-contiguous).
    state : ndarray, shape (3,), uint32
        Smallest and largest bit pattern so far and the OR of all of them; updated in place.
    """
    words = values.view(np.uint32)
    low, high, seen = state[0], state[1], state[2]
    for col in range(words.shape[0]):
        word = words[col]
        low = min(low, word)
        high = max(high, word)
        seen |= word
    state[0], state[1], state[2] = low, high, seen


def extremes(state: np.ndarray, field: np.ndarray) -> tuple[float, float]:
    """A field's (minimum, maximum) from its state, both NaN when a value is not finite.

    Parameters
    ----------
    state : ndarray, uint32, shape (3,)
        The field's state after all its rows (:func:`add_row`).
    field : ndarray, float32
        The field itself, read again (numpy) only when a value has its sign bit set.

    Returns
    -------
    (float, float)
        Minimum and maximum of the field, or (NaN, NaN) when it holds a NaN or an infinity.
    """
    low, high, seen = (int(value) for value in state)
    if seen & SIGN_BIT:     # a negative value, -0.0, -inf or a signed NaN: numpy's way (rare)
        if not np.isfinite(field).all():
            return float("nan"), float("nan")
        return float(np.min(field)), float(np.max(field))
    if high >= INF_BITS:
        return float("nan"), float("nan")
    return (float(np.array(low, dtype=np.uint32).view(np.float32)),
            float(np.array(high, dtype=np.uint32).view(np.float32)))
