"""Compiled (numba) passes of the matcher: the per-feature small-array work in a few calls.

Each kernel does the same float64 operations in the same order as the numpy definition it replaces in
:mod:`dimes_velocity.matching`, so the results are the same bits:

- sums of arrays are numpy's pairwise summation (:func:`pairwise_sum`: 8 running sums over blocks of up to 128
  values, halves above that), which is what ``np.add.reduce`` does on a contiguous float64 array;
- dot products and the 6 x 9 biquadratic fit call ``np.dot``, which numba hands to the same BLAS routines
  (``ddot``, ``dgemv``) as numpy;
- element-wise passes keep numpy's order of operations (no fast-math: no fused multiply-adds, no reassociation).

Each kernel is tested against its numpy definition (tests/dimes_velocity/test_compiled_matching.py). The
kernels are compiled on first use and cached on disk (``cache=True``).
"""
from __future__ import annotations

import math

import numba
import numpy as np

_PAIRWISE_BLOCK = 128    # numpy's PW_BLOCKSIZE


@numba.njit(cache=True)
def _block_sum(values: np.ndarray, start: int, count: int) -> float:
    """The pairwise sum (numpy's) of at most ``_PAIRWISE_BLOCK`` values: 8 running sums (sequential below 8 values)."""
    if count < 8:
        total = 0.0
        for i in range(count):
            total += values[start + i]
        return total
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = 8
    whole = count - count % 8
    while i < whole:
        at = start + i
        r0 += values[at]
        r1 += values[at + 1]
        r2 += values[at + 2]
        r3 += values[at + 3]
        r4 += values[at + 4]
        r5 += values[at + 5]
        r6 += values[at + 6]
        r7 += values[at + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < count:
        total += values[start + i]
        i += 1
    return total


@numba.njit(cache=True)
def pairwise_sum(values: np.ndarray, start: int, count: int) -> float:
    """``np.add.reduce(values[start:start + count])`` of a contiguous float64 array, by the same pairwise sum.

    Above ``_PAIRWISE_BLOCK`` values numpy sums the two halves (the first a multiple of 8 long) and adds them; the
    halving is walked here with an explicit stack (a recursive function does not survive numba's on-disk cache).

    Parameters
    ----------
    values : ndarray, shape (n,), float64
        The values.
    start, count : int
        The slice summed.

    Returns
    -------
    float
        The sum (the same bits as numpy's).
    """
    if count <= _PAIRWISE_BLOCK:
        return _block_sum(values, start, count)
    starts = np.empty(64, np.int64)        # pending halvings (post-order): first value, count, halves summed
    counts = np.empty(64, np.int64)
    stage = np.empty(64, np.int64)
    partial = np.empty(64)                 # sums of finished halves, left before right
    depth, done = 1, 0
    starts[0], counts[0], stage[0] = start, count, 0
    while depth:
        depth -= 1
        first, size, visited = starts[depth], counts[depth], stage[depth]
        if size <= _PAIRWISE_BLOCK:
            partial[done] = _block_sum(values, first, size)
            done += 1
        elif visited:
            partial[done - 2] = partial[done - 2] + partial[done - 1]
            done -= 1
        else:
            half = size // 2
            half -= half % 8
            starts[depth], counts[depth], stage[depth] = first, size, 1
            starts[depth + 1], counts[depth + 1], stage[depth + 1] = first + half, size - half, 0
            starts[depth + 2], counts[depth + 2], stage[depth + 2] = first, half, 0
            depth += 3
    return partial[0]


@numba.njit(cache=True)
def keys_weights(fraction: float) -> tuple[float, float, float, float]:
    """Keys (a = -1/2) cubic convolution weights of the samples at -1, 0, 1, 2 for a point at ``fraction``.

    Parameters
    ----------
    fraction : float
        Position of the point after sample 0 (0 .. 1, px).

    Returns
    -------
    tuple of 4 float
        The weights of the samples at -1, 0, 1 and 2.
    """
    t = fraction
    return (((-0.5 * t + 1.0) * t - 0.5) * t,
            (1.5 * t - 2.5) * t * t + 1.0,
            ((-1.5 * t + 2.0) * t + 0.5) * t,
            (0.5 * t - 0.5) * t * t)


@numba.njit(cache=True)
def shifted_window(window: np.ndarray, offset_x: float, offset_y: float, out_size: int) -> np.ndarray:
    """Keys cubic re-sampling of a square float64 window at ``(x + offset_x, y + offset_y)`` (``shift_window``).

    The horizontal 4-tap pass, then the vertical one, each sum taken left to right (``((w0 s0 + w1 s1) + w2 s2)
    + w3 s3``).

    Parameters
    ----------
    window : ndarray, shape (M, M), float64
        The window; it extends ``|offset| + 2`` pixels beyond the output on every side.
    offset_x, offset_y : float
        The shift (px).
    out_size : int
        Side of the output square (px).

    Returns
    -------
    ndarray, shape (out_size, out_size), float64
        The central square, shifted.
    """
    first_out = window.shape[0] // 2 - out_size // 2
    whole_x, whole_y = math.floor(offset_x), math.floor(offset_y)
    wx0, wx1, wx2, wx3 = keys_weights(offset_x - whole_x)
    wy0, wy1, wy2, wy3 = keys_weights(offset_y - whole_y)
    fx, fy = first_out + whole_x - 1, first_out + whole_y - 1
    columns = np.empty((out_size + 3, out_size))
    for r in range(out_size + 3):
        for c in range(out_size):
            at = fx + c
            value = window[fy + r, at] * wx0
            value += window[fy + r, at + 1] * wx1
            value += window[fy + r, at + 2] * wx2
            value += window[fy + r, at + 3] * wx3
            columns[r, c] = value
    out = np.empty((out_size, out_size))
    for r in range(out_size):
        for c in range(out_size):
            value = columns[r, c] * wy0
            value += columns[r + 1, c] * wy1
            value += columns[r + 2, c] * wy2
            value += columns[r + 3, c] * wy3
            out[r, c] = value
    return out


@numba.njit(cache=True)
def _normalised_at(window: np.ndarray, offset_x: float, offset_y: float, size: int) -> tuple[np.ndarray, bool]:
    """The re-sampled window of B at an offset, raveled, to zero mean and unit variance (flag: not flat)."""
    moved = shifted_window(window, offset_x, offset_y, size).ravel()
    count = moved.size
    mean = pairwise_sum(moved, 0, count) / count
    for i in range(count):
        moved[i] -= mean
    norm = math.sqrt(np.dot(moved, moved) / count)
    if not norm > 0:
        return moved, False
    for i in range(count):
        moved[i] /= norm
    return moved, True


@numba.njit(cache=True)
def refine(image_a: np.ndarray, image_b: np.ndarray, centre_column: int, centre_row: int, peak_column: int,
           peak_row: int, offset_x: float, offset_y: float, half: int,
           iterations: int) -> tuple[float, float, float]:
    """``matching._refine`` (inverse-compositional Gauss-Newton sub-pixel refinement), compiled.

    Parameters
    ----------
    image_a, image_b : ndarray, shape (N, N), float32
        The pair's rectified, flattened images.
    centre_column, centre_row : int
        Template centre in A (px).
    peak_column, peak_row : int
        Integer fine-level peak in B (px).
    offset_x, offset_y : float
        Starting sub-pixel offset from the peak (px).
    half : int
        Template half size (px).
    iterations : int
        Gauss-Newton steps at most.

    Returns
    -------
    offset_x, offset_y, correlation : float
        The refined offset from the peak (px) and the normalised correlation there (NaN when a window leaves the
        image or the template is flat: the offset is then the last one reached).
    """
    nan = math.nan
    reach_b, reach_a = half + 4, half + 1
    rows_b, columns_b = image_b.shape
    rows_a, columns_a = image_a.shape
    if (peak_row - reach_b < 0 or peak_column - reach_b < 0 or peak_row + reach_b >= rows_b
            or peak_column + reach_b >= columns_b):
        return offset_x, offset_y, nan
    if (centre_row - reach_a < 0 or centre_column - reach_a < 0 or centre_row + reach_a >= rows_a
            or centre_column + reach_a >= columns_a):
        return offset_x, offset_y, nan
    window = image_b[peak_row - reach_b: peak_row + reach_b + 1,
                     peak_column - reach_b: peak_column + reach_b + 1].astype(np.float64)
    padded = image_a[centre_row - reach_a: centre_row + reach_a + 1,
                     centre_column - reach_a: centre_column + reach_a + 1].astype(np.float64)
    size = 2 * half + 1
    count = size * size
    template = np.empty(count)
    for r in range(size):
        for c in range(size):
            template[r * size + c] = padded[r + 1, c + 1]
    mean = pairwise_sum(template, 0, count) / count
    centred = np.empty(count)
    for i in range(count):
        centred[i] = template[i] - mean
    spread = math.sqrt(np.dot(centred, centred) / count)
    if not spread > 0:
        return offset_x, offset_y, nan
    target = np.empty(count)
    for i in range(count):
        target[i] = centred[i] / spread
    scale = 0.5 / spread
    grad_x = np.empty(count)
    grad_y = np.empty(count)
    for r in range(size):
        for c in range(size):
            grad_x[r * size + c] = scale * (padded[r + 1, c + 2] - padded[r + 1, c])
            grad_y[r * size + c] = scale * (padded[r + 2, c + 1] - padded[r, c + 1])
    hxx, hxy, hyy = np.dot(grad_x, grad_x), np.dot(grad_x, grad_y), np.dot(grad_y, grad_y)
    determinant = hxx * hyy - hxy * hxy
    if not determinant > 1e-12 * max(hxx * hyy, 1e-300):
        return offset_x, offset_y, nan
    correlation = nan
    for step in range(iterations + 1):
        normalised, usable = _normalised_at(window, offset_x, offset_y, size)
        if not usable:
            return offset_x, offset_y, nan
        correlation = np.dot(normalised, target) / count
        if step == iterations:
            break
        for i in range(count):
            normalised[i] -= target[i]
        ex, ey = np.dot(grad_x, normalised), np.dot(grad_y, normalised)
        delta_x, delta_y = (hyy * ex - hxy * ey) / determinant, (hxx * ey - hxy * ex) / determinant
        offset_x, offset_y = clip(offset_x - delta_x, 1.5), clip(offset_y - delta_y, 1.5)
        if max(abs(delta_x), abs(delta_y)) < 1e-3:
            normalised, usable = _normalised_at(window, offset_x, offset_y, size)
            if usable:
                correlation = np.dot(normalised, target) / count
            break
    return offset_x, offset_y, correlation


@numba.njit(cache=True)
def clip(value: float, bound: float) -> float:
    """``value`` clipped to ``[-bound, bound]`` (NaN stays NaN).

    Parameters
    ----------
    value, bound : float
        The value and the bound (> 0).

    Returns
    -------
    float
        The clipped value.
    """
    return -bound if value < -bound else bound if value > bound else value


@numba.njit(cache=True)
def fit_peak(fit: np.ndarray, patch: np.ndarray) -> tuple[float, float, float, float]:
    """``matching.fit_peak`` of a 3 x 3 patch, compiled.

    Parameters
    ----------
    fit : ndarray, shape (6, 9), float64
        The least-squares operator of the biquadratic (``matching._FIT``).
    patch : ndarray, shape (3, 3)
        Correlation values around the maximum.

    Returns
    -------
    offset_x, offset_y : float
        Sub-pixel position of the maximum from the centre (px, clipped to +-1).
    peak_value : float
        Fitted value there (clipped to [-1, 1]).
    curvature : float
        Smallest principal curvature (0 when not a maximum), 1/px^2.
    """
    values = np.empty(9)
    for r in range(3):
        for c in range(3):
            values[3 * r + c] = np.float64(patch[r, c])
    coefficients = np.dot(fit, values)
    a, bx, by, dxx, exy, fyy = (coefficients[0], coefficients[1], coefficients[2], coefficients[3],
                                coefficients[4], coefficients[5])
    hxx, hxy, hyy = 2.0 * dxx, exy, 2.0 * fyy
    larger = 0.5 * (hxx + hyy) + math.hypot(0.5 * (hxx - hyy), hxy)
    if larger < 0.0:
        determinant = hxx * hyy - hxy * hxy
        x = (-bx * hyy + by * hxy) / determinant
        y = (-by * hxx + bx * hxy) / determinant
        curvature = -larger
    else:
        x = -bx / hxx if hxx < 0 else 0.0
        y = -by / hyy if hyy < 0 else 0.0
        curvature = 0.0
    x, y = min(max(x, -1.0), 1.0), min(max(y, -1.0), 1.0)
    value = a + bx * x + by * y + dxx * x * x + exy * x * y + fyy * y * y
    return x, y, min(max(value, -1.0), 1.0), curvature


@numba.njit(cache=True)
def correlation_difference_sigma(best: float, other: float, template_variance: float, window_variance: float,
                                 noise_a_dn: float, noise_b_dn: float, pixels: int) -> float:
    """``matching.correlation_difference_sigma``, compiled (the same scalar operations).

    Parameters
    ----------
    best, other : float
        The two correlations.
    template_variance, window_variance : float
        Variances of the coarse template and of the coarse window at the best peak (DN^2).
    noise_a_dn, noise_b_dn : float
        Fine-level pixel noise of A and B (DN).
    pixels : int
        Pixels of the coarse template.

    Returns
    -------
    float
        Standard deviation of ``best - other`` (correlation units).
    """
    rho0 = min(max(best, -1.0), 1.0)
    rho1 = min(max(other, -1.0), 1.0)
    eps_a2 = 0.25 * noise_a_dn * noise_a_dn / max(template_variance, 1e-12)
    eps_b2 = max(0.25 * noise_b_dn * noise_b_dn / max(window_variance, 1e-12), 2.0 * (1.0 - rho0) - eps_a2)
    return math.sqrt((eps_a2 + eps_b2) / pixels) * (math.sqrt(max(1.0 - rho0 * rho0, 0.0))
                                                     + math.sqrt(max(1.0 - rho1 * rho1, 0.0)))


@numba.njit(cache=True)
def distinct_peak_level(best: float, template_variance: float, window_variance: float, noise_a_dn: float,
                        noise_b_dn: float, pixels: int, confidence_sigma: float) -> float:
    """``matching.distinct_peak_level``, compiled (the same fixed-point iteration).

    Parameters
    ----------
    best : float
        Best coarse correlation.
    template_variance, window_variance : float
        Variances of the coarse template and of the coarse window at the best peak (DN^2).
    noise_a_dn, noise_b_dn : float
        Fine-level pixel noise of A and B (DN).
    pixels : int
        Pixels of the coarse template.
    confidence_sigma : float
        Standard deviations below the best a distinct peak must lie.

    Returns
    -------
    float
        The level (-1 when nothing can be told apart).
    """
    rho0 = min(max(best, -1.0), 1.0)
    level = rho0
    for _ in range(8):
        updated = rho0 - confidence_sigma * correlation_difference_sigma(
            rho0, level, template_variance, window_variance, noise_a_dn, noise_b_dn, pixels)
        if updated <= -1.0:
            return -1.0
        if abs(updated - level) < 1e-6:
            return updated
        level = updated
    return level


@numba.njit(cache=True)
def binned_charge(raw_dn: np.ndarray, binning: int, offset_dn: np.float32, storage_dark_dn: np.ndarray,
                  gain: np.float32) -> np.ndarray:
    """Column binning, offset and storage-dark removal and the DN -> e- gain of ``preprocess.flatten``, one pass.

    The column sums of integer DN (at most 16 bits) are exact integers in float32 whatever the order (below
    2^24), as ``preprocess.bin_columns`` gives them; then ``((sum - offset) - dark) * gain`` in float32.

    Parameters
    ----------
    raw_dn : ndarray, shape (rows, columns), integer of at most 16 bits
        The read-out image (DN).
    binning : int
        Columns summed; divides ``columns``.
    offset_dn : float32
        ADC offset of a binned block (DN).
    storage_dark_dn : ndarray, shape (rows, 1), float32
        Storage-area dark of each row (DN).
    gain : float32
        e- per DN.

    Returns
    -------
    ndarray, shape (rows, columns / binning), float32
        Collected charge of each block (e-).
    """
    rows, columns = raw_dn.shape
    blocks = columns // binning
    charge = np.empty((rows, blocks), np.float32)
    for row in range(rows):
        dark = storage_dark_dn[row, 0]
        for block in range(blocks):
            total = np.int64(raw_dn[row, block * binning])
            for k in range(1, binning):
                total += np.int64(raw_dn[row, block * binning + k])
            charge[row, block] = ((np.float32(total) - offset_dn) - dark) * gain
    return charge


@numba.njit(cache=True)
def binned_charge_u16x4(words: np.ndarray, offset_dn: np.float32, storage_dark_dn: np.ndarray,
                        gain: np.float32) -> np.ndarray:
    """:func:`binned_charge` of uint16 DN binned 4:1, read as one uint64 word per block (the same bits).

    The four 16-bit lanes of a word are summed in pairs within the word (no carry leaves a 32-bit lane: the
    sum of four uint16 is below 2^18), which the compiler turns into vector instructions; a strided 4-column
    gather does not vectorise (20x slower).

    Parameters
    ----------
    words : ndarray, shape (rows, columns / 4), uint64
        The uint16 image viewed as uint64 (``raw.view(np.uint64)``: the four columns of each block).
    offset_dn, storage_dark_dn, gain
        As :func:`binned_charge`.

    Returns
    -------
    ndarray, shape (rows, columns / 4), float32
        Collected charge of each block (e-).
    """
    rows, blocks = words.shape
    charge = np.empty((rows, blocks), np.float32)
    lanes = np.uint64(0x0000FFFF0000FFFF)
    low_half = np.uint64(0xFFFFFFFF)
    for row in range(rows):
        dark = storage_dark_dn[row, 0]
        for block in range(blocks):
            word = words[row, block]
            pairs = (word & lanes) + ((word >> np.uint64(16)) & lanes)
            total = (pairs & low_half) + (pairs >> np.uint64(32))
            charge[row, block] = ((np.float32(np.int64(total)) - offset_dn) - dark) * gain
    return charge


@numba.njit(cache=True)
def flattened_signal(charge_e: np.ndarray, smear: bool, total_divisor: float, gamma_s: float, rate_divisor: np.float32,
                     area_dark: np.float32, scale: np.float32, inverse_response: np.ndarray,
                     min_signal_dn: np.float32) -> tuple[np.ndarray, np.ndarray, int]:
    """``preprocess.unsmear`` (no smear, or equal flush and transfer times) and the rest of ``flatten``, one pass.

    With smear: column totals summed row by row in float64 (``charge.sum(axis=0, dtype=float64)``) over
    ``total_divisor = d + n gamma``, then ``(Q - float32(gamma total)) / float32(d)``; without: ``Q / float32(alpha)``
    (``rate_divisor``). Then, in float32: ``((G - area_dark) * scale) * inverse_response``, and the blocks below
    ``min_signal_dn``.

    Parameters
    ----------
    charge_e : ndarray, shape (n, m), float32
        Collected charge of each block (e-).
    smear : bool
        Remove the smear (the equal-times closed form).
    total_divisor, gamma_s : float
        ``d + n gamma`` and ``gamma`` (s).
    rate_divisor : float32
        ``d`` with smear, ``alpha`` without (s).
    area_dark : float32
        Image-area dark generation of a block (e-/s).
    scale : float32
        ``float32(exposure) / gain``.
    inverse_response : ndarray, shape (n, m), float32
        ``1 / response``.
    min_signal_dn : float32
        Blocks below it are dark.

    Returns
    -------
    signal_dn : ndarray, shape (n, m), float32
        The flattened signal (DN).
    dark : ndarray, shape (n, m), uint8
        1 where below ``min_signal_dn``.
    dark_count : int
        Dark blocks.
    """
    rows, columns = charge_e.shape
    subtracted = np.zeros(columns, np.float32)
    if smear:
        totals = np.zeros(columns)
        for row in range(rows):
            for column in range(columns):
                totals[column] += np.float64(charge_e[row, column])
        for column in range(columns):
            subtracted[column] = np.float32(gamma_s * (totals[column] / total_divisor))
    signal = np.empty((rows, columns), np.float32)
    dark = np.empty((rows, columns), np.uint8)
    dark_count = 0
    for row in range(rows):
        for column in range(columns):
            if smear:
                value = (charge_e[row, column] - subtracted[column]) / rate_divisor
            else:
                value = charge_e[row, column] / rate_divisor
            value = ((value - area_dark) * scale) * inverse_response[row, column]
            signal[row, column] = value
            below = value < min_signal_dn
            dark[row, column] = below
            dark_count += below
    return signal, dark, dark_count


@numba.njit(cache=True)
def variance(values: np.ndarray) -> float:
    """``matching._variance``: population variance of a 2-D array in float64 (numpy's pairwise sums, one each).

    numpy reduces the (buffered, float64) values in one pairwise sum, the mean divided by the count, the squared
    deviations summed the same way.

    Parameters
    ----------
    values : ndarray, shape (rows, columns)
        The values (any real dtype, any strides).

    Returns
    -------
    float
        Their population variance.
    """
    rows, columns = values.shape
    count = rows * columns
    flat = np.empty(count)
    for row in range(rows):
        for column in range(columns):
            flat[row * columns + column] = np.float64(values[row, column])
    mean = pairwise_sum(flat, 0, count) / count
    for i in range(count):
        deviation = flat[i] - mean
        flat[i] = deviation * deviation
    return pairwise_sum(flat, 0, count) / count


@numba.njit(cache=True)
def peak_and_second(surface: np.ndarray, exclusion_px: int) -> tuple[float, int, int, float]:
    """The best peak of a correlation surface and ``matching.second_peak`` in one pass over it.

    The best peak is ``cv2.minMaxLoc``'s maximum (the first in row-major order); the second is the highest
    local maximum (a value at least each of its 3 x 3 neighbours inside the surface, as ``cv2.dilate`` with its
    default border) outside the ``exclusion_px`` box around the best, -1 when there is none.

    Parameters
    ----------
    surface : ndarray, shape (rows, columns), float32
        Correlation surface (no NaN).
    exclusion_px : int
        Local maxima within this many pixels of the best peak in both directions are ignored.

    Returns
    -------
    best : float
        The largest value.
    column, row : int
        Where it is.
    second : float
        The second peak's value (-1 when there is none).
    """
    rows, columns = surface.shape
    best = surface[0, 0]
    best_row = best_column = 0
    for row in range(rows):
        for column in range(columns):
            if surface[row, column] > best:
                best, best_row, best_column = surface[row, column], row, column
    return np.float64(best), best_column, best_row, second_peak(surface, best_column, best_row, exclusion_px)


@numba.njit(cache=True)
def second_peak(surface: np.ndarray, best_column: int, best_row: int, exclusion_px: int) -> float:
    """``matching.second_peak``: the highest local maximum away from the best peak, compiled.

    Parameters
    ----------
    surface : ndarray, shape (rows, columns), float32
        Correlation surface.
    best_column, best_row : int
        The best peak.
    exclusion_px : int
        Maxima within this many pixels of the best in both directions are ignored.

    Returns
    -------
    float
        The second peak's value; -1 when there is none.
    """
    rows, columns = surface.shape
    second = -1.0
    found = False
    for row in range(rows):
        for column in range(columns):
            if abs(row - best_row) <= exclusion_px and abs(column - best_column) <= exclusion_px:
                continue
            value = surface[row, column]
            local = True
            for near_row in range(max(row - 1, 0), min(row + 2, rows)):
                for near_column in range(max(column - 1, 0), min(column + 2, columns)):
                    if surface[near_row, near_column] > value:
                        local = False
            if local and (not found or value > second):
                second, found = np.float64(value), True
    return second


@numba.njit(cache=True)
def lobes_above(surface: np.ndarray, level: np.float32) -> int:
    """``matching.lobes_above``: 8-connected regions of ``surface >= level`` (flood fill), compiled.

    Parameters
    ----------
    surface : ndarray, shape (rows, columns), float32
        Correlation surface.
    level : float32
        The level.

    Returns
    -------
    int
        Regions.
    """
    rows, columns = surface.shape
    label = np.zeros((rows, columns), np.uint8)
    stack = np.empty(rows * columns, np.int64)
    regions = 0
    for row in range(rows):
        for column in range(columns):
            if label[row, column] or not surface[row, column] >= level:
                continue
            regions += 1
            label[row, column] = 1
            stack[0] = row * columns + column
            size = 1
            while size:
                size -= 1
                at_row, at_column = divmod(stack[size], columns)
                for near_row in range(max(at_row - 1, 0), min(at_row + 2, rows)):
                    for near_column in range(max(at_column - 1, 0), min(at_column + 2, columns)):
                        if not label[near_row, near_column] and surface[near_row, near_column] >= level:
                            label[near_row, near_column] = 1
                            stack[size] = near_row * columns + near_column
                            size += 1
    return regions


@numba.njit(cache=True)
def inside_frame(map_x: np.ndarray, map_y: np.ndarray, last_column: np.float32, last_row: np.float32) -> np.ndarray:
    """``(map_x >= 0) & (map_x <= last_column) & (map_y >= 0) & (map_y <= last_row)`` in one pass, as 0/1 uint8.

    Parameters
    ----------
    map_x, map_y : ndarray, shape (rows, columns), float32
        Image column and row of each rectified pixel (binned px).
    last_column, last_row : float32
        The image's last column and row (binned px).

    Returns
    -------
    ndarray, shape (rows, columns), uint8
        1 where the position lies on the image (NaN: 0, as numpy's comparisons).
    """
    rows, columns = map_x.shape
    inside = np.empty((rows, columns), np.uint8)
    for row in range(rows):
        for column in range(columns):
            x, y = map_x[row, column], map_y[row, column]
            inside[row, column] = 1 if (x >= 0 and x <= last_column and y >= 0 and y <= last_row) else 0
    return inside


@numba.njit(cache=True)
def cone_cells(cosines: np.ndarray, level: float, overshoot: float) -> tuple[bool, int, int, int, int]:
    """``geometry._cone_cells``: the block of knot cells where ``max + overshoot (max - min) > level``.

    Each cell's largest and smallest of its 4 x 4 knots (``cells = knots - 3`` per axis), the same float64
    expression as the numpy definition (cv2.dilate / cv2.erode with a 4 x 4 kernel anchored at (0, 0)).

    Parameters
    ----------
    cosines : ndarray, shape (K + 2, K + 2), float64
        Cosine of each knot's ray to the cone's axis.
    level : float
        The test's level (the cone's cosine less the test margin).
    overshoot : float
        Largest Catmull-Rom overshoot, as a fraction of a cell's knot range.

    Returns
    -------
    found : bool
        Some cell passes.
    first_row, end_row, first_column, end_column : int
        The passing cells' bounding block (0 when none).
    """
    cells = cosines.shape[0] - 3
    found = False
    first_row, end_row, first_column, end_column = cells, 0, cells, 0
    for row in range(cells):
        for column in range(cells):
            highest = cosines[row, column]
            lowest = highest
            for near_row in range(row, row + 4):
                for near_column in range(column, column + 4):
                    value = cosines[near_row, near_column]
                    highest = max(highest, value)
                    lowest = min(lowest, value)
            if highest + overshoot * (highest - lowest) > level:
                found = True
                first_row, end_row = min(first_row, row), max(end_row, row + 1)
                first_column, end_column = min(first_column, column), max(end_column, column + 1)
    if not found:
        return False, 0, 0, 0, 0
    return True, first_row, end_row, first_column, end_column


@numba.njit(cache=True)
def grid_maxima(interest: np.ndarray, candidates: np.ndarray, row_edges: np.ndarray,
                column_edges: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each grid cell's most interesting allowed pixel (``features.FeatureSelector``'s offers), in one pass.

    The numpy definition: ``scored = np.where(candidates, interest, -1.0)``; per cell ``argmax`` (the first of
    equal maxima in row-major order, or the first NaN), kept when its score is not negative. Cells are taken row by
    row; empty cells are skipped.

    Parameters
    ----------
    interest : ndarray, shape (rows, columns), float32
        Interest of the window (its top-left is row 0, column 0).
    candidates : ndarray, shape (rows, columns), bool
        Where a centre is allowed.
    row_edges, column_edges : ndarray of int
        Cell boundaries in window coordinates (``cells + 1`` each).

    Returns
    -------
    scores : ndarray, float64
        Each kept cell's best score.
    columns, rows : ndarray of int
        Its position in the window (px).
    """
    cells = (len(row_edges) - 1) * (len(column_edges) - 1)
    scores = np.empty(cells)
    columns = np.empty(cells, np.int64)
    rows = np.empty(cells, np.int64)
    kept = 0
    for cell_row in range(len(row_edges) - 1):
        for cell_column in range(len(column_edges) - 1):
            best = -np.inf
            best_row = best_column = -1
            for row in range(row_edges[cell_row], row_edges[cell_row + 1]):
                for column in range(column_edges[cell_column], column_edges[cell_column + 1]):
                    score = np.float64(interest[row, column]) if candidates[row, column] else -1.0
                    if best_row < 0 or score > best or (score != score and best == best):   # the first NaN, as argmax
                        best, best_row, best_column = score, row, column
            if best_row < 0 or best < 0:
                continue
            scores[kept], columns[kept], rows[kept] = best, best_column, best_row
            kept += 1
    return scores[:kept], columns[:kept], rows[:kept]


@numba.njit(cache=True)
def templates_statistics(image: np.ndarray, columns: np.ndarray, rows: np.ndarray, half: int,
                         offsets: np.ndarray, norm: float) -> np.ndarray:
    """``features.templates_statistics``: mean, standard deviation and detrended standard deviation of templates.

    The same float64 operations as the numpy definition: whole-template sums and each template row's sum are
    numpy's pairwise sums (:func:`pairwise_sum`), each column's sum runs down the rows in order (numpy's reduction
    over a middle axis), the plane slopes are ``np.dot`` (BLAS ``ddot``, as numpy's ``@``) over ``norm``.

    Parameters
    ----------
    image : ndarray, shape (N, M)
        Rectified, flattened image (DN), any real dtype.
    columns, rows : ndarray of int, shape (n,)
        Template centres (px); every template lies inside the image.
    half : int
        Half size: the templates are (2 half + 1) x (2 half + 1) pixels.
    offsets : ndarray, shape (2 half + 1,), float64
        ``-half .. half``.
    norm : float
        ``(2 half + 1) * sum(offsets^2)``.

    Returns
    -------
    ndarray, shape (n, 3), float64
        Per template: mean, standard deviation, detrended standard deviation (DN).
    """
    side = 2 * half + 1
    count = side * side
    templates = len(columns)
    out = np.empty((templates, 3))
    patch = np.empty(count)
    work = np.empty(count)
    column_sums = np.empty(side)
    row_sums = np.empty(side)
    for k in range(templates):
        top, left = rows[k] - half, columns[k] - half
        for i in range(side):
            for j in range(side):
                patch[i * side + j] = np.float64(image[top + i, left + j])
        mean = pairwise_sum(patch, 0, count) / count
        for j in range(side):
            total = patch[j]
            for i in range(1, side):
                total += patch[i * side + j]
            column_sums[j] = total
        for i in range(side):
            row_sums[i] = pairwise_sum(patch, i * side, side)
        slope_x = np.dot(column_sums, offsets) / norm
        slope_y = np.dot(row_sums, offsets) / norm
        for index in range(count):
            deviation = patch[index] - mean
            work[index] = deviation * deviation
        spread = math.sqrt(pairwise_sum(work, 0, count) / count)
        for i in range(side):
            for j in range(side):
                index = i * side + j
                work[index] = ((patch[index] - mean) - slope_x * offsets[j]) - slope_y * offsets[i]
        level = pairwise_sum(work, 0, count) / count
        for index in range(count):
            residual = work[index] - level
            work[index] = residual * residual
        out[k, 0], out[k, 1], out[k, 2] = mean, spread, math.sqrt(pairwise_sum(work, 0, count) / count)
    return out


@numba.njit(cache=True)
def erode_columns(mask: np.ndarray, side: int) -> np.ndarray:
    """Binary erosion along the columns by ``side`` (odd) pixels, outside the array counting as 0.

    ``out[r, c] = 1`` when ``mask[r - half .. r + half, c]`` all lie inside the array and are 1 (``half = side // 2``):
    the run of 1s down column ``c`` ending at row ``r + half`` is at least ``side`` long. One counter per column,
    updated a row at a time (vectorised across the row), whatever ``side`` is.

    Parameters
    ----------
    mask : ndarray, shape (rows, columns), uint8
        0/1 values.
    side : int
        Odd length of the vertical structuring element (px).

    Returns
    -------
    ndarray, shape (rows, columns), uint8
        0/1, as ``cv2.erode`` with a ``(side, 1)`` kernel of ones and a constant 0 border.
    """
    rows, columns = mask.shape
    half = side // 2
    out = np.zeros((rows, columns), np.uint8)
    runs = np.zeros(columns, np.int32)
    for row in range(rows):
        line = mask[row]
        for column in range(columns):
            runs[column] = (runs[column] + 1) * np.int32(line[column])
        if row >= side - 1:
            target = out[row - half]
            for column in range(columns):
                target[column] = np.uint8(runs[column] >= side)
    return out
