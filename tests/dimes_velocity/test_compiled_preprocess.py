"""The flattening's compiled (numba) passes against their numpy definition: the same bits.

An integer image takes the compiled passes (uint16 binned 4:1 as uint64 words; other integers of up to 16 bits
column by column); the same image as float32 takes the numpy passes (``bin_columns``, ``unsmear`` and the
in-place float32 operations of ``flatten``), whose sums of integer DN are the same exact integers. Both must give
the same signal, charge and excluded blocks, with and without smear removal, saturated blocks or not.
"""
from __future__ import annotations

import numpy as np
import pytest

from dimes_velocity import compiled
from dimes_velocity.config import EstimatorConfig
from dimes_velocity.preprocess import bin_columns, flatten, make_flattening


def _raw(seed, shape, low, high):
    rng = np.random.default_rng(seed)
    return rng.integers(low, high, shape).astype(np.uint16)


def _assert_same(first, second):
    assert np.array_equal(first.signal_dn, second.signal_dn)
    assert np.array_equal(first.charge_e, second.charge_e)
    assert np.array_equal(first.excluded, second.excluded) and first.excluded.dtype == second.excluded.dtype
    assert first.dark_fraction == second.dark_fraction and first.saturated_fraction == second.saturated_fraction


@pytest.mark.parametrize("remove_smear", [True, False])
@pytest.mark.parametrize("bright", [False, True])
def test_flatten_of_integer_images_is_the_numpy_definition(mer_a, remove_smear, bright):
    config = EstimatorConfig(remove_smear=remove_smear)
    flattening = make_flattening(mer_a, config)
    raw = _raw(3, flattening.raw_shape, 0, 4095 if bright else 700)      # bright: saturated blocks
    raw[:16] = round(mer_a.electronics.adc_offset_dn)                      # a band of dark blocks
    compiled_result = flatten(raw, flattening, config)
    numpy_result = flatten(raw.astype(np.float32), flattening, config)
    _assert_same(compiled_result, numpy_result)
    assert compiled_result.dark_fraction > 0.0
    assert (compiled_result.saturated_fraction > 0.0) == bright
    _assert_same(flatten(raw.astype(np.int16), flattening, config), numpy_result)      # the column-by-column pass


def test_uint16_words_bin_as_the_columns():
    raw = _raw(5, (64, 256), 0, 65535)
    gain, offset = np.float32(3.7), np.float32(12.5)
    dark = np.linspace(0.0, 2.0, 64, dtype=np.float32)[:, None]
    want = (bin_columns(raw, 4) - offset - dark) * gain        # exact integer sums (4 x 65535 < 2^24) in float32
    assert np.array_equal(compiled.binned_charge_u16x4(raw.view(np.uint64), offset, dark, gain), want)
    assert np.array_equal(compiled.binned_charge(raw, 4, offset, dark, gain), want)
    assert np.array_equal(compiled.binned_charge(raw, 2, offset, dark, gain), (bin_columns(raw, 2) - offset - dark) * gain)
