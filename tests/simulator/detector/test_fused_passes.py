"""The camera chain's compiled (numba) passes against their definitions written out in numpy: the rate block
sums and the field's extremes, the OTF product with the fold, the smear fields read in the exposure's pass,
the read-out, and the per-thread work arrays they use (an image's result is never overwritten by the next)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from simulator.detector import charge_transfer, float_bits, psf, readout
from simulator.detector.camera_chain import expected_charge_e, pixel_gain, render_image
from simulator.fields import RadianceFields


def _field(seed: int, mean: float = 30.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (mean + 5.0 * rng.standard_normal((1024, 1024))).clip(0.0).astype(np.float32)


def _rate_sums_by_definition(field, gain, b, toward_last, offset):
    """Plain and ramp-weighted (b, b - 1, .., 1 from the first row the charge meets) block sums, float64."""
    rate = field.astype(np.float64) * gain.astype(np.float64) + offset
    blocks = rate.reshape(-1, b, rate.shape[1])
    if not toward_last:
        blocks = blocks[::-1, ::-1]
    weights = np.arange(b, 0, -1, dtype=np.float64)[None, :, None]
    return blocks.sum(axis=1), (blocks * weights).sum(axis=1)


@pytest.mark.parametrize("toward_last", [True, False])
@pytest.mark.parametrize("offset", [0.0, 12.5])
def test_rate_sums_and_extremes_are_their_definition(toward_last, offset):
    field = _field(1)
    gain = (900.0 + 10.0 * np.random.default_rng(2).standard_normal((1024, 1024))).astype(np.float32)
    plain, ramp, sums, smallest, largest = charge_transfer.checked_block_rate_sums(field, gain, 4, toward_last, offset)
    want_plain, want_ramp = _rate_sums_by_definition(field, gain, 4, toward_last, offset)
    np.testing.assert_allclose(plain, want_plain, rtol=1e-6)
    np.testing.assert_allclose(ramp, want_ramp, rtol=1e-6)
    radiance = field.astype(np.float64).reshape(256, 4, 1024).sum(axis=1)
    np.testing.assert_allclose(sums, radiance if toward_last else radiance[::-1], rtol=1e-6)
    assert (smallest, largest) == (float(field.min()), float(field.max()))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_value_that_is_not_finite_makes_both_extremes_nan(bad):
    field = _field(3)
    field[700, 3] = bad
    *_, smallest, largest = charge_transfer.checked_block_rate_sums(field, np.ones_like(field), 4, True)
    assert np.isnan(smallest) and np.isnan(largest)


def _bit_extremes(field: np.ndarray) -> tuple[float, float]:
    state = float_bits.new_state()[0]
    for row in field:
        float_bits.add_row(np.ascontiguousarray(row), state)
    return float_bits.extremes(state, field)


@pytest.mark.parametrize("special", [None, 0.0, 1e-42, 3.0e38, -0.0, -2.5, np.nan, -np.nan, np.inf, -np.inf])
def test_extremes_from_bit_patterns_are_numpys(special):
    """Min and max (both NaN when a value is not finite) from the patterns: zero, subnormal, huge, signed, special."""
    field = np.random.default_rng(13).uniform(0.5, 40.0, (64, 96)).astype(np.float32)
    if special is not None:
        field[17, 41] = special
    smallest, largest = _bit_extremes(field)
    if not np.isfinite(field).all():
        assert np.isnan(smallest) and np.isnan(largest)
    else:
        assert (smallest, largest) == (float(field.min()), float(field.max()))
        assert np.signbit(smallest) == np.signbit(field.min())


def test_fold_of_the_spectrum_samples_every_fourth_row():
    """Without an OTF the inverse DFT of the folded spectrum is every 4th row of the signal, times 4."""
    signal = np.random.default_rng(4).random((64, 48)).astype(np.float32)
    folded = psf._fold_packed_rows(cv2.dft(signal), 4)
    sampled = cv2.idft(folded, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    np.testing.assert_allclose(sampled, 4.0 * signal[::4], atol=1e-5)


def test_the_fold_reads_one_otf_value_per_frequency_and_refuses_an_otf_that_is_not():
    rng = np.random.default_rng(5)
    spectrum = rng.standard_normal((64, 48)).astype(np.float32)
    otf = np.repeat(rng.random((64, 25)).astype(np.float32), 2, axis=1)[:, 1:-1]    # (Re, Im) pairs equal
    with_otf = psf._fold_packed_rows(spectrum, 4, otf).copy()
    by_numpy = (spectrum * otf).reshape(4, 16, 48).sum(axis=0)      # the band sums of the product
    np.testing.assert_allclose(with_otf[:, 1:-1], by_numpy[:, 1:-1], rtol=1e-5, atol=1e-6)
    otf[3, 5] += 0.25
    with pytest.raises(ValueError, match="differ"):
        psf._fold_packed_rows(spectrum, 4, otf)


def test_smear_fields_read_in_the_exposures_pass_give_their_own_sums(mer_a):
    exposure, flush, transfer = _field(6), _field(7, 10.0), _field(8, 50.0)
    gain = pixel_gain(mer_a)
    sums = psf.binned_blur_rate_sums(exposure, mer_a, 4, gain, 3.0, (flush, transfer))
    alone = psf.binned_blur_sums(exposure, mer_a, 4)
    np.testing.assert_array_equal(np.maximum(sums.blurred, 0.0), alone[0])
    np.testing.assert_array_equal(sums.plain, alone[1])
    for field, read in zip((exposure, flush, transfer),
                           ((sums.rate_plain, sums.rate_ramp, None, sums.smallest, sums.largest), *sums.smear)):
        plain, ramp, radiance, smallest, largest = charge_transfer.checked_block_rate_sums(field, gain, 4, True, 3.0)
        np.testing.assert_array_equal(read[0], plain)
        np.testing.assert_array_equal(read[1], ramp)
        if read[2] is not None:
            np.testing.assert_array_equal(read[2], radiance)
        assert (read[3], read[4]) == (smallest, largest)


def test_a_smear_field_that_is_not_finite_sends_the_image_to_the_full_resolution_stages(mer_a):
    exposure, flush = _field(9), _field(10)
    flush[100, 100] = np.nan
    fields = RadianceFields(flush, exposure, np.roll(exposure, 1, axis=1))
    charge = expected_charge_e(mer_a, fields)
    np.testing.assert_array_equal(charge, expected_charge_e(mer_a, fields, full_resolution=True))


def test_a_negative_smear_field_is_refused(mer_a):
    exposure, transfer = _field(11), _field(12)
    transfer[5, 5] = -1.0
    with pytest.raises(ValueError, match="negative"):
        expected_charge_e(mer_a, RadianceFields(exposure, exposure, transfer))


def test_fused_read_out_is_the_numpy_digitisation(mer_a):
    """The same draws through noisy_charge_e's Gaussian form and digitize / expected_dn in float64."""
    electronics = mer_a.electronics
    rng = np.random.default_rng(13)
    mean = rng.uniform(1500.0, 1.1 * electronics.binned_full_well_e, (256, 1024)).astype(np.float32)
    dn, expected = readout.read_out_dn(np.random.default_rng(14), mean, electronics)
    draws = readout.standard_normal_f32(np.random.default_rng(14), mean.shape).astype(np.float64)
    noisy = mean + np.sqrt(mean + electronics.read_noise_e ** 2) * draws
    want = readout.digitize(noisy, electronics)
    level = np.minimum(noisy, electronics.binned_full_well_e) / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn
    near_half = np.abs(level - np.floor(level) - 0.5) < 1e-3          # float32 rounding may go either way
    assert np.array_equal(dn[~near_half], want[~near_half])
    assert np.abs(dn.astype(int) - want).max() <= 1
    np.testing.assert_allclose(expected, readout.expected_dn(mean.astype(np.float64), electronics), atol=2e-3)


def test_dim_pixels_keep_exact_poisson_in_the_fused_read_out(mer_a):
    electronics = mer_a.electronics
    mean = np.full((256, 1024), 3000.0, dtype=np.float32)
    mean[:8] = 0.0                  # no charge, no shot noise: read noise alone
    dn, _ = readout.read_out_dn(np.random.default_rng(15), mean, electronics, read_noise=False)
    assert np.all(dn[:8] == np.rint(electronics.adc_offset_dn))
    assert dn[8:].std() > 0


def test_an_image_is_not_overwritten_by_the_next_one(mer_a):
    """The chain's work arrays are reused image after image; its results are not."""
    first_fields = RadianceFields(_field(16), _field(17), _field(18))
    first = render_image(mer_a, first_fields, np.random.default_rng(19))
    kept = [first.dn.copy(), first.expected_dn.copy(), first.expected_charge_e.copy()]
    render_image(mer_a, RadianceFields(_field(20), _field(21), _field(22)), np.random.default_rng(23))
    for array, copy in zip((first.dn, first.expected_dn, first.expected_charge_e), kept):
        np.testing.assert_array_equal(array, copy)
    again = render_image(mer_a, first_fields, np.random.default_rng(19))
    np.testing.assert_array_equal(again.dn, first.dn)


def _block_field(seed: int, mean: float) -> np.ndarray:
    return _field(seed, mean).reshape(256, 4, 1024).mean(axis=1).astype(np.float32)


@pytest.mark.parametrize("toward_last", [True, False])
@pytest.mark.parametrize("offset", [0.0, 12.5])
def test_block_smear_fields_share_one_row_transform_with_the_steps_bits(mer_a, toward_last, offset):
    """Two per-block smear fields through one row transform: the bits of the line-spread blur, its clip, the rate
    and the sums of a block-mean rate (b and b (b + 1) / 2 times it), one field after the other."""
    flush, transfer = _block_field(24, 10.0), _block_field(25, 50.0)
    flush[:, 300:340] = 0.0                      # a dark band by a bright line
    flush[:, 340] = 1000.0
    gain = pixel_gain(mer_a, per_block=True)
    read = psf.row_blurred_block_rate_sums((flush, transfer), mer_a, gain, offset, 4, toward_last)
    assert read is not None
    for field, (plain, ramp, largest) in zip((flush, transfer), read):
        blurred = psf.blur_field_along_rows(field, mer_a)
        rate = blurred * gain
        if offset:
            rate += np.float32(offset)
        if not toward_last:
            rate = rate[::-1]
        np.testing.assert_array_equal(plain, rate * np.float32(4))
        np.testing.assert_array_equal(ramp, rate * np.float32(10))
        assert largest == float(blurred.max())


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0])
def test_a_block_smear_field_that_is_not_finite_or_negative_is_left_to_the_steps(mer_a, bad):
    flush = _block_field(26, 10.0)
    flush[7, 9] = bad
    gain = pixel_gain(mer_a, per_block=True)
    assert psf.row_blurred_block_rate_sums((flush,), mer_a, gain, 0.0, 4, True) is None


def test_per_block_smear_fields_give_the_chain_the_bits_of_the_step_by_step_path(mer_a, monkeypatch):
    from simulator.detector import camera_chain

    fields = RadianceFields(_block_field(27, 20.0), _field(28), _block_field(29, 40.0))
    fused = expected_charge_e(mer_a, fields)
    monkeypatch.setattr(camera_chain, "_row_blurred_block_smear", lambda state, gains: {})
    np.testing.assert_array_equal(fused, expected_charge_e(mer_a, fields))


def test_the_block_smear_pass_clips_as_numpy_does():
    """Ringing below 0 reads 0 and a -0.0 reads +0.0 (np.maximum's bits)."""
    blurred = np.array([[-2.0, -0.0, 0.0, 3.0]], dtype=np.float32)
    gain = np.full_like(blurred, 2.0)
    plain, ramp = np.empty_like(blurred), np.empty_like(blurred)
    psf._clipped_block_rate_sums(blurred, gain, np.float32(0.0), False, np.float32(4.0), np.float32(10.0), True,
                                 plain, ramp)
    rate = np.maximum(blurred, np.float32(0.0)) * gain
    np.testing.assert_array_equal(plain.view(np.uint32), (rate * np.float32(4.0)).view(np.uint32))
    np.testing.assert_array_equal(ramp.view(np.uint32), (rate * np.float32(10.0)).view(np.uint32))
