"""The solution: agreement among a pair's matches, and among the pairs' IMU bias estimates.

Each matched template of an image pair (A, B) gives the ground offset ``d`` of B's view from the
IMU-predicted one, ``d = bias * (t_B - t_A)``. A wrong match (repetitive texture, a moving shadow,
noise) gives an unrelated ``d``, so a pair's answer is the largest group of matches that agree within
a tolerance, and it must hold a majority of the pair's good matches. The IMU bias is constant, so
the pairs must then agree with each other.
"""
from __future__ import annotations

import math

import numpy as np

_SCALAR_MATCHES = 12        # up to this many matches, the agreement test in Python scalars (fewer calls)


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

    Returns
    -------
    ndarray of int, shape (m,)
        Indices into ``displacements_m`` of the group; shape (0,) when there is none.
    """
    displacements_m = np.asarray(displacements_m, dtype=float).reshape(-1, 2)
    count = len(displacements_m)
    if count == 0:
        return np.zeros(0, dtype=int)
    weights = np.asarray(correlations, dtype=float).ravel()
    if count <= _SCALAR_MATCHES and np.isfinite(displacements_m).all() and np.isfinite(weights).all():
        # the same test in Python scalars: the norm of a 2-vector is sqrt(dx * dx + dy * dy), correctly rounded
        points, values = displacements_m.tolist(), weights.tolist()
        close_rows = [[math.sqrt((x - other_x) * (x - other_x) + (y - other_y) * (y - other_y)) <= tolerance_m
                       for other_x, other_y in points] for x, y in points]
        scores = [sum(row) + 1e-3 * min(max(value, -1.0), 1.0) for row, value in zip(close_rows, values)]
        seed = max(range(count), key=scores.__getitem__)            # the first largest, as np.argmax
        group = np.array([k for k, near in enumerate(close_rows[seed]) if near], dtype=np.intp)
    else:
        close = np.linalg.norm(displacements_m[:, None, :] - displacements_m[None, :, :], axis=-1) <= tolerance_m
        sizes = close.sum(axis=1)
        seed = int(np.argmax(sizes + 1e-3 * np.clip(weights, -1.0, 1.0)))
        group = np.flatnonzero(close[seed])
    if len(group) < min_count or (require_majority and 2 * len(group) <= count):
        return np.zeros(0, dtype=int)
    return group


def weighted_displacement(displacements_m: np.ndarray, correlations: np.ndarray) -> np.ndarray:
    """Correlation-weighted mean displacement of an agreeing group.

    Parameters
    ----------
    displacements_m : ndarray, shape (n, 2)
        Ground displacement of each match (m, east and north).
    correlations : ndarray, shape (n,)
        Their correlation peaks (weights, at least 1e-3).

    Returns
    -------
    ndarray, shape (2,)
        The weighted mean displacement (m).
    """
    weights = np.maximum(np.asarray(correlations, dtype=float), 1e-3)
    return (weights[:, None] * np.asarray(displacements_m, dtype=float)).sum(axis=0) / weights.sum()


def displacement_standard_error(displacements_m: np.ndarray, floor_m: float) -> float:
    """Standard error (per axis) of the mean of an agreeing group's displacements.

    Parameters
    ----------
    displacements_m : ndarray, shape (n, 2)
        Ground displacement of each match (m).
    floor_m : float
        Smallest standard error returned (m).

    Returns
    -------
    float
        The RMS per-axis sample standard deviation over sqrt(n), at least ``floor_m`` (m); ``floor_m``
        for a single match.
    """
    displacements_m = np.asarray(displacements_m, dtype=float).reshape(-1, 2)
    count = len(displacements_m)
    if count < 2:
        return float(floor_m)
    # ``displacements_m.var(axis=0, ddof=1).mean()`` written out with numpy's own steps (sum, divide, subtract,
    # square, sum, divide; the mean of the two a sum over 2): the same values without ``var``'s Python overhead
    deviations = displacements_m - np.add.reduce(displacements_m, axis=0, keepdims=True) / count
    np.multiply(deviations, deviations, out=deviations)
    east, north = (np.add.reduce(deviations, axis=0) / (count - 1)).tolist()
    spread = math.sqrt((east + north) / 2)                   # correctly rounded, as np.sqrt
    return max(spread / math.sqrt(count), float(floor_m))


def combine_pairs(biases_mps: np.ndarray, valid: np.ndarray, reasons: list[str], tolerance_mps: float,
                  require_all: bool) -> tuple[bool, str, np.ndarray]:
    """Combine the pairs' bias estimates.

    Parameters
    ----------
    biases_mps : ndarray, shape (P, 2)
        Each pair's IMU bias estimate (m/s, east and north).
    valid : ndarray of bool, shape (P,)
        Which pairs gave an estimate.
    reasons : list of str
        Each pair's reason (``"ok"`` when valid).
    tolerance_mps : float
        Largest allowed pairwise difference of the valid pairs' biases (m/s).
    require_all : bool
        Every pair must be valid (else at least one).

    Returns
    -------
    valid : bool
        The pairs are enough and agree.
    reason : str
        ``"ok"``; else the first failed pair's reason or ``"pairs_disagree"``.
    bias_mps : ndarray, shape (2,)
        Mean bias of the valid pairs (m/s); zero when not valid.
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


def velocity_uncertainty(heights_m: np.ndarray, intervals_s: np.ndarray, used_pairs: np.ndarray,
                         pair_sigmas_m: np.ndarray, pair_spread_mps: float, attitude_sigma_rad: float,
                         relative_attitude_sigma_rad: float, altitude_sigma_fraction: float,
                         ground_reach_m: np.ndarray) -> float:
    """Stated uncertainty of the estimated horizontal velocity (m/s).

    It is the RMS of the horizontal error magnitude, ``sqrt(2) sigma`` for a per-component standard
    deviation ``sigma``.

    The estimate is the mean bias of the used pairs, ``b = mean_k d_k / dt_k`` with ``d_k`` the
    displacement of pair ``k`` (images ``k``, ``k + 1``). Its error terms, added in quadrature:

    * a common attitude error ``e`` (sigma ``attitude_sigma_rad``) shifts image ``k`` by ``H_k e``:
      ``mean_k (H_k - H_{k+1}) / dt_k * e``;
    * independent image-to-image attitude noise ``e_j`` (sigma ``relative_attitude_sigma_rad``):
      coefficient of ``e_j`` is ``(H_j / dt_j [j a first image] - H_j / dt_{j-1} [j a second image]) / P``;
    * radar altitude errors (``altitude_sigma_fraction * H``) scale the ground grid about the nadir
      point: ``sigma_H / H * ground_reach_m`` per image, ``ground_reach_m`` the distance of the
      tracked ground from the nadir point;
    * the matches: ``pair_sigmas_m`` (standard error of each pair's mean displacement) / dt;
    * half the observed disagreement of the pairs' biases, ``pair_spread_mps / 2``.

    Parameters
    ----------
    heights_m : ndarray, shape (K,)
        Camera height per image (m).
    intervals_s : ndarray, shape (K - 1,)
        Time between consecutive images (s).
    used_pairs : ndarray of bool, shape (K - 1,)
        Pairs that enter the estimate.
    pair_sigmas_m : ndarray, shape (K - 1,)
        Standard error of each pair's displacement (m).
    pair_spread_mps : float
        Largest difference of the used pairs' biases (m/s).
    attitude_sigma_rad : float
        Common attitude error, 1 sigma (rad).
    relative_attitude_sigma_rad : float
        Image-to-image attitude noise, 1 sigma (rad).
    altitude_sigma_fraction : float
        Radar altitude error, 1 sigma, as a fraction of the altitude.
    ground_reach_m : ndarray, shape (K,)
        Distance of the tracked ground from the nadir point per image (m).

    Returns
    -------
    float
        The uncertainty (m/s); 0 when no pair is used.
    """
    heights_m = np.asarray(heights_m, dtype=float)
    intervals_s = np.asarray(intervals_s, dtype=float)
    used = np.flatnonzero(np.asarray(used_pairs, dtype=bool))
    if used.size == 0:
        return 0.0
    count = used.size
    common = sum((heights_m[k] - heights_m[k + 1]) / intervals_s[k] for k in used) / count
    coefficients = np.zeros(len(heights_m))
    altitude = np.zeros(len(heights_m))
    for k in used:
        coefficients[k] += heights_m[k] / intervals_s[k] / count
        coefficients[k + 1] -= heights_m[k + 1] / intervals_s[k] / count
        for j in (k, k + 1):
            altitude[j] += altitude_sigma_fraction * ground_reach_m[j] / intervals_s[k] / count
    matching = np.sqrt(sum((pair_sigmas_m[k] / intervals_s[k]) ** 2 for k in used)) / count
    variance = ((common * attitude_sigma_rad) ** 2 + relative_attitude_sigma_rad ** 2 * float(coefficients @ coefficients)
                + float(altitude @ altitude) + matching ** 2 + (0.5 * pair_spread_mps) ** 2)
    return float(np.sqrt(2.0 * variance))


def implied_bias_limit_mps(uncertainty_mps: float, imu_bias_sigma_mps: float, confidence: float) -> float:
    """Largest IMU horizontal velocity bias a valid answer may imply (m/s).

    The answer ``v = v_IMU - b`` implies the bias ``b``. For a right answer ``b`` is the IMU's true bias
    (normal, ``imu_bias_sigma_mps`` per axis) minus the answer's error (normal, ``uncertainty_mps /
    sqrt(2)`` per axis, ``uncertainty_mps`` being the RMS of the horizontal error magnitude), so
    ``|b|^2 / s^2`` with ``s^2 = imu_bias_sigma_mps^2 + uncertainty_mps^2 / 2`` is chi-square with two
    degrees of freedom, ``P(|b| > r s) = exp(-r^2 / 2)``.

    Parameters
    ----------
    uncertainty_mps : float
        The answer's stated uncertainty (RMS horizontal error magnitude, m/s).
    imu_bias_sigma_mps : float
        The IMU's horizontal bias, 1 sigma per axis (m/s).
    confidence : float
        Probability that a right answer's implied bias is within the limit; 1: no limit (inf).

    Returns
    -------
    float
        ``sqrt(-2 ln(1 - confidence)) * s`` (m/s).
    """
    if confidence >= 1.0:
        return float("inf")
    radius = float(np.sqrt(-2.0 * np.log1p(-confidence)))
    return radius * float(np.hypot(imu_bias_sigma_mps, uncertainty_mps / np.sqrt(2.0)))
