"""Charge collection and transfer in a frame-transfer CCD, with fast-flush and frame-transfer smear.

Stage 3 of the camera chain. The image area is illuminated during all three periods:

* fast flush (``T_f``): the array is clocked out continuously; the charge packet that ends at row
  ``r`` entered empty at the far edge and crossed rows ``0..r``, spending ``T_f / N`` in each;
* exposure (``T_e``): the packet sits at row ``r``;
* frame transfer (``T_t``): the packet is clocked from row ``r`` across rows ``r..N-1`` into storage.

So with generation rates ``g_f, g_e, g_t`` (e-/s) of the three periods, for charge moving toward the
last row::

    Q[r] = T_f/N * sum_{i<=r} g_f[i] + T_e * g_e[r] + T_t/N * sum_{i>=r} g_t[i]

(rows reversed when charge moves toward the first row). On-chip binning then sums ``b`` rows in the
serial register. Because binning only needs block sums, the binned charge is computed exactly from
block cumulative sums::

    sum_{r in block k} sum_{i<=r} g[i] = b * C[k-1] + sum_j (b - j) g[k*b + j]

where ``C`` is the cumulative sum over whole blocks; no per-row loop and no full-resolution cumulative
sum is needed unless a pixel can reach full well, when :func:`pixel_charge_e` is used instead.

The flush and transfer rates may also be given per block (shape (N / b, width), each block's mean
rate): smear only sees them through block sums, so that is all the fast path needs.
"""
from __future__ import annotations

import numpy as np

from flight_interface.camera_file import Timing
from simulator.fields import bin_rows
from simulator.scratch import scratch


def cumsum_rows(values: np.ndarray) -> np.ndarray:
    """Cumulative sum down axis 0, as row-vector adds in groups.

    numpy's axis-0 cumsum walks each column separately and is ~10x slower on C-ordered images; one add
    per row costs a call per row. Rows are taken in ``g ~ sqrt(N)`` groups: the running sums within every
    group at once (``g`` adds of ``N / g`` rows), then each group's total carried into the next
    (``N / g`` adds).

    Parameters
    ----------
    values : ndarray, shape (N, W)
        Values to sum.

    Returns
    -------
    ndarray, shape (N, W), float32
        Cumulative sums.
    """
    rows, width = values.shape
    group = max(int(np.sqrt(rows)), 1)
    while rows % group:
        group -= 1
    out = np.empty((rows // group, group, width), dtype=np.float32)
    grouped = values.reshape(rows // group, group, width)
    out[:, 0] = grouped[:, 0]
    for row in range(1, group):
        np.add(out[:, row - 1], grouped[:, row], out=out[:, row])
    for index in range(1, rows // group):
        out[index] += out[index - 1, -1]
    return out.reshape(rows, width)


def _flip(rate: np.ndarray, toward_last_row: bool) -> np.ndarray:
    return rate if toward_last_row else rate[::-1]


def pixel_charge_e(rate_flush: np.ndarray, rate_exposure: np.ndarray, rate_transfer: np.ndarray,
                   timing: Timing) -> np.ndarray:
    """Full-resolution charge per pixel at the end of frame transfer.

    Block-mean smear rates are spread evenly over their blocks' rows.

    Parameters
    ----------
    rate_flush, rate_exposure, rate_transfer : ndarray, shape (N, W) or (N / b, W)
        Generation rates (e-/s) of the fast flush, exposure and frame transfer; the smear rates may be
        block means.
    timing : Timing
        The CCD timing (flush, exposure, transfer durations, transfer direction).

    Returns
    -------
    ndarray, shape (N, W), float32
        Charge per pixel (e-).
    """
    rows = rate_exposure.shape[0]
    rate_flush, rate_transfer = full_rows(rate_flush, rows), full_rows(rate_transfer, rows)
    toward_last = timing.transfer_toward_last_row
    flush_smear = cumsum_rows(_flip(rate_flush, toward_last))
    transfer_smear = cumsum_rows(_flip(rate_transfer, toward_last)[::-1])[::-1]
    smear = (timing.fast_flush_s / rows) * flush_smear + (timing.frame_transfer_s / rows) * transfer_smear
    return _flip(smear, toward_last) + timing.exposure_s * rate_exposure


def binned_charge_e(rate_flush: np.ndarray, rate_exposure: np.ndarray, rate_transfer: np.ndarray,
                    timing: Timing, binning_rows: int, rows: int | None = None) -> np.ndarray:
    """Binned charge of ``binning_rows``-row blocks, exact, from block cumulative sums (module doc).

    Parameters
    ----------
    rate_flush, rate_exposure, rate_transfer : ndarray, shape (N, W) or (N / b, W)
        Generation rates (e-/s) of the fast flush, exposure and frame transfer; the smear rates may be
        block means.
    timing : Timing
        The CCD timing (flush, exposure, transfer durations, transfer direction).
    binning_rows : int
        Rows per block ``b``.
    rows : int, optional
        Full-frame rows N; needed only when the exposure rate too is given per block (its mean).

    Returns
    -------
    ndarray, shape (N / b, W), float32
        Charge per binned pixel (e-).
    """
    rows = rate_exposure.shape[0] if rows is None else rows
    toward_last = timing.transfer_toward_last_row
    flush_sums = _block_sums(_flip(rate_flush, toward_last), binning_rows, rows)
    if rate_transfer is rate_flush:
        transfer_sums = flush_sums
    else:
        transfer_sums = _block_sums(_flip(rate_transfer, toward_last), binning_rows, rows)
    if is_block_mean(rate_exposure, rows, binning_rows):
        exposure_blocks = rate_exposure * np.float32(binning_rows)
    elif rate_exposure is rate_flush and toward_last:    # a still image: the same rows summed in the same order
        exposure_blocks = flush_sums[0]
    else:
        exposure_blocks = bin_rows(rate_exposure, binning_rows)
    return binned_charge_from_sums(flush_sums, exposure_blocks, transfer_sums, timing, binning_rows, rows)


def binned_charge_from_sums(flush_sums: tuple[np.ndarray, np.ndarray], exposure_blocks: np.ndarray,
                            transfer_sums: tuple[np.ndarray, np.ndarray], timing: Timing, binning_rows: int,
                            rows: int) -> np.ndarray:
    """Binned charge from the block sums of the three periods' rates (module doc).

    Parameters
    ----------
    flush_sums, transfer_sums : (ndarray, ndarray), each shape (N / b, W)
        Per block of the fast-flush (transfer) rate, in the order the charge moves (blocks and rows
        reversed when it moves toward the first row): the plain sum of its rows and the sum weighted
        ``b, b - 1, ..., 1`` from its first row (e-/s); :func:`block_rate_sums`.
    exposure_blocks : ndarray, shape (N / b, W)
        Sum of the exposure rate over each block's rows (e-/s), in image order.
    timing : Timing
        The CCD timing (flush, exposure, transfer durations, transfer direction).
    binning_rows : int
        Rows per block ``b``.
    rows : int
        Full-frame rows N.

    Returns
    -------
    ndarray, shape (N / b, W), float32
        Charge per binned pixel (e-).
    """
    toward_last = timing.transfer_toward_last_row
    flush_blocks, flush_ramp = flush_sums
    transfer_blocks, transfer_ramp = transfer_sums
    flush_through = cumsum_rows(flush_blocks)                       # blocks up to and including
    if transfer_blocks is flush_blocks:      # one cumulative sum serves both: after = total - up to and including
        transfer_after = np.subtract(flush_through[-1], flush_through)
    else:
        transfer_after = cumsum_rows(transfer_blocks[::-1])[::-1]
        transfer_after -= transfer_blocks
    flush_smear = flush_through
    flush_smear -= flush_blocks                                      # blocks strictly before
    flush_smear *= np.float32(binning_rows)
    flush_smear += flush_ramp                                        # ramp weights b, b-1, .., 1
    # weights 1, 2, .., b  =  (b + 1) * block sum - (weights b, .., 1)
    transfer_smear = transfer_after
    transfer_smear *= np.float32(binning_rows)
    transfer_smear += np.float32(binning_rows + 1) * transfer_blocks
    transfer_smear -= transfer_ramp
    flush_smear *= np.float32(timing.fast_flush_s / rows)
    transfer_smear *= np.float32(timing.frame_transfer_s / rows)
    smear = flush_smear
    smear += transfer_smear
    charge = np.multiply(exposure_blocks, np.float32(timing.exposure_s), dtype=np.float32)
    charge += _flip(smear, toward_last)
    return charge


def block_rate_sums(radiance: np.ndarray, gain: np.ndarray, binning_rows: int, toward_last_row: bool,
                    offset_e_per_s: float = 0.0,
                    radiance_sums: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Block sums of a rate ``radiance x gain + offset`` without the full-resolution rate, in one pass.

    Parameters
    ----------
    radiance : ndarray, shape (N, W), float32
        Radiance per pixel (W m^-2 sr^-1 um^-1).
    gain : ndarray, shape (N, W), float32
        Rate per unit radiance of every pixel (e-/s per W m^-2 sr^-1 um^-1).
    binning_rows : int
        Rows per block ``b``.
    toward_last_row : bool
        The charge moves toward the last row (else blocks and the rows in them are taken in reverse,
        as :func:`binned_charge_from_sums` wants them).
    offset_e_per_s : float, optional
        A rate added to every pixel (dark current, e-/s).
    radiance_sums : bool, optional
        Also sum the radiance (else the third array is None).

    Returns
    -------
    (plain, ramp, radiance_sums) : three ndarrays, float32, shape (N / b, W)
        Per block, in the order the charge moves: the sum of the rate over its rows, the sum weighted
        ``b, b - 1, ..., 1`` from the block's first row (e-/s), and the sum of the radiance.
    """
    rows, width = radiance.shape
    blocks = rows // binning_rows
    with np.errstate(over="ignore", invalid="ignore"):      # an overflowing rate: inf, which saturates
        product = np.multiply(radiance, gain, dtype=np.float32,      # dies here: this thread's scratch array
                              out=scratch("rate_product", (rows, width))).reshape(blocks, binning_rows, width)
        field = radiance.reshape(blocks, binning_rows, width)
        if not toward_last_row:
            product, field = product[::-1, ::-1], field[::-1, ::-1]
        plain = product[:, 0].copy()          # partial sums over the block's first rows; their sum is the ramp
        ramp = plain.copy()
        for offset in range(1, binning_rows):
            plain += product[:, offset]
            ramp += plain
        field_sums = None
        if radiance_sums:
            field_sums = field[:, 0].astype(np.float32, copy=True)
            for offset in range(1, binning_rows):
                field_sums += field[:, offset]
    if offset_e_per_s:
        plain += np.float32(binning_rows * offset_e_per_s)
        ramp += np.float32(binning_rows * (binning_rows + 1) / 2 * offset_e_per_s)
    return plain, ramp, field_sums


def is_block_mean(rate: np.ndarray, rows: int, binning_rows: int) -> bool:
    """Whether a smear-period rate is given per binning block rather than per pixel row.

    See :func:`simulator.scene.periods.period_fields`.

    Parameters
    ----------
    rate : ndarray, shape (rows, W) or (rows / b, W)
        A generation rate (e-/s).
    rows : int
        Full-frame rows.
    binning_rows : int
        Rows per block ``b``.

    Returns
    -------
    bool
        True for a (rows / b, W) block-mean rate.
    """
    return rate.shape[0] * binning_rows == rows and binning_rows > 1


def full_rows(rate: np.ndarray, rows: int) -> np.ndarray:
    """A per-row rate: block-mean rates are repeated over their block's rows.

    Parameters
    ----------
    rate : ndarray, shape (rows, W) or (rows / b, W)
        A generation rate (e-/s).
    rows : int
        Full-frame rows.

    Returns
    -------
    ndarray, shape (rows, W)
        The rate per pixel row (e-/s).
    """
    return rate if rate.shape[0] == rows else np.repeat(rate, rows // rate.shape[0], axis=0)


def _block_sums(rate: np.ndarray, binning_rows: int, rows: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per block: the plain sum of its rows and the sum weighted b, b-1, ..., 1 (first row heaviest).

    A block-mean rate (``rows`` given and ``rate`` of shape (rows / b, W)) stands for ``b`` equal rows:
    sums ``b m`` and ``b (b + 1) / 2 m``.
    """
    if rows is not None and is_block_mean(rate, rows, binning_rows):
        mean = rate.astype(np.float32, copy=False)
        return mean * np.float32(binning_rows), mean * np.float32(binning_rows * (binning_rows + 1) / 2)
    rows, width = rate.shape
    blocks = rate.reshape(rows // binning_rows, binning_rows, width)
    plain = blocks[:, 0].astype(np.float32, copy=True)
    weighted = plain * np.float32(binning_rows)
    for offset in range(1, binning_rows):
        row = blocks[:, offset]
        plain += row
        weighted += np.float32(binning_rows - offset) * row
    return plain, weighted


def max_pixel_charge_bound_e(rate_flush: np.ndarray, rate_exposure: np.ndarray, rate_transfer: np.ndarray,
                             timing: Timing) -> float:
    """An upper bound on any pixel's charge, cheap: used to skip the full-resolution path.

    Parameters
    ----------
    rate_flush, rate_exposure, rate_transfer : ndarray, shape (N, W) or (N / b, W)
        Generation rates (e-/s) of the fast flush, exposure and frame transfer; the smear rates may be
        block means.
    timing : Timing
        The CCD timing (flush, exposure, transfer durations, transfer direction).

    Returns
    -------
    float
        Bound (e-).
    """
    rows = rate_exposure.shape[0]
    flush_column = float(rate_flush.sum(axis=0).max()) * rows / rate_flush.shape[0]
    transfer_column = float(rate_transfer.sum(axis=0).max()) * rows / rate_transfer.shape[0]
    return (timing.exposure_s * float(rate_exposure.max()) + timing.fast_flush_s / rows * flush_column
            + timing.frame_transfer_s / rows * transfer_column)
