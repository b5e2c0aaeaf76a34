"""The solution: agreement among a pair's matches, and among the pairs' IMU bias estimates.

Each matched template of an image pair (A, B) gives the ground offset ``d`` of B's view from the
IMU-predicted one, ``d = bias * (t_B - t_A)``. A wrong match (repetitive texture, a moving shadow,
noise) gives an unrelated ``d``, so a pair's answer is the largest group of matches that agree within
a tolerance, and it must hold a majority of the pair's good matches. The IMU bias is constant, so
the pairs must then agree with each other.
"""
from __future__ import annotations

import numpy as np


def consensus(displacements_m: np.ndarray, correlations: np.ndarray, tolerance_m: float, min_count: int,
              require_majority: bool) -> np.ndarray:
    """Indices of the agreeing group of matches, empty when there is none.

    Parameters
    ----------
    displacements_m : ndarray (n, 2)
        Ground displacement of each good match.
    correlations : ndarray (n,)
        Their correlation peaks (break ties between equally large groups).
    tolerance_m : float
        Matches within this distance of the group's seed agree.
    min_count : int
        Smallest acceptable group.
    require_majority : bool
        The group must hold more than half of the matches.
    """
    displacements_m = np.asarray(displacements_m, dtype=float).reshape(-1, 2)
    count = len(displacements_m)
    if count == 0:
        return np.zeros(0, dtype=int)
    close = np.linalg.norm(displacements_m[:, None, :] - displacements_m[None, :, :], axis=-1) <= tolerance_m
    sizes = close.sum(axis=1)
    seed = int(np.argmax(sizes + 1e-3 * np.clip(np.asarray(correlations, dtype=float), -1.0, 1.0)))
    group = np.flatnonzero(close[seed])
    if len(group) < min_count or (require_majority and 2 * len(group) <= count):
        return np.zeros(0, dtype=int)
    return group


def weighted_displacement(displacements_m: np.ndarray, correlations: np.ndarray) -> np.ndarray:
    """Correlation-weighted mean displacement (2,) of an agreeing group."""
    weights = np.maximum(np.asarray(correlations, dtype=float), 1e-3)
    return (weights[:, None] * np.asarray(displacements_m, dtype=float)).sum(axis=0) / weights.sum()


def combine_pairs(biases_mps: np.ndarray, valid: np.ndarray, reasons: list[str], tolerance_mps: float,
                  require_all: bool) -> tuple[bool, str, np.ndarray]:
    """Combine the pairs' bias estimates.

    Returns ``(valid, reason, bias (2,))``: the mean bias of the valid pairs when they are enough
    (all of them with ``require_all``, else at least one) and agree within ``tolerance_mps``
    (largest pairwise difference); otherwise invalid with the first failed pair's reason or
    "pairs_disagree", and a zero bias.
    """
    biases_mps = np.asarray(biases_mps, dtype=float).reshape(-1, 2)
    valid = np.asarray(valid, dtype=bool)
    failed = [reason for reason, ok in zip(reasons, valid) if not ok]
    if not valid.any() or (require_all and failed):
        return False, failed[0], np.zeros(2)
    good = biases_mps[valid]
    spread = float(np.linalg.norm(good[:, None, :] - good[None, :, :], axis=-1).max())
    if spread > tolerance_mps:
        return False, "pairs_disagree", np.zeros(2)
    return True, "ok", good.mean(axis=0)
