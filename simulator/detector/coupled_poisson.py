"""Exact Poisson shot noise coupled to the Gaussian default's normal deviates (common random numbers).

The default preset reads a pixel of mean charge ``m`` out as ``m + sqrt(m + s^2) z`` (shot and read
noise merged into one float32 normal deviate ``z`` per pixel, :mod:`simulator.detector.readout`, read
noise ``s`` e- rms). The exact presets (``reference``, ``high``: ``exact_poisson``) draw the same ``z``
from the same stream (the same first call, :func:`simulator.detector.readout.standard_normal_f32`),
one more standard normal ``e`` per pixel, and rotate the pair::

    b = s / sqrt(m + s^2),   a = sqrt(1 - b^2)
    u = a z + b e            (shot-noise deviate)
    v = b z - a e            (read-noise deviate)
    charge = F^-1(Phi(u); m) + s v

``(u, v)`` is an orthogonal rotation of two independent standard normals, so ``u`` and ``v`` are
independent standard normals: the shot noise ``F^-1(Phi(u); m)`` (``F`` the Poisson CDF of mean ``m``,
``Phi`` the standard normal CDF) is exactly Poisson(``m``) (inversion), and the read noise ``s v`` is
Gaussian and independent of it: the exact presets' noise model is unchanged in distribution. In the
Gaussian limit ``F^-1(Phi(u); m) ~ m + sqrt(m) u``, so the charge is
``m + (sqrt(m) a + s b) z + (sqrt(m) b - s a) e = m + sqrt(m + s^2) z``: the exact draw equals the
default's up to the Poisson skewness and the integer count (``(u^2 - 1) / 6`` e- and a rounding
residual: 0.37 e- RMS, against 150 e- per DN) and the difference of the presets' means. Compared on the same seeds, the presets' images then differ by
their rendering, not by independent noise realisations. (Pixels below
:data:`~simulator.detector.readout.GAUSSIAN_MIN_MEAN_E`, which the default draws with numpy's Poisson
sampler whose bits it keeps, are not coupled: their shot noise is below 0.21 DN.)

The inversion (:func:`poisson_quantile`) is exact: the count ``k`` is the smallest with
``F(k; m) >= Phi(u)``. Above :data:`EXPANSION_MIN_MEAN_E` it starts from the Cornish-Fisher expansion
of the continuous quantile ``y`` (``F(k; m) = Q(k + 1, m)``, regularised upper incomplete gamma, solved
for its shape ``y + 1``)::

    y + 1 = m + sqrt(m) u + (u^2 + 2) / 6 - (u^3 + 2 u) / (72 sqrt(m))
              + (3 u^4 + 7 u^2 - 16) / (810 m) - (207 u^5 + 548 u^3 - 2684 u) / (155520 m^1.5)

(the expansion of ``Gamma(y + 1)``'s quantile inverted in its shape; its error is below 2e-4 counts
for ``m >= 1000`` and ``|u| <= 8``, below 2e-8 from ``m = 1e5``, falling as ``1 / m^2``: checked against
mpmath). ``k = ceil(y)`` wherever ``y`` lies more than :data:`BOUNDARY_MARGIN` (50x that error) from an
integer; the ~2 % of pixels nearer an integer are decided by one exact CDF evaluation
(``scipy.special.pdtr``/``pdtrc``), except where scipy's CDF is itself inaccurate (upper tail beyond
:data:`SCIPY_TAIL_MAX_DEVIATE` at means above :data:`SCIPY_TAIL_MAX_MEAN_E`; :data:`MAX_CHECKED_MEAN_E`):
there the expansion (error < 2e-8 counts) decides alone, so the count can differ from the exact quantile
only with a probability below 1e-12 per pixel. Dim pixels from :data:`DIM_MIN_MEAN_E` take the expansion
too for ``|u| <=`` :data:`DIM_MAX_DEVIATE`, with a wider margin (its error grows as ``1 / m^2``). Dimmer
pixels sum the CDF from 0 (the pmf recursion); the rare larger deviates step along the exact CDF from an
expansion guess (one CDF value and the pmf recursion). Above :data:`MAX_POISSON_MEAN_E` the mean itself is returned (no shot noise).
"""
from __future__ import annotations

import numpy as np

from simulator.scratch import scratch

#: Means (e-) from which the inversion starts from the Cornish-Fisher expansion for ``|u| <=``
#: :data:`EXPANSION_MAX_DEVIATE` (error < 2e-4 counts), with the margin :data:`BOUNDARY_MARGIN`.
EXPANSION_MIN_MEAN_E = 1000.0
EXPANSION_MAX_DEVIATE = 8.0
#: Distance (counts) of the expansion's continuous quantile to an integer below which the exact CDF decides.
BOUNDARY_MARGIN = 0.01
#: Dim pixels from this mean (e-) to :data:`EXPANSION_MIN_MEAN_E` take the expansion too for ``|u| <=``
#: :data:`DIM_MAX_DEVIATE` (error < 1.3e-3 (100 / m)^2 counts), with the margin ``DIM_MARGIN_E2 / m^2``
#: (50x that error: 6.5 % at 100 e-); dimmer pixels and larger deviates search the exact CDF.
DIM_MIN_MEAN_E = 100.0
DIM_MAX_DEVIATE = 5.0
DIM_MARGIN_E2 = 650.0
#: Means (e-) above which the expansion's count is taken without an exact check (float64 rounding of
#: ``y`` there nears the margin; 10x the camera file's largest full well).
MAX_CHECKED_MEAN_E = 1.0e11
#: scipy's Poisson CDF (``pdtr``/``pdtrc``, cephes ``igam``) loses accuracy in the upper tail beyond about
#: 4.5 sigma at large means (relative error of the tail 1e-5 at 1e6 e-, 4e-2 at 1e7, 0.4 at 1e8, measured
#: against a direct pmf sum; accurate to 1e-10 up to 1e5 e- and on the lower tail): above this mean and
#: beyond :data:`SCIPY_TAIL_MAX_DEVIATE` the expansion decides alone.
SCIPY_TAIL_MAX_MEAN_E = 1.0e5
SCIPY_TAIL_MAX_DEVIATE = 4.0
#: Means (e-) above which the mean itself is returned (no shot noise; as readout.MAX_POISSON_MEAN_E).
MAX_POISSON_MEAN_E = 1.0e18


def coupled_shot_and_read_noise_e(deviate: np.ndarray, rng: np.random.Generator, mean_e: np.ndarray,
                                  read_sigma_e: float) -> np.ndarray:
    """Exact Poisson shot noise plus Gaussian read noise, from the default preset's normal deviates.

    With read noise, draws ``e = rng.standard_normal(shape)`` and returns ``F^-1(Phi(u); m) + s v``
    (module doc); without, ``F^-1(Phi(z); m)``.

    Parameters
    ----------
    deviate : ndarray, float32 or float64, shape of ``mean_e``
        ``z``: the standard normal deviates the default preset draws first from the same stream
        (:func:`simulator.detector.readout.standard_normal_f32`).
    rng : numpy.random.Generator
        The noise stream after ``z`` (the read-noise partner ``e``).
    mean_e : ndarray
        Expected charge per binned pixel (e-), >= 0 (NaN refused).
    read_sigma_e : float
        Output-amplifier noise (e- rms), >= 0; 0 draws no ``e``.

    Returns
    -------
    ndarray, float64, shape of ``mean_e``
        Charge (e-).
    """
    mean = np.asarray(mean_e, dtype=np.float64)
    if not read_sigma_e:
        return poisson_quantile(np.asarray(deviate, dtype=np.float64), mean)
    shape = mean.shape
    # this thread's scratch arrays "poisson_a".."poisson_f" (a fresh full-frame array costs page faults): here
    # a = e, b = b then v, c = a, d = work, e = u; the quantile reuses a, c, d (dead by then) and f
    other = rng.standard_normal(out=scratch("poisson_a", shape, np.float64))    # e
    read_share = np.add(mean, read_sigma_e ** 2, out=scratch("poisson_b", shape, np.float64))
    np.sqrt(read_share, out=read_share)
    np.divide(read_sigma_e, read_share, out=read_share)           # b = s / sqrt(m + s^2) (0 where m is infinite)
    shot_share = np.multiply(read_share, read_share, out=scratch("poisson_c", shape, np.float64))
    np.subtract(1.0, shot_share, out=shot_share)
    np.sqrt(shot_share, out=shot_share)                           # a = sqrt(1 - b^2)
    work = scratch("poisson_d", shape, np.float64)
    shot_deviate = np.multiply(shot_share, deviate, out=scratch("poisson_e", shape, np.float64))
    shot_deviate += np.multiply(read_share, other, out=work)      # u = a z + b e
    read_deviate = np.multiply(read_share, deviate, out=read_share)
    read_deviate -= np.multiply(shot_share, other, out=work)      # v = b z - a e
    charge = poisson_quantile(shot_deviate, mean)
    read_deviate *= read_sigma_e
    charge += read_deviate
    return charge


def poisson_quantile(normal_deviate: np.ndarray, mean_e: np.ndarray) -> np.ndarray:
    """Exact Poisson quantile of a standard normal deviate: the smallest ``k`` with ``F(k; m) >= Phi(u)``.

    For ``u ~ N(0, 1)`` the result is Poisson(``m``) in distribution (to the accuracy of the CDF,
    ``scipy.special.pdtr``/``pdtrc``, ~1e-12 in probability); increasing in ``u`` (module doc: method).

    Parameters
    ----------
    normal_deviate : ndarray
        ``u``, finite.
    mean_e : ndarray, same shape
        Poisson mean ``m`` (e-), >= 0; means above :data:`MAX_POISSON_MEAN_E` (and +inf) are returned as is.

    Returns
    -------
    ndarray, float64, shape of ``mean_e``
        Counts (integers as float64; e-).

    Raises
    ------
    ValueError
        A mean is NaN or negative.
    """
    deviate = np.asarray(normal_deviate, dtype=np.float64)
    mean = np.asarray(mean_e, dtype=np.float64)
    if np.isnan(mean).any() or (mean < 0).any():
        raise ValueError("Poisson means must be >= 0 (a mean is negative or NaN)")
    magnitude = np.abs(deviate)
    if float(mean.min(initial=np.inf)) >= EXPANSION_MIN_MEAN_E and float(magnitude.max(initial=0.0)) \
            <= EXPANSION_MAX_DEVIATE and float(mean.max(initial=0.0)) <= MAX_POISSON_MEAN_E:
        return _expansion_count(deviate, mean)        # every pixel bright (the usual image): no indexing
    counts = np.empty(mean.shape, dtype=np.float64)
    huge = mean > MAX_POISSON_MEAN_E
    counts[huge] = mean[huge]
    expansion = ((mean >= EXPANSION_MIN_MEAN_E) & (magnitude <= EXPANSION_MAX_DEVIATE)) \
        | ((mean >= DIM_MIN_MEAN_E) & (magnitude <= DIM_MAX_DEVIATE)) | (mean > SCIPY_TAIL_MAX_MEAN_E)
    expansion &= ~huge
    summed = ~expansion & ~huge & (mean < DIM_MIN_MEAN_E) & (deviate <= DIM_MAX_DEVIATE)
    search = ~expansion & ~huge & ~summed
    counts[expansion] = _expansion_count(deviate[expansion], mean[expansion])
    counts[summed] = _summed_count(deviate[summed], mean[summed])
    counts[search] = _search_count(deviate[search], mean[search])
    return counts


def _summed_count(deviate: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Exact quantile of the dimmest pixels (``m <`` :data:`DIM_MIN_MEAN_E`, ``u <=`` :data:`DIM_MAX_DEVIATE`).

    ``k = #{j >= 0: F(j) < Phi(u)}``, the CDF summed from ``j = 0`` by the pmf recursion
    ``p(j) = p(j - 1) m / j``, all pixels in step (a few full-array operations per count).
    """
    import scipy.special as special  # here, not at module level: declaring a configuration imports no scipy
    target = special.ndtr(deviate)              # <= Phi(5): the sum reaches it with 2.9e-7 to spare
    pmf = np.exp(-mean)
    cdf = pmf.copy()
    short = cdf < target
    counts = short.astype(np.float64)
    step = 0
    while short.any():
        step += 1
        pmf *= mean
        pmf *= 1.0 / step
        cdf += pmf
        np.less(cdf, target, out=short)
        counts += short
    return counts


def _expansion_count(deviate: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Counts from the Cornish-Fisher quantile (means >= :data:`DIM_MIN_MEAN_E`).

    One exact CDF check where the quantile lies within the margin of an integer and scipy's CDF is
    accurate.
    """
    quantile = _continuous_quantile(deviate, mean)
    nearest = np.rint(quantile, out=scratch("poisson_a", mean.shape, np.float64))
    distance = np.subtract(quantile, nearest, out=scratch("poisson_c", mean.shape, np.float64))
    np.abs(distance, out=distance)
    margin: float | np.ndarray = BOUNDARY_MARGIN
    if float(mean.min(initial=np.inf)) < EXPANSION_MIN_MEAN_E:
        margin = np.maximum(BOUNDARY_MARGIN, DIM_MARGIN_E2 / np.square(mean))
    near = np.less(distance, margin, out=scratch("poisson_near", mean.shape, np.bool_))
    counts = np.ceil(quantile, out=quantile)
    index = np.flatnonzero(near)
    near_mean, near_deviate = mean.ravel()[index], deviate.ravel()[index]
    trusted = (near_mean <= MAX_CHECKED_MEAN_E) & ((near_deviate <= SCIPY_TAIL_MAX_DEVIATE)
                                                   | (near_mean <= SCIPY_TAIL_MAX_MEAN_E))
    index, near_mean, near_deviate = index[trusted], near_mean[trusted], near_deviate[trusted]
    if index.size:
        candidate = nearest.ravel()[index]
        reaches = _cdf_reaches(candidate, near_mean, near_deviate)
        counts.ravel()[index] = np.where(reaches, candidate, candidate + 1.0)
    return np.maximum(counts, 0.0, out=counts)


def _continuous_quantile(deviate: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """``y`` with ``Q(y + 1, m) = Phi(u)``: the Cornish-Fisher expansion of the module doc (to ``m^-1.5``).

    Evaluated as ``m + sqrt(m) u + c0 + (c1 + (c2 + c3 / sqrt(m)) / sqrt(m)) / sqrt(m)`` in this thread's
    scratch arrays ``poisson_a``, ``_c``, ``_d``, ``_f``; returns a new array.
    """
    shape = mean.shape
    inverse_root = np.sqrt(mean, out=scratch("poisson_a", shape, np.float64))
    linear = np.multiply(inverse_root, deviate, out=scratch("poisson_c", shape, np.float64))   # sqrt(m) u
    np.divide(1.0, inverse_root, out=inverse_root)
    square = np.multiply(deviate, deviate, out=scratch("poisson_d", shape, np.float64))
    work = scratch("poisson_f", shape, np.float64)
    series = np.multiply(square, -207.0 / 155520.0)                      # c3 = -u (207 u^4 + 548 u^2 - 2684) / 155520
    series -= 548.0 / 155520.0
    series *= square
    series += 2684.0 / 155520.0
    series *= deviate
    series *= inverse_root
    np.multiply(square, 3.0 / 810.0, out=work)                           # c2 = (3 u^4 + 7 u^2 - 16) / 810
    work += 7.0 / 810.0
    work *= square
    work -= 16.0 / 810.0
    series += work
    series *= inverse_root
    np.add(square, 2.0, out=work)                                        # c1 = -u (u^2 + 2) / 72
    work *= deviate
    work *= 1.0 / 72.0
    series -= work
    series *= inverse_root
    np.multiply(square, 1.0 / 6.0, out=work)                             # c0 = (u^2 + 2) / 6, minus 1 (y = shape - 1)
    work += 1.0 / 3.0 - 1.0
    series += work
    series += linear
    series += mean
    return series


def _search_count(deviate: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Exact quantile by stepping along the CDF from an expansion guess (dim pixels, far tails).

    One exact CDF (or tail) value at the guess, then the pmf recursion ``p(k + 1) = p(k) m / (k + 1)``
    step by step: on the lower tail ``F(k)`` for ``u <= 0``, on the upper tail ``P(X > k)`` for ``u > 0``.
    """
    import scipy.special as special  # here, not at module level: declaring a configuration imports no scipy
    counts = np.zeros(mean.shape)
    live = np.flatnonzero(mean > 0)                      # Poisson(0) is 0
    if live.size == 0:
        return counts
    m, u = mean[live], deviate[live]
    root = np.sqrt(m)
    guess = m + root * u + (u * u - 4.0) / 6.0 - u * (u * u + 2.0) / (72.0 * np.maximum(root, 1.0))
    k = np.maximum(np.floor(guess), 0.0)
    upper = u > 0
    # tail[i]: F(k) below (u <= 0) or P(X > k) above (u > 0); target the matching normal tail
    tail = np.empty(k.shape)
    tail[upper] = special.pdtrc(k[upper], m[upper])
    tail[~upper] = special.pdtr(k[~upper], m[~upper])
    target = special.ndtr(np.where(upper, -u, u))
    pmf = np.exp(k * np.log(m) - m - special.gammaln(k + 1.0))
    sign = np.where(upper, -1.0, 1.0)                    # stepping up adds pmf to F, removes it from P(X > k)
    reached = np.where(upper, tail <= target, tail >= target)
    up = np.flatnonzero(~reached)
    while up.size:                                       # F(k) < p: k + 1
        k[up] += 1.0
        pmf[up] *= m[up] / k[up]
        tail[up] += sign[up] * pmf[up]
        done = np.where(upper[up], tail[up] <= target[up], tail[up] >= target[up])
        up = up[~done]
    down = np.flatnonzero(k > 0)
    while down.size:                                     # F(k - 1) >= p: k - 1
        below = tail[down] - sign[down] * pmf[down]      # the tail value at k - 1
        step = np.where(upper[down], below <= target[down], below >= target[down])
        down = down[step]
        tail[down] = below[step]
        pmf[down] *= k[down] / m[down]
        k[down] -= 1.0
        down = down[k[down] > 0]
    counts[live] = k
    return counts


def _cdf_reaches(count: np.ndarray, mean: np.ndarray, deviate: np.ndarray) -> np.ndarray:
    """``F(k; m) >= Phi(u)``.

    Compared on the lower tail for ``u <= 0`` and the upper tail for ``u > 0`` (full double precision in
    both tails).
    """
    import scipy.special as special  # here, not at module level: declaring a configuration imports no scipy
    reaches = np.empty(np.shape(count), dtype=bool)
    upper = deviate > 0
    lower = ~upper
    reaches[lower] = special.pdtr(count[lower], mean[lower]) >= special.ndtr(deviate[lower])
    reaches[upper] = special.pdtrc(count[upper], mean[upper]) <= special.ndtr(-deviate[upper])
    return reaches
