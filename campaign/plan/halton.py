"""The scrambled Halton sequence the planner spreads cases with, without importing ``scipy.stats``.

``scipy.stats.qmc.Halton(d, scramble=True, rng=default_rng(seed_sequence)).random(count)`` (scipy 1.17),
operation for operation: the engine owns a child generator spawned from the seed sequence; per dimension
(prime bases 2, 3, 5, ...) it shuffles ``ceil(54 / log2(base)) - 1`` copies of ``0 .. base - 1`` in turn
(Owen's random-permutation scrambling, A. B. Owen, "A randomized Halton algorithm in R", arXiv:1706.02808,
2017), and point ``i`` is ``sum_j perm_j[digit_j(i)] base^-(j+1)``, summed digit by digit from the lowest,
with ``base^-(j+1)`` formed by repeated division. So the plans are the same bits as with scipy's engine
(``tests/campaign/plan/test_halton.py`` compares them), and they stay so whatever scipy version is installed.

Why not scipy's engine: importing ``scipy.stats`` costs 0.64 s, in every command that plans (measured
2026-11-27, ``python -X importtime``); this module needs numpy only.
"""
from __future__ import annotations

import math

import numpy as np

PRIME_BASES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29)


def scrambled_halton(count: int, dimensions: int, seed_sequence: np.random.SeedSequence) -> np.ndarray:
    """The first ``count`` points of the scrambled Halton sequence in ``[0, 1)^dimensions``.

    Parameters
    ----------
    count : int
        Number of points (>= 0).
    dimensions : int
        Dimensions, 1 .. 10 (the first primes are the bases).
    seed_sequence : numpy.random.SeedSequence
        Seeds the permutations (spawns one child, as scipy's engine does from the generator it is given).

    Returns
    -------
    ndarray, shape (count, dimensions), float64
        The points; each prefix of the sequence is the same whatever ``count``.
    """
    if not 1 <= dimensions <= len(PRIME_BASES) or count < 0:
        raise ValueError(f"scrambled Halton: 1 to {len(PRIME_BASES)} dimensions and count >= 0; got {dimensions}, {count}")
    # scipy spawns from the seed sequence of the generator it is given: default_rng(seed_sequence) is a PCG64
    # holding seed_sequence itself
    rng = np.random.Generator(np.random.PCG64(seed_sequence.spawn(1)[0]))
    index = np.arange(count, dtype=np.int64)
    points = np.empty((count, dimensions))
    for dimension, base in enumerate(PRIME_BASES[:dimensions]):
        permutations = np.repeat(np.arange(base)[None], math.ceil(54 / math.log2(base)) - 1, axis=0)
        for permutation in permutations:
            rng.shuffle(permutation)
        value = np.zeros(count)
        quotient = index.copy()
        weight = 1.0 / base
        for permutation in permutations:
            value += permutation[quotient % base] * weight
            quotient //= base
            weight /= base
        points[:, dimension] = value
    return points
