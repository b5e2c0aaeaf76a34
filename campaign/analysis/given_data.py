"""Moment-independent sensitivity indices from given data: PAWN (Pianosi & Wagener 2015, 2018), the expected
Kolmogorov-Smirnov distance between an output's distribution and its distribution with one input fixed.

For an input ``X_i`` and an output ``Y`` from the same ``n`` cases (no design: the campaign's cases as they
were drawn), the cases are split into conditioning slices of ``X_i`` -- equal-count quantile slices of a
continuous input, one slice per value of a categorical or few-valued input -- and the index is

    T_i = sum_s (n_s / n) * KS(Y | X_i in slice s, Y),
    KS(A, B) = max_y |F_A(y) - F_B(y)|,

the Kolmogorov-Smirnov statistic between the empirical CDF of the slice's outputs and that of all outputs,
averaged over the slices weighted by their sizes (for equal-count slices SALib's ``pawn.analyze`` "mean").
``T_i`` is 0 when ``Y`` does not depend on ``X_i`` (up to sampling noise) and at most 1. For a yes/no output
(valid, false-valid) the KS distance of a slice is ``|P(Y=1 | slice) - P(Y=1)|``, so ``T_i`` is Borgonovo's
moment-independent delta of a binary output.

Why this estimator: it needs no sampling design (every campaign's cases are given data), no independence
between inputs (the trajectory parameters come from EDL simulations and are correlated; a given-data
conditional-distribution index stays well defined for dependent inputs -- it then measures what knowing
``X_i`` tells about ``Y``, including through the inputs correlated with it; variance-based Sobol indices
estimated with Saltelli's scheme assume independent inputs and a design, so they are used only for designed
sweeps), and it treats a yes/no output and a heavy-tailed error alike (a CDF distance, no variance or
density).

Two uncertainties are reported per index:

- a bootstrap interval: cases resampled with replacement, the slices re-cut, the index recomputed, the
  percentile interval shifted by the replicates' bias (a resample repeats cases, which raises a KS
  distance: for an input without effect the raw replicates lie almost wholly above the index itself);
- a permutation p-value against "no effect": the outputs shuffled against the input, which keeps the
  slices' sizes and the outputs' ties, so it gives the index's distribution when ``Y`` does not depend on
  ``X_i`` (an index of a few hundred cases is biased upwards by ~1/sqrt(n_s)). An input whose p-value,
  Holm-corrected over the inputs of one output, is above ``alpha`` is marked indistinguishable from noise.

The computation is vectorised here (thousands of bootstrap and permutation replicates per input); it is
checked against SALib's ``pawn.analyze`` and against closed forms in tests/campaign/analysis.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_SLICES = 10
MIN_CASES_PER_SLICE = 25
CATEGORICAL_MAX_VALUES = 10
"""An input with at most this many distinct values is conditioned value by value (a class, a yes/no flag)."""


@dataclass(frozen=True)
class IndexEstimate:
    """One input's PAWN index for one output.

    Attributes
    ----------
    index : float
        Expected KS distance ``T_i`` (0 to 1).
    low, high : float
        Bias-corrected bootstrap percentile interval of ``index`` at the analysis's confidence level.
    p_value : float
        Permutation p-value of "the output does not depend on this input" (uncorrected).
    slices : int
        Conditioning slices used.
    categorical : bool
        Conditioned value by value rather than on quantile slices.
    """

    index: float
    low: float
    high: float
    p_value: float
    slices: int
    categorical: bool


def slice_count(cases: int) -> int:
    """Quantile slices for ``cases`` cases: 10 (SALib's default) when there are at least 25 cases per slice,
    fewer for smaller campaigns, never fewer than 2."""
    return int(min(MAX_SLICES, max(2, cases // MIN_CASES_PER_SLICE)))


def is_categorical(values: np.ndarray) -> bool:
    """Whether ``values`` is conditioned value by value: non-numeric, or at most
    :data:`CATEGORICAL_MAX_VALUES` distinct values."""
    values = np.asarray(values)
    return values.dtype.kind not in "fiub" or np.unique(values).size <= CATEGORICAL_MAX_VALUES


def slice_labels(values: np.ndarray, slices: int, categorical: bool) -> np.ndarray:
    """Conditioning slice (0..k-1) of each case, shape (n,): the value's rank among the distinct values of a
    categorical input, else the equal-count quantile slice of the case's rank (ties broken by position)."""
    values = np.asarray(values)
    if categorical:
        return np.unique(values, return_inverse=True)[1].reshape(-1)
    ranks = np.empty(values.size, dtype=np.int64)
    ranks[np.argsort(values, kind="stable")] = np.arange(values.size)
    return (ranks * slices) // values.size


def _ks_to_all(outputs_sorted_groups: np.ndarray, labels_sorted: np.ndarray, slices: int) -> np.ndarray:
    """KS distance of each slice's outputs to all outputs, shape (slices,).

    ``labels_sorted`` are the slice labels of the cases in increasing order of the output; the empirical CDFs
    are compared at the last case of each run of equal outputs (``outputs_sorted_groups``: those positions).
    """
    cases = labels_sorted.size
    one_hot = np.zeros((slices, cases), dtype=np.float64)
    one_hot[labels_sorted, np.arange(cases)] = 1.0
    counts = one_hot.sum(axis=1)
    cumulative = np.cumsum(one_hot, axis=1)[:, outputs_sorted_groups]
    with np.errstate(invalid="ignore", divide="ignore"):
        slice_cdf = cumulative / counts[:, None]
    all_cdf = (outputs_sorted_groups + 1.0) / cases
    distance = np.abs(slice_cdf - all_cdf[None, :]).max(axis=1)
    return np.where(counts > 0, distance, np.nan)


def _group_ends(outputs_sorted: np.ndarray) -> np.ndarray:
    """Positions of the last case of each run of equal values in a sorted output vector."""
    return np.flatnonzero(np.append(outputs_sorted[1:] != outputs_sorted[:-1], True))


def pawn_index(inputs: np.ndarray, outputs: np.ndarray, slices: int | None = None,
               categorical: bool | None = None) -> float:
    """The expected KS index ``T_i`` of one input (module docstring).

    Parameters
    ----------
    inputs : numpy.ndarray
        The input's value per case, shape (n,).
    outputs : numpy.ndarray
        The output per case, shape (n,), finite.
    slices : int, optional
        Quantile slices of a continuous input (default :func:`slice_count`).
    categorical : bool, optional
        Condition value by value (default :func:`is_categorical`).
    """
    outputs = np.asarray(outputs, dtype=float)
    categorical = is_categorical(inputs) if categorical is None else categorical
    labels = slice_labels(inputs, slices or slice_count(outputs.size), categorical)
    return _weighted_index(labels, outputs)


def _weighted_index(labels: np.ndarray, outputs: np.ndarray) -> float:
    order = np.argsort(outputs, kind="stable")
    ends = _group_ends(outputs[order])
    slices = int(labels.max()) + 1
    distances = _ks_to_all(ends, labels[order], slices)
    weights = np.bincount(labels, minlength=slices) / labels.size
    return float(np.nansum(weights * distances))


def analyse_input(inputs: np.ndarray, outputs: np.ndarray, rng: np.random.Generator, *,
                  resamples: int = 300, permutations: int = 2000, confidence: float = 0.95,
                  slices: int | None = None, null: np.ndarray | None = None) -> IndexEstimate:
    """One input's index with its bootstrap interval and permutation p-value.

    Parameters
    ----------
    inputs, outputs : numpy.ndarray
        Shape (n,) each; ``outputs`` finite.
    rng : numpy.random.Generator
        Source of the resamples and permutations (same seed, same numbers).
    resamples, permutations : int
        Bootstrap replicates of the interval; permutations of the null distribution.
    confidence : float
        Level of the interval (0.95: the 2.5 and 97.5 percentiles).
    slices : int, optional
        Quantile slices (default :func:`slice_count`).
    null : numpy.ndarray, optional
        A null distribution already computed for the same slices (the permutation null of a continuous input
        depends only on ``n``, the slice count and the outputs, so one serves every continuous input).
    """
    outputs = np.asarray(outputs, dtype=float)
    cases = outputs.size
    categorical = is_categorical(inputs)
    slices = slices or slice_count(cases)
    labels = slice_labels(inputs, slices, categorical)
    index = _weighted_index(labels, outputs)
    replicates = np.empty(resamples)
    inputs = np.asarray(inputs)
    for replicate in range(resamples):
        chosen = rng.integers(0, cases, cases)
        replicates[replicate] = _weighted_index(slice_labels(inputs[chosen], slices, categorical), outputs[chosen])
    tail = (1.0 - confidence) / 2.0
    bias = replicates.mean() - index
    low, high = np.clip(np.quantile(replicates, [tail, 1.0 - tail]) - bias, 0.0, 1.0)
    if null is None or categorical:
        null = permutation_null(labels, outputs, rng, permutations)
    p_value = (1.0 + np.count_nonzero(null >= index - 1e-12)) / (1.0 + null.size)
    return IndexEstimate(index, float(low), float(high), float(p_value), int(labels.max()) + 1, categorical)


def permutation_null(labels: np.ndarray, outputs: np.ndarray, rng: np.random.Generator,
                     permutations: int = 2000) -> np.ndarray:
    """The index's distribution when the output does not depend on the input: ``permutations`` indices of
    the slice labels ``labels`` against shuffled outputs, shape (permutations,)."""
    outputs = np.asarray(outputs, dtype=float)
    order = np.argsort(outputs, kind="stable")
    ends = _group_ends(outputs[order])
    slices = int(labels.max()) + 1
    weights = np.bincount(labels, minlength=slices) / labels.size
    null = np.empty(permutations)
    for permutation in range(permutations):
        shuffled = rng.permutation(labels)
        null[permutation] = np.nansum(weights * _ks_to_all(ends, shuffled, slices))
    return null


def continuous_null(outputs: np.ndarray, rng: np.random.Generator, permutations: int = 2000,
                    slices: int | None = None) -> np.ndarray:
    """The permutation null shared by every continuous input of one output (:func:`permutation_null` of
    equal-count quantile slices)."""
    outputs = np.asarray(outputs, dtype=float)
    labels = slice_labels(np.arange(outputs.size, dtype=float), slices or slice_count(outputs.size), False)
    return permutation_null(labels, outputs, rng, permutations)


def holm_noise(p_values: np.ndarray, alpha: float = 0.05) -> np.ndarray:
    """Holm's step-down correction over one output's inputs: True where an input's effect is
    indistinguishable from noise (not rejected at family-wise level ``alpha``), shape like ``p_values``."""
    p_values = np.asarray(p_values, dtype=float)
    order = np.argsort(p_values, kind="stable")
    noise = np.ones(p_values.size, dtype=bool)
    for rank, position in enumerate(order):
        if p_values[position] > alpha / (p_values.size - rank):
            break
        noise[position] = False
    return noise
