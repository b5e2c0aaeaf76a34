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
from numba import njit

from flight_interface.camera_file import Timing
from simulator.detector import float_bits
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
                            rows: int, row_offset_e: np.ndarray | None = None) -> np.ndarray:
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
    row_offset_e : ndarray, shape (N / b, 1), optional
        Charge added to every pixel of a binned row after the rest (e-; the storage dark), in the same
        pass: the float32 sum ``charge + offset`` a separate addition gives.

    Returns
    -------
    ndarray, shape (N / b, W), float32
        Charge per binned pixel (e-).
    """
    flush_blocks, flush_ramp = (np.ascontiguousarray(sums, dtype=np.float32) for sums in flush_sums)
    shared = transfer_sums[0] is flush_sums[0]
    transfer_blocks, transfer_ramp = (np.ascontiguousarray(sums, dtype=np.float32) for sums in transfer_sums)
    charge = np.empty(flush_blocks.shape, dtype=np.float32)
    with_offset = row_offset_e is not None
    offsets = (np.ascontiguousarray(np.reshape(row_offset_e, -1), dtype=np.float32) if row_offset_e is not None
               else np.zeros(flush_blocks.shape[0], dtype=np.float32))
    _binned_charge_kernel(flush_blocks, flush_ramp, shared, transfer_blocks, transfer_ramp,
                          np.ascontiguousarray(exposure_blocks, dtype=np.float32), timing.transfer_toward_last_row,
                          np.float32(binning_rows), np.float32(timing.fast_flush_s / rows),
                          np.float32(timing.frame_transfer_s / rows), np.float32(timing.exposure_s),
                          _cumsum_group(flush_blocks.shape[0]), scratch("charge_flush_through", charge.shape),
                          scratch("charge_transfer_from", charge.shape), with_offset, offsets, charge)
    return charge


def _cumsum_group(rows: int) -> int:
    """Rows per group of :func:`cumsum_rows` (``~ sqrt(rows)``, dividing ``rows``)."""
    group = max(int(np.sqrt(rows)), 1)
    while rows % group:
        group -= 1
    return group


@njit(cache=True, nogil=True, boundscheck=False)
def _grouped_cumsum(values, reverse, group, out):
    """:func:`cumsum_rows` into ``out``: the same float32 additions in the same order.

    Running sums within groups of ``group`` rows, each group's total carried into the next; with
    ``reverse`` the cumulative sum of ``values[::-1]``, written back reversed.
    """
    rows, width = values.shape
    within = np.empty(width, dtype=np.float32)
    carry = np.zeros(width, dtype=np.float32)
    for index in range(rows):
        source = rows - 1 - index if reverse else index
        row = values[source]
        target = out[source]
        if index % group == 0:
            for col in range(width):
                within[col] = row[col]
        else:
            for col in range(width):
                within[col] += row[col]
        if index < group:
            for col in range(width):
                target[col] = within[col]
        else:
            for col in range(width):
                target[col] = within[col] + carry[col]
        if index % group == group - 1:
            for col in range(width):
                carry[col] = target[col]


@njit(cache=True, nogil=True, boundscheck=False)
def _binned_charge_kernel(flush_blocks, flush_ramp, shared, transfer_blocks, transfer_ramp, exposure_blocks,
                          toward_last_row, binning_rows, flush_scale, transfer_scale, exposure_s, group, flush_through,
                          transfer_from, with_offset, row_offsets, charge):
    """:func:`binned_charge_from_sums`, compiled: the float32 operations of the numpy form, in its order.

    ``flush_through``, ``transfer_from``: work arrays of the charge's shape. With ``with_offset``,
    ``row_offsets[k]`` (float32) is added to every pixel of binned row ``k`` (image order) last.
    """
    blocks, width = flush_blocks.shape
    _grouped_cumsum(flush_blocks, False, group, flush_through)        # blocks up to and including
    if not shared:                                                     # blocks from this one on
        _grouped_cumsum(transfer_blocks, True, group, transfer_from)
    total = flush_through[blocks - 1]
    ramp_weight = binning_rows + np.float32(1.0)
    for block in range(blocks):
        through, plain, ramp = flush_through[block], flush_blocks[block], flush_ramp[block]
        after_source, transfer_plain, transfer_weighted = transfer_from[block], transfer_blocks[block], transfer_ramp[block]
        image_block = block if toward_last_row else blocks - 1 - block
        exposure, out = exposure_blocks[image_block], charge[image_block]
        for col in range(width):
            if shared:        # after = total - up to and including
                after = total[col] - through[col]
            else:
                after = after_source[col] - transfer_plain[col]
            flush_smear = ((through[col] - plain[col]) * binning_rows + ramp[col]) * flush_scale
            transfer_smear = ((after * binning_rows + ramp_weight * transfer_plain[col]) - transfer_weighted[col]) * transfer_scale
            out[col] = exposure[col] * exposure_s + (flush_smear + transfer_smear)
        if with_offset:
            row_offset = row_offsets[image_block]
            for col in range(width):
                out[col] += row_offset


def add_blur_change(plain: np.ndarray, ramp: np.ndarray, blurred: np.ndarray, unblurred: np.ndarray,
                    block_gain: np.ndarray, toward_last_row: bool, binning_rows: int) -> None:
    """Add the blur's change of a period's block sums to its rate sums, in place (one compiled pass).

    ``change = (max(blurred, 0) - unblurred) x block gain`` per block (the clip: a band-limited blur's ringing
    next to a sky edge); ``plain += change`` and ``ramp += change x (b + 1) / 2`` (the change spread evenly
    over the block's rows).

    Parameters
    ----------
    plain, ramp : ndarray, float32, shape (N / b, W)
        The rate's plain and ramp-weighted block sums (e-/s), in the order the charge moves; updated.
    blurred, unblurred : ndarray, float32, shape (N / b, W)
        Block sums of the blurred and of the unblurred radiance (W m^-2 sr^-1 um^-1), in image order
        (``blurred`` may be a view with strided rows).
    block_gain : ndarray, float32, shape (N / b, W)
        Mean gain of each block (e-/s per W m^-2 sr^-1 um^-1), in image order.
    toward_last_row : bool
        The charge moves toward the last row (else the sums are in reversed block order).
    binning_rows : int
        Rows per block ``b``.

    Returns
    -------
    None
    """
    if blurred.dtype != np.float32 or blurred.strides[1] != blurred.itemsize:
        blurred = np.ascontiguousarray(blurred, dtype=np.float32)
    _add_blur_change_kernel(plain, ramp, blurred,
                            np.ascontiguousarray(unblurred, dtype=np.float32),
                            np.ascontiguousarray(block_gain, dtype=np.float32), toward_last_row,
                            np.float32((binning_rows + 1) / 2))


@njit(cache=True, nogil=True, boundscheck=False)
def _add_blur_change_kernel(plain, ramp, blurred, unblurred, block_gain, toward_last_row, ramp_factor):
    blocks, width = plain.shape
    zero = np.float32(0.0)
    for block in range(blocks):
        image_block = block if toward_last_row else blocks - 1 - block
        new, old, gain = blurred[image_block, :width], unblurred[image_block], block_gain[image_block]
        block_plain, block_ramp = plain[block], ramp[block]
        for col in range(width):
            change = (max(new[col], zero) - old[col]) * gain[col]
            block_plain[col] += change
            block_ramp[col] += change * ramp_factor


def column_sum_max(values: np.ndarray) -> float:
    """The largest column sum of a (N, W) array, summed in float32 row by row (as numpy's ``sum(axis=0)``).

    Parameters
    ----------
    values : ndarray, float32, shape (N, W)
        Values (e.g. block sums of a rate, e-/s).

    Returns
    -------
    float
        ``max_c sum_r values[r, c]`` (NaN propagates).
    """
    return float(_column_sum_max_kernel(np.ascontiguousarray(values, dtype=np.float32)))


@njit(cache=True, nogil=True, boundscheck=False)
def _column_sum_max_kernel(values):
    rows, width = values.shape
    sums = values[0].copy()
    for row in range(1, rows):
        line = values[row]
        for col in range(width):
            sums[col] += line[col]
    largest = sums[0]
    for col in range(width):
        if not sums[col] <= largest:      # NaN wins
            largest = sums[col]
    return largest


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
    plain, ramp, field_sums, _, _ = checked_block_rate_sums(radiance, gain, binning_rows, toward_last_row,
                                                            offset_e_per_s, radiance_sums)
    return plain, ramp, field_sums


def checked_block_rate_sums(radiance: np.ndarray, gain: np.ndarray, binning_rows: int, toward_last_row: bool,
                            offset_e_per_s: float = 0.0, radiance_sums: bool = True, scratch_name: str | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float, float]:
    """:func:`block_rate_sums` with the radiance's smallest and largest value, from the same pass.

    One compiled pass over the rows (numba): per pixel the float32 product ``radiance x gain`` (inf where it
    overflows: a saturating rate), summed into its block's plain and ramp-weighted sums in the order
    the charge moves, the radiance summed likewise, and its extremes from the bit patterns (:mod:`simulator.detector.float_bits`).

    Parameters
    ----------
    radiance, gain, binning_rows, toward_last_row, offset_e_per_s, radiance_sums
        As :func:`block_rate_sums`.
    scratch_name : str, optional
        Give the sums in this thread's scratch arrays of this name (:func:`simulator.scratch.scratch`; valid
        until the next call with the name) instead of new arrays.

    Returns
    -------
    (plain, ramp, radiance_sums, smallest, largest)
        The sums of :func:`block_rate_sums` and the radiance's minimum and maximum (W m^-2 sr^-1 um^-1):
        both NaN when a value is not finite.
    """
    rows, width = radiance.shape
    blocks = rows // binning_rows
    field = np.ascontiguousarray(radiance, dtype=np.float32)
    gains = np.ascontiguousarray(gain, dtype=np.float32)
    def output(name: str, shape: tuple[int, int]) -> np.ndarray:
        return np.empty(shape, dtype=np.float32) if scratch_name is None else scratch(f"{scratch_name}_{name}", shape)

    plain = output("plain", (blocks, width))
    ramp = output("ramp", (blocks, width))
    field_sums = output("radiance", (blocks if radiance_sums else 1, width))
    bit_state = float_bits.new_state()
    _block_rate_sums_kernel(field, gains, binning_rows, toward_last_row, np.float32(binning_rows * offset_e_per_s),
                            np.float32(binning_rows * (binning_rows + 1) / 2 * offset_e_per_s), bool(offset_e_per_s),
                            plain, ramp, bool(radiance_sums), field_sums, bit_state[0])
    smallest, largest = float_bits.extremes(bit_state[0], field)
    return plain, ramp, field_sums if radiance_sums else None, smallest, largest


@njit(cache=True, nogil=True, boundscheck=False)
def add_row_to_block(values, gains, first, block_plain, block_ramp, with_field, block_field):
    """Add one frame row's rate ``values x gains`` to its binning block's running sums (in place).

    Parameters
    ----------
    values, gains : ndarray, shape (W,), float32
        The row's radiance and gain.
    first : bool
        The block's first row read (the sums start from it).
    block_plain, block_ramp : ndarray, shape (W,), float32
        The block's plain rate sum and its ramp-weighted sum (the running sum of the plain sums).
    with_field : bool
        Also add the row's values to ``block_field``.
    block_field : ndarray, shape (W,), float32
        The block's sum of ``values`` (unused unless ``with_field``).
    """
    width = values.shape[0]
    if first:
        for col in range(width):
            product = values[col] * gains[col]
            block_plain[col] = product
            block_ramp[col] = product
    else:
        for col in range(width):
            total = block_plain[col] + values[col] * gains[col]
            block_plain[col] = total
            block_ramp[col] += total
    if with_field:
        if first:
            for col in range(width):
                block_field[col] = values[col]
        else:
            for col in range(width):
                block_field[col] += values[col]


@njit(cache=True, nogil=True, boundscheck=False)
def _block_rate_sums_kernel(field, gain, binning_rows, toward_last_row, plain_offset, ramp_offset, add_offset,
                            plain, ramp, with_sums, field_sums, bit_state):
    """:func:`checked_block_rate_sums`' pass.

    ``field_sums`` has one unused row unless ``with_sums``. ``bit_state``: the field's extremes as bit
    patterns (:mod:`simulator.detector.float_bits`), updated.
    """
    blocks, width = plain.shape
    for block in range(blocks):
        image_block = block if toward_last_row else blocks - 1 - block
        block_plain, block_ramp = plain[block], ramp[block]
        block_field = field_sums[block if with_sums else 0]
        for offset in range(binning_rows):
            row = image_block * binning_rows + (offset if toward_last_row else binning_rows - 1 - offset)
            values = field[row]
            add_row_to_block(values, gain[row], offset == 0, block_plain, block_ramp, with_sums, block_field)
            float_bits.add_row(values, bit_state)
        if add_offset:
            for col in range(width):
                block_plain[col] += plain_offset
                block_ramp[col] += ramp_offset


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
