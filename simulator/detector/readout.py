"""Measurement and readout: shot noise, read noise, full well, ADC gain, quantisation and clipping.

Stage 4 of the camera chain, at binned resolution. On-chip binning sums the charge of independent
pixels before the output amplifier, and a sum of independent Poisson variables is Poisson with the
summed mean, so drawing shot noise on the binned mean is exact in distribution (as long as no single
pixel is clipped at full well, which :func:`simulator.detector.camera_chain.render_image` handles before binning).

Fidelity shortcut (:func:`noisy_charge_e` with ``exact_poisson=False``, the default preset): where the
binned mean is at least :data:`GAUSSIAN_MIN_MEAN_E` the Poisson draw is replaced by a Gaussian of the
same mean and variance, merged with the read noise into one float32 normal draw (OpenCV's ``randn``
seeded from the image's stream: 15x cheaper than numpy's Poisson sampler). The two distributions differ only through the Poisson skewness
``1 / sqrt(mean)`` (<= 3 % at 1000 e-, a shift of the median by ``1/3`` e-, far below the 150 e-/DN
quantisation step); below the threshold (sky, shadows) the draw stays exact Poisson.

Exact presets (``exact_poisson=True``: ``reference``, ``high``): every pixel exact Poisson plus Gaussian
read noise, drawn from the same float32 normal deviates as the default (same stream, same first call)
by inversion, ``F^-1(Phi(u); m)``, of a rotation of them with one more normal per pixel
(:mod:`simulator.detector.coupled_poisson`): the presets compared on the same seeds carry the same
noise up to the Poisson skewness, so their differences are those of the rendering.
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from flight_interface.camera_file import Electronics
from simulator.detector import coupled_poisson, opencv_normal
from simulator.scratch import scratch


def shot_noise_e(rng: np.random.Generator, mean_e: np.ndarray) -> np.ndarray:
    """Poisson draw of the photo + thermal electrons.

    Exact for means up to :data:`MAX_POISSON_MEAN_E` (numpy's limit is ~9.2e18), above which the mean
    itself is returned (relative noise < 1e-9, and any such charge is far beyond every full well).

    Parameters
    ----------
    rng : numpy.random.Generator
        Noise stream.
    mean_e : ndarray
        Expected charge (e-), >= 0.

    Returns
    -------
    ndarray, float64, shape of ``mean_e``
        Drawn charge (e-).
    """
    mean = np.maximum(mean_e, 0.0)
    huge = mean > MAX_POISSON_MEAN_E
    if not huge.any():
        return rng.poisson(mean).astype(np.float64)
    noisy = rng.poisson(np.where(huge, 0.0, mean)).astype(np.float64)
    noisy[huge] = np.asarray(mean, dtype=np.float64)[huge]
    return noisy


GAUSSIAN_MIN_MEAN_E = 1000.0
MAX_POISSON_MEAN_E = 1.0e18


def noisy_charge_e(rng: np.random.Generator, mean_e: np.ndarray, read_noise_sigma_e: float,
                   shot_noise: bool = True, read_noise: bool = True, exact_poisson: bool = False) -> np.ndarray:
    """Charge with shot and read noise.

    Parameters
    ----------
    rng : numpy.random.Generator
        Noise stream (shot noise first, then read noise).
    mean_e : ndarray
        Expected charge per binned pixel (e-); negative values count as 0.
    read_noise_sigma_e : float
        Output-amplifier noise (e- rms).
    shot_noise, read_noise : bool
        Switches of the two noise sources.
    exact_poisson : bool
        True draws every pixel from Poisson and adds Gaussian read noise (reference), both from the
        normal deviates the default draws (:mod:`simulator.detector.coupled_poisson`); False uses the
        Gaussian approximation above :data:`GAUSSIAN_MIN_MEAN_E` (see module doc).

    Returns
    -------
    ndarray, float64, shape of ``mean_e``
        Charge (e-).
    """
    mean = np.maximum(mean_e, 0.0)
    read_sigma = read_noise_sigma_e if read_noise and read_noise_sigma_e > 0 else 0.0
    if shot_noise and not exact_poisson:
        return _gaussian_shot_and_read_noise_e(rng, mean, read_sigma)
    if shot_noise:      # exact Poisson on the default's deviates (common random numbers, coupled_poisson)
        return coupled_poisson.coupled_shot_and_read_noise_e(standard_normal_f32(rng, mean.shape), rng, mean,
                                                             read_sigma)
    noisy = mean.astype(np.float64)
    return noisy + read_noise_e(rng, noisy.shape, read_sigma) if read_sigma else noisy


def _gaussian_shot_and_read_noise_e(rng: np.random.Generator, mean_e: np.ndarray, read_sigma_e: float) -> np.ndarray:
    """Shot and read noise: Gaussian where the mean is high, exact Poisson below.

    One normal draw of variance ``mean + sigma_read^2`` where the mean is at least
    :data:`GAUSSIAN_MIN_MEAN_E`; exact Poisson plus read noise for the dimmer pixels (drawn after the
    bulk, so the stream is fixed).
    """
    mean32 = mean_e.astype(np.float32)
    low = mean32 < np.float32(GAUSSIAN_MIN_MEAN_E)
    sigma = np.sqrt(mean32 + np.float32(read_sigma_e ** 2))
    noisy = (mean32 + sigma * standard_normal_f32(rng, mean32.shape)).astype(np.float64)
    if low.any():
        dim = shot_noise_e(rng, mean32[low].astype(np.float64))
        noisy[low] = dim + read_noise_e(rng, dim.shape, read_sigma_e) if read_sigma_e else dim
    return noisy


def standard_normal_f32(rng: np.random.Generator, shape: tuple[int, ...], out: np.ndarray | None = None) -> np.ndarray:
    """Standard normal float32 samples, seeded from ``rng`` (one 31-bit draw): OpenCV's ``randn``'s.

    ``cv2.setRNGSeed`` with the drawn seed then ``cv2.randn``, or the same samples bit for bit from its
    numba reproduction (:mod:`simulator.detector.opencv_normal`, ~20 % faster) where it has been checked
    against OpenCV in this process for this shape. 4x faster than numpy's float32 ziggurat. Deterministic
    for a given ``rng`` state, independent of OpenCV's thread count (checked by the tests); its generator
    is a 64-bit multiply-with-carry, ample for detector noise.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream the seed is drawn from.
    shape : tuple of int
        Shape of the samples.
    out : ndarray, float32, C-contiguous, shape ``shape``, optional
        Where to write them (else a new array).

    Returns
    -------
    ndarray, float32, shape ``shape``
        Samples of N(0, 1).
    """
    return opencv_normal.seeded_standard_normal_f32(int(rng.integers(1, 2**31 - 1)), shape, out=out)


def read_noise_e(rng: np.random.Generator, shape: tuple[int, ...], sigma_e: float) -> np.ndarray:
    """Gaussian read noise of the output amplifier.

    Parameters
    ----------
    rng : numpy.random.Generator
        Noise stream.
    shape : tuple of int
        Shape of the image.
    sigma_e : float
        Noise (e- rms).

    Returns
    -------
    ndarray, float64, shape ``shape``
        Noise (e-).
    """
    return sigma_e * rng.standard_normal(shape)


def expected_dn(mean_e: np.ndarray, electronics: Electronics) -> np.ndarray:
    """Noise-free DN: charge clipped at the binned full well, gain, offset, clipped to the ADC range.

    Parameters
    ----------
    mean_e : ndarray
        Expected charge per binned pixel (e-).
    electronics : Electronics
        Full well, gain (e-/DN), offset (DN), bits.

    Returns
    -------
    ndarray, float32, shape of ``mean_e``
        Expected DN, before rounding.
    """
    charge = np.minimum(mean_e, electronics.binned_full_well_e)
    dn = charge / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn
    return np.clip(dn, 0.0, electronics.max_dn).astype(np.float32)


def digitize(charge_e: np.ndarray, electronics: Electronics) -> np.ndarray:
    """ADC: charge with noise -> DN, clipped to ``0 .. 2**bits - 1`` (never wraps).

    Parameters
    ----------
    charge_e : ndarray
        Charge per binned pixel (e-).
    electronics : Electronics
        Full well, gain (e-/DN), offset (DN), bits.

    Returns
    -------
    ndarray, uint16, shape of ``charge_e``
        DN.
    """
    charge = np.minimum(charge_e, electronics.binned_full_well_e)
    dn = np.rint(charge / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn)
    return np.clip(dn, 0.0, electronics.max_dn).astype(np.uint16)


def read_out_dn(rng: np.random.Generator, mean_e: np.ndarray, electronics: Electronics, shot_noise: bool = True,
                read_noise: bool = True, exact_poisson: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The read-out image and its expected DN: :func:`noisy_charge_e`, :func:`digitize` and :func:`expected_dn`.

    The default (Gaussian shot noise, :func:`noisy_charge_e` with ``exact_poisson=False``) runs fused in
    float32 on the same draws of the stream: the noise, full well, gain, offset, rounding (to nearest,
    ties to even, as :func:`digitize`), the 12-bit clip and the expected DN in one compiled pass (numba;
    the gain and offset as OpenCV's float32 multiply-add, which it replaces), the dim pixels' exact
    Poisson draws after it. Other settings call the three functions. The DN differ from the float64 path only where float32
    rounding moves a value across a half-DN boundary.

    Parameters
    ----------
    rng : numpy.random.Generator
        Noise stream (shot noise first, then read noise).
    mean_e : ndarray, shape (binned rows, width)
        Expected charge per binned pixel (e-); negative values count as 0.
    electronics : Electronics
        Read noise, full well, gain (e-/DN), offset (DN), bits.
    shot_noise, read_noise, exact_poisson : bool
        As :func:`noisy_charge_e`.

    Returns
    -------
    (dn, expected_dn) : ndarray uint16 and ndarray float32, shape of ``mean_e``
        The image (DN) and the noise-free DN before rounding.
    """
    read_sigma = electronics.read_noise_e if read_noise and electronics.read_noise_e > 0 else 0.0
    if not shot_noise or exact_poisson:
        noisy = noisy_charge_e(rng, mean_e, electronics.read_noise_e, shot_noise, read_noise, exact_poisson)
        return digitize(noisy, electronics), expected_dn(mean_e, electronics)
    mean_f32 = np.ascontiguousarray(mean_e, dtype=np.float32)
    noisy = standard_normal_f32(rng, mean_f32.shape, out=scratch("readout_noisy", mean_f32.shape))  # -> charge (e-)
    dn = np.empty(mean_f32.shape, dtype=np.uint16)
    expected = np.empty(mean_f32.shape, dtype=np.float32)
    gain, offset, full_well, max_dn = _adc_constants(electronics)
    low_count = _gaussian_read_out_kernel(mean_f32, noisy, np.float32(read_sigma ** 2), np.float32(GAUSSIAN_MIN_MEAN_E),
                                          full_well, gain, offset, max_dn, _expected_dn_top(electronics), dn, expected)
    if low_count:
        mean = np.maximum(mean_f32, np.float32(0.0))
        low = mean < np.float32(GAUSSIAN_MIN_MEAN_E)
        dim = shot_noise_e(rng, mean[low].astype(np.float64))
        noisy[low] = dim + read_noise_e(rng, dim.shape, read_sigma) if read_sigma else dim
        dn[low] = _dn_of_charge(noisy[low], electronics)
    return dn, expected


def _adc_constants(electronics: Electronics) -> tuple[float, float, np.float32, int]:
    """The ADC's constants as the fused read-out uses them.

    (1 / gain, offset) as float32 values in float64 (what OpenCV's float32 multiply-add uses), the binned
    full well (float32, e-) and the largest DN.
    """
    return (float(np.float32(1.0 / electronics.adc_gain_e_per_dn)), float(np.float32(electronics.adc_offset_dn)),
            np.float32(electronics.binned_full_well_e), int(electronics.max_dn))


def _expected_dn_top(electronics: Electronics) -> np.float32:
    """The expected DN's ceiling: the full well's DN, ``full_well / gain + offset``, or the ADC top if lower."""
    return np.float32(min(electronics.binned_full_well_e / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn,
                          float(electronics.max_dn)))


@njit(cache=True, nogil=True, boundscheck=False)
def _dn_value(charge, gain, offset):
    """``charge / gain + offset`` as OpenCV's float32 ``addWeighted`` gives it.

    One fused multiply-add of float32 values, rounded once to float32 (the float64 product of two float32
    is exact).
    """
    return np.float32(np.float64(charge) * gain + offset)


@njit(cache=True, nogil=True, boundscheck=False)
def _gaussian_read_out_kernel(mean_e, noisy, read_variance, gaussian_min, full_well, gain, offset, max_dn, top,
                              dn, expected):
    """The default read-out in one pass; returns how many pixels have a mean below ``gaussian_min``.

    ``noisy`` (standard normal draws on entry) becomes ``mean + sqrt(mean + read variance) x draw`` (mean
    clipped at 0, float32 as the numpy form), then full well, gain, offset, rounding to nearest even, the
    ADC range; the expected DN alongside. The pixels below ``gaussian_min`` are the caller's to redraw
    (exact Poisson).
    """
    rows, width = mean_e.shape
    low = 0
    zero = np.float32(0.0)
    for row in range(rows):
        means, draws, counts, expectation = mean_e[row], noisy[row], dn[row], expected[row]
        for col in range(width):
            mean = max(means[col], zero)
            if mean < gaussian_min:
                low += 1
            charge = draws[col] * np.sqrt(mean + read_variance) + mean
            draws[col] = charge
            value = np.rint(_dn_value(min(charge, full_well), gain, offset))
            counts[col] = np.uint16(min(max(value, zero), np.float32(max_dn)))
            level = _dn_value(means[col], gain, offset)
            expectation[col] = min(max(level, zero), top)
    return low


def _dn_of_charge(charge_e: np.ndarray, electronics: Electronics) -> np.ndarray:
    """:func:`digitize` of a float32 charge, in place on it.

    Full well, then gain, offset and rounding to uint16 in one pass (``cv2.addWeighted`` rounds to
    nearest even and saturates at 0), then the ADC top.
    """
    np.minimum(charge_e, np.float32(electronics.binned_full_well_e), out=charge_e)
    dn = cv2.addWeighted(charge_e, 1.0 / electronics.adc_gain_e_per_dn, charge_e, 0.0, electronics.adc_offset_dn,
                         dtype=cv2.CV_16U)
    return np.minimum(dn, np.uint16(electronics.max_dn), out=dn)
