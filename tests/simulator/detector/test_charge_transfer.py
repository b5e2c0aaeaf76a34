"""simulator.detector.charge_transfer: frame-transfer smear against the charge-packet sums written out by
hand (uniform rates, one bright row), both transfer directions, and binning as a plain sum of rows."""
from __future__ import annotations

import numpy as np
import pytest

from flight_interface.camera_file import Timing
from simulator.detector import charge_transfer

T_F, T_E, T_T = 0.004, 0.005, 0.003


def _timing(direction: str = "toward_last_row") -> Timing:
    return Timing(fast_flush_s=T_F, exposure_s=T_E, frame_transfer_s=T_T, transfer_direction=direction)


def test_uniform_rates_give_the_linear_smear_ramps():
    rows, width = 16, 3
    g_f, g_e, g_t = 100.0, 1000.0, 50.0
    charge = charge_transfer.pixel_charge_e(np.full((rows, width), g_f), np.full((rows, width), g_e),
                                            np.full((rows, width), g_t), _timing())
    r = np.arange(rows)[:, None]
    # flush: the packet crossed rows 0..r; transfer: rows r..N-1 (each for T/N)
    expected = T_F / rows * (r + 1) * g_f + T_E * g_e + T_T / rows * (rows - r) * g_t
    assert np.allclose(charge, np.broadcast_to(expected, (rows, width)), rtol=1e-5)


@pytest.mark.parametrize("direction", ["toward_last_row", "toward_first_row"])
def test_one_bright_row_smears_flush_on_one_side_and_transfer_on_the_other(direction):
    rows, bright, g = 12, 5, 1.0e6
    rate = np.zeros((rows, 2), np.float32)
    rate[bright] = g
    charge = charge_transfer.pixel_charge_e(rate, np.zeros_like(rate), rate, _timing(direction))[:, 0]
    r = np.arange(rows)
    if direction == "toward_last_row":
        flush_hit, transfer_hit = r >= bright, r <= bright
    else:
        flush_hit, transfer_hit = r <= bright, r >= bright
    expected = T_F / rows * g * flush_hit + T_T / rows * g * transfer_hit
    assert np.allclose(charge, expected, rtol=1e-5)


@pytest.mark.parametrize("direction", ["toward_last_row", "toward_first_row"])
def test_binned_charge_is_the_sum_of_the_full_resolution_rows(direction):
    rng = np.random.default_rng(3)
    rows, width, b = 32, 5, 4
    flush, exposure, transfer = (rng.uniform(0, 1e5, (rows, width)).astype(np.float32) for _ in range(3))
    full = charge_transfer.pixel_charge_e(flush, exposure, transfer, _timing(direction)).astype(np.float64)
    binned = charge_transfer.binned_charge_e(flush, exposure, transfer, _timing(direction), b)
    assert binned.shape == (rows // b, width) and binned.dtype == np.float32
    assert np.allclose(binned, full.reshape(rows // b, b, width).sum(axis=1), rtol=1e-4)
    assert charge_transfer.max_pixel_charge_bound_e(flush, exposure, transfer, _timing(direction)) >= full.max()
    # a still image: one rate object for the three periods (its block sums are shared inside)
    still = charge_transfer.binned_charge_e(exposure, exposure, exposure, _timing(direction), b)
    still_full = charge_transfer.pixel_charge_e(exposure, exposure, exposure, _timing(direction)).astype(np.float64)
    assert np.allclose(still, still_full.reshape(rows // b, b, width).sum(axis=1), rtol=1e-4)


def test_block_mean_rates_stand_for_equal_rows():
    rows, b = 8, 4
    per_block = np.array([[2.0], [6.0]], np.float32)
    assert charge_transfer.is_block_mean(per_block, rows, b) and not charge_transfer.is_block_mean(per_block, rows, 1)
    assert np.array_equal(charge_transfer.full_rows(per_block, rows)[:, 0], [2, 2, 2, 2, 6, 6, 6, 6])
    exposure = np.zeros((rows, 1), np.float32)
    from_blocks = charge_transfer.binned_charge_e(per_block, exposure, per_block, _timing(), b)
    from_rows = charge_transfer.binned_charge_e(charge_transfer.full_rows(per_block, rows), exposure,
                                                charge_transfer.full_rows(per_block, rows), _timing(), b)
    assert np.allclose(from_blocks, from_rows, rtol=1e-6)
    assert np.allclose(charge_transfer.cumsum_rows(np.arange(6, dtype=np.float32).reshape(3, 2)), [[0, 1], [2, 4], [6, 9]])
