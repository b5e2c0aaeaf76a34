"""Optics point-spread function (PSF): the lens's blur, applied to the radiance fields as an MTF.

Model (camera ``[optics]``, :class:`flight_interface.camera_file.Optics`)
-------------------------------------------------------------------
The optical transfer function at spatial frequency ``f`` (cycles/m in the focal plane) is::

    OTF(f) = sum_i w_i  D(f lambda_i N)  A_i(f lambda_i N)  x  exp(-2 pi^2 sigma^2 f^2)

* ``D(v) = 2/pi (acos v - v sqrt(1 - v^2))`` for ``v < 1``, else 0: the diffraction MTF of an
  unobstructed circular aperture of focal ratio ``N`` (cut-off ``1 / (lambda N)``), whose PSF is the
  Airy pattern ``[2 J1(x) / x]^2``, ``x = pi r / (lambda N)`` (first dark ring at ``1.22 lambda N``);
* ``w_i``: the band weight of wavelength ``lambda_i``, optics transmission x quantum efficiency (the
  electrons per wavelength of a photon spectrum flat over the band), on a 5 nm grid (trapezoid rule);
* ``A(v) = 1 - (W / 0.18)^2 (1 - 4 (v - 0.5)^2)``: the aberration transfer factor of a random rms
  wavefront error ``W`` (waves at ``lambda_i``; Shannon, *The Art and Science of Optical Design*, 1997),
  valid for ``W <= 0.18`` waves;
* ``sigma``: a Gaussian blur (defocus, residual aberrations), um in the focal plane.

It is real and >= 0 (the PSF is symmetric), 1 at ``f = 0`` (energy is conserved).

Where it is applied
-------------------
The scene stage already integrates each pixel over its area (the pixel-area filter, or s x s
supersampling), so a radiance field is the scene convolved with the pixel box and sampled at the pixel
centres: the pixel aperture's MTF ``|sinc(f p)|`` is in it. Convolution commutes, so the optics' blur
is the remaining factor: each field is multiplied by ``OTF`` in the frequency domain at the resolution
it is sampled (12 um columns; 12 um rows, or ``b`` x 12 um rows for a field given per binning block),
which is exact for the field's band-limited content. The frame is mirrored 16 px beyond its edges
(what lies outside the view is unknown; a mirror keeps the local statistics) and padded on to the next
11-smooth DFT length; the product is taken on OpenCV's packed real spectrum (``cv2.dft``; the
real OTF multiplies it elementwise), single precision. The few slightly negative values the band-limited filter leaves
next to a sky edge are set to 0.

Smear fields
------------
A flush or transfer field reaches the charge only through column sums: the charge of row ``r`` gets
``T/N`` times the sum of the column's rates over the rows the packet crosses
(simulator.detector.charge_transfer). Blurring the field along a column moves light between rows of
the same column, which leaves such a sum unchanged except for the light within the PSF's reach of
where the sum starts or stops: of order ``w / N`` of the smear (``w`` ~ 1 px, ``N`` = 1024 rows).
Across columns the blur is the line-spread function, whose transfer function is the OTF's section
``OTF(f_x, 0)``. So a smear field that is not the exposure field itself is filtered along its rows
only (a 1-D DFT per row, :func:`blur_field_along_rows`): a sixth of the 2-D cost, the same charge to
``w / N`` (test: against the 2-D blur in the camera chain).
:func:`system_mtf` (optics x pixel) is what ``campaign camera`` prints.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from flight_interface.camera import Camera
from flight_interface.camera_file import MAX_WAVEFRONT_ERROR_WAVES
from simulator.derived_cache import DERIVED
from simulator.detector import float_bits
from simulator.detector.charge_transfer import add_row_to_block
from simulator.fields import RadianceFields
from simulator.scratch import scratch

#: Mirrored margin beyond the frame edges (px along a row; rows scale with the field's row pitch).
PAD_PX = 16
#: Samples of the tabulated radial OTF (linear interpolation error below 1e-6).
RADIAL_SAMPLES = 8192


def diffraction_mtf(normalized_frequency: np.ndarray) -> np.ndarray:
    """Diffraction MTF of a circular aperture.

    Parameters
    ----------
    normalized_frequency : ndarray
        ``v = f lambda N``, any shape.

    Returns
    -------
    ndarray, shape of ``normalized_frequency``
        ``D(v)`` (module doc); 0 for ``v >= 1``.
    """
    v = np.clip(np.abs(np.asarray(normalized_frequency, dtype=float)), 0.0, 1.0)
    return 2.0 / np.pi * (np.arccos(v) - v * np.sqrt(1.0 - v * v))


def pixel_mtf(frequency_cyc_per_m: np.ndarray, pitch_m: float) -> np.ndarray:
    """MTF of a pixel aperture along one axis, ``|sinc(f p)|``.

    Parameters
    ----------
    frequency_cyc_per_m : ndarray
        Focal-plane frequency (cycles/m), any shape.
    pitch_m : float
        Pixel width ``p`` (m).

    Returns
    -------
    ndarray, shape of ``frequency_cyc_per_m``
        The MTF.
    """
    return np.abs(np.sinc(np.asarray(frequency_cyc_per_m, dtype=float) * pitch_m))


def optics_mtf(frequency_cyc_per_m: np.ndarray, camera: Camera) -> np.ndarray:
    """The optics' OTF (module doc) at radial focal-plane frequencies.

    Parameters
    ----------
    frequency_cyc_per_m : ndarray
        Radial focal-plane frequency (cycles/m), any shape.
    camera : Camera
        The camera (its ``[optics]``, band and focal ratio).

    Returns
    -------
    ndarray, float64, shape of ``frequency_cyc_per_m``
        The OTF (real, 1 at f = 0).
    """
    optics, radiometry = camera.optics, camera.radiometry
    wavelengths_m, weights = optics.band_weights(radiometry.band_min_um, radiometry.band_max_um)
    frequency = np.abs(np.asarray(frequency_cyc_per_m, dtype=float))
    total = np.zeros(frequency.shape)
    wavefront_m = optics.wavefront_error_rms_um * 1e-6
    for wavelength_m, weight in zip(wavelengths_m, weights):
        if weight == 0.0:
            continue
        v = frequency * wavelength_m * radiometry.f_number
        term = diffraction_mtf(v)
        if wavefront_m > 0.0:
            waves = wavefront_m / wavelength_m
            term = term * (1.0 - (waves / MAX_WAVEFRONT_ERROR_WAVES) ** 2 * (1.0 - 4.0 * (np.minimum(v, 1.0) - 0.5) ** 2))
        total += weight * term
    sigma_m = optics.blur_sigma_um * 1e-6
    if sigma_m > 0.0:
        total *= np.exp(-2.0 * np.pi**2 * sigma_m**2 * frequency**2)
    return total


def system_mtf(frequency_cyc_per_m: np.ndarray, camera: Camera) -> np.ndarray:
    """Optics x pixel aperture MTF along a row.

    Parameters
    ----------
    frequency_cyc_per_m : ndarray
        Radial focal-plane frequency (cycles/m), any shape.
    camera : Camera
        The camera (its ``[optics]``, band and focal ratio).

    Returns
    -------
    ndarray, shape of ``frequency_cyc_per_m``
        The MTF.
    """
    return optics_mtf(frequency_cyc_per_m, camera) * pixel_mtf(frequency_cyc_per_m, camera.pixel_pitch_m)


def cutoff_frequency_cyc_per_m(camera: Camera) -> float:
    """Highest frequency the optics pass, ``1 / (lambda_min N)``.

    Parameters
    ----------
    camera : Camera
        The camera (band, focal ratio).

    Returns
    -------
    float
        Cut-off (cycles/m).
    """
    return 1.0 / (camera.radiometry.band_min_um * 1e-6 * camera.radiometry.f_number)


def _radial_otf(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The OTF on 20001 radial frequencies from 0 to the cut-off (cycles/m), for the Hankel integrals (cached)."""
    cache = DERIVED.of(camera, "psf")
    if "radial" not in cache:
        rho = np.linspace(0.0, cutoff_frequency_cyc_per_m(camera), 20001)
        cache["radial"] = (rho, optics_mtf(rho, camera))
    return cache["radial"]


def encircled_energy(radius_m: np.ndarray, camera: Camera) -> np.ndarray:
    """Fraction of a point's energy inside a radius, for the optics PSF (no pixel).

    ``EE(r) = 2 pi r int_0^fc OTF(rho) J1(2 pi r rho) d rho`` (a circularly symmetric OTF).

    Parameters
    ----------
    radius_m : ndarray
        Radius in the focal plane (m), any shape.
    camera : Camera
        The camera.

    Returns
    -------
    ndarray, shape of ``radius_m``
        Encircled energy fraction, 0 .. 1.
    """
    import scipy.special

    rho, otf = _radial_otf(camera)
    radius = np.atleast_1d(np.asarray(radius_m, dtype=float))
    integrand = otf[None, :] * scipy.special.j1(2.0 * np.pi * radius[:, None] * rho[None, :])
    energy = 2.0 * np.pi * radius * np.trapezoid(integrand, rho, axis=1)
    return energy.reshape(np.shape(radius_m))


def psf_radial(radius_m: np.ndarray, camera: Camera) -> np.ndarray:
    """Optics PSF at a radius: ``PSF(r) = 2 pi int_0^fc OTF(rho) J0(2 pi r rho) rho d rho``.

    Parameters
    ----------
    radius_m : ndarray
        Radius in the focal plane (m), any shape.
    camera : Camera
        The camera.

    Returns
    -------
    ndarray, shape of ``radius_m``
        Fraction of a point's energy per m^2.
    """
    import scipy.special

    rho, otf = _radial_otf(camera)
    radius = np.atleast_1d(np.asarray(radius_m, dtype=float))
    integrand = otf[None, :] * scipy.special.j0(2.0 * np.pi * radius[:, None] * rho[None, :]) * rho[None, :]
    return (2.0 * np.pi * np.trapezoid(integrand, rho, axis=1)).reshape(np.shape(radius_m))


def encircled_energy_radius_m(camera: Camera, fraction: float = 0.8) -> float:
    """Radius holding a fraction of a point's energy (optics PSF, no pixel).

    Parameters
    ----------
    camera : Camera
        The camera.
    fraction : float, optional
        Energy fraction, 0 < fraction < 1.

    Returns
    -------
    float
        Radius in the focal plane (m).
    """
    import scipy.optimize

    scale = camera.radiometry.band_max_um * 1e-6 * camera.radiometry.f_number + 4.0 * camera.optics.blur_sigma_um * 1e-6
    radii = np.linspace(0.0, 8.0 * scale, 401)[1:]
    energy = encircled_energy(radii, camera)
    above = int(np.argmax(energy >= fraction))
    if energy[above] < fraction:
        raise ValueError(f"{camera.source}: less than {fraction:.0%} of the PSF's energy within "
                         f"{radii[-1] * 1e6:.0f} um")
    low = radii[above - 1] if above else 0.0
    return float(scipy.optimize.brentq(lambda r: float(encircled_energy(r, camera)) - fraction, low, radii[above]))


def _padded_shape(rows: int, cols: int, pad_rows: int) -> tuple[int, int]:
    """The DFT size of a field with its mirrored margins: the next 11-smooth length.

    1056 for 1024 + 2 x 16: OpenCV transforms it faster than the 5-smooth 1080, measured 13 vs 15.5 ms for the pair).
    """
    import scipy.fft

    return scipy.fft.next_fast_len(rows + 2 * pad_rows), scipy.fft.next_fast_len(cols + 2 * PAD_PX)


def _otf_grid(camera: Camera, shape: tuple[int, int], row_pitch_m: float) -> np.ndarray:
    """The OTF on the rfft2 grid of a padded field of ``shape``, float64 (rows, cols // 2 + 1), cached."""
    import scipy.fft

    cache = DERIVED.of(camera, "psf")
    key = ("rfft2", shape, row_pitch_m)
    if key not in cache:
        radial = np.linspace(0.0, cutoff_frequency_cyc_per_m(camera), RADIAL_SAMPLES)
        table = optics_mtf(radial, camera)
        fy = scipy.fft.fftfreq(shape[0], d=row_pitch_m)
        fx = scipy.fft.rfftfreq(shape[1], d=camera.pixel_pitch_m)
        frequency = np.hypot(fy[:, None], fx[None, :])
        otf = np.interp(frequency, radial, table, right=0.0)
        otf[0, 0] = 1.0                       # energy conserved exactly
        otf.setflags(write=False)
        cache[key] = otf
    return cache[key]


def _otf_packed(camera: Camera, shape: tuple[int, int], row_pitch_m: float, scale: float = 1.0) -> np.ndarray:
    """The OTF laid out as OpenCV's packed (CCS) real spectrum of ``shape``: float32, cached.

    The OTF is real and even, so it multiplies a frequency's real and imaginary parts alike: each entry
    of the packed layout (real parts, imaginary parts, and the vertically packed first column and, for
    an even width, last column) gets its frequency's OTF, and the product is one elementwise multiply.
    The values are taken from the forward DFT of the OTF's own periodic kernel (the inverse real DFT of
    :func:`_otf_grid`), so OpenCV's packing is its own whatever the parity of the sizes; there the
    imaginary entries are ~0 and take the real entry of their frequency. ``scale`` multiplies it (a power of
    two, e.g. ``1 / b``, scales every product exactly).
    """
    import scipy.fft

    cache = DERIVED.of(camera, "psf")
    key = ("ccs", shape, row_pitch_m, scale)
    if key not in cache and scale != 1.0:
        scaled = _otf_packed(camera, shape, row_pitch_m) * np.float32(scale)
        scaled.setflags(write=False)
        cache[key] = scaled
    if key not in cache:
        kernel = scipy.fft.irfft2(_otf_grid(camera, shape, row_pitch_m), s=shape)
        spectrum = cv2.dft(kernel.astype(np.float32))
        packed = spectrum.copy()
        rows, cols = shape
        last_col = cols - 1 if cols % 2 == 0 else cols      # an even width ends with a packed Nyquist column
        packed[:, 2:last_col:2] = spectrum[:, 1:last_col - 1:2]           # (Re, Im) pairs along each row
        last_row = rows - 1 if rows % 2 == 0 else rows
        for col in ([0, cols - 1] if cols % 2 == 0 else [0]):             # (Re, Im) pairs down these columns
            packed[2:last_row:2, col] = spectrum[1:last_row - 1:2, col]
        packed.setflags(write=False)
        cache[key] = packed
    return cache[key]


def _row_otf_packed(camera: Camera, cols: int) -> np.ndarray:
    """The OTF along a row, ``OTF(f_x, 0)``, as OpenCV's packed spectrum of one real row.

    ``cols`` samples (Re0, Re1, Im1, Re2, Im2, ..., and Re of the Nyquist term for even ``cols``):
    real and symmetric, it multiplies a frequency's real and imaginary parts alike. float32 (cols,), cached.
    """
    import scipy.fft

    cache = DERIVED.of(camera, "psf")
    key = ("row", cols)
    if key not in cache:
        otf = optics_mtf(scipy.fft.rfftfreq(cols, d=camera.pixel_pitch_m), camera)
        otf[0] = 1.0
        packed = np.empty(cols, dtype=np.float32)
        packed[0] = otf[0]
        pairs = (cols - 1) // 2
        packed[1:2 * pairs + 1] = np.repeat(otf[1:pairs + 1], 2)
        if cols % 2 == 0:
            packed[-1] = otf[cols // 2]
        packed.setflags(write=False)
        cache[key] = packed
    return cache[key]


def kernel_abs_sum(camera: Camera) -> float:
    """Sum of the absolute values of the optics' kernel on the padded full-frame grid (cached).

    A bound on how much the blur can raise a field's maximum: ``max B <= max F x kernel_abs_sum``
    for a field ``F >= 0`` (1 plus twice the small negative lobes the band-limited OTF leaves).

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    float
        ``sum |k|`` (>= 1).
    """
    import scipy.fft

    cache = DERIVED.of(camera, "psf")
    if "kernel_abs_sum" not in cache:
        shape = _padded_shape(camera.height_px, camera.width_px, PAD_PX)
        kernel = scipy.fft.irfft2(_otf_grid(camera, shape, camera.pixel_pitch_m), s=shape)
        cache["kernel_abs_sum"] = float(np.abs(kernel).sum())
    return cache["kernel_abs_sum"]


def _fold_packed_rows(spectrum: np.ndarray, factor: int, otf: np.ndarray | None = None) -> np.ndarray:
    """Fold a packed (CCS) spectrum of ``(H, W)`` to the spectrum of its every ``factor``-th row, ``(H / factor, W)``.

    Sampling every ``factor``-th row of a signal sums its spectrum's ``factor`` row bands
    (``X_d(u) = sum_q X(u + q H / factor)``; the inverse DFT of ``H / factor`` rows then scales by
    ``factor`` too much). The columns that hold complex (Re, Im) pairs are summed as they are; the first
    and last column hold a real column's packed vertical spectrum, unpacked to complex (float64), folded
    and packed again. H, W and H / factor even. With ``otf`` (packed, :func:`_otf_packed`: one value per
    (Re, Im) pair) the spectrum is multiplied by it on the way (each product rounded to float32), in the
    same pass (numba). The result is this thread's scratch array (:func:`simulator.scratch.scratch`):
    valid until the next fold.
    """
    rows, cols = spectrum.shape
    if rows % (2 * factor) or cols % 2:
        raise ValueError(f"fold: a ({rows}, {cols}) spectrum does not fold to every {factor}-th row")
    pairs, edges = _otf_fold_parts(np.ones(spectrum.shape, dtype=np.float32) if otf is None else otf)
    folded = scratch("psf_folded", (rows // factor, cols))        # dies in the inverse transform
    _fold_kernel(np.ascontiguousarray(spectrum, dtype=np.float32), pairs, edges, factor, folded)
    return folded


def _otf_fold_parts(otf_packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A packed OTF as the fold reads it: one value per (Re, Im) pair, and the first and last columns.

    Shapes (rows, W / 2 - 1) and (rows, 2). The pair's two entries are equal (:func:`_otf_packed`), so this
    is the same OTF in half the memory; cached on a cached OTF (read-only).
    """
    if otf_packed.flags.writeable:
        return _fold_parts(otf_packed)
    cache = DERIVED.of(otf_packed, "psf")
    if "fold_parts" not in cache:
        cache["fold_parts"] = _fold_parts(otf_packed)
    return cache["fold_parts"]


def _fold_parts(otf_packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pairs = np.ascontiguousarray(otf_packed[:, 1:-1:2], dtype=np.float32)
    if not np.array_equal(pairs, otf_packed[:, 2:-1:2]):
        raise ValueError("fold: the OTF's (Re, Im) entries of a frequency differ")
    return pairs, np.ascontiguousarray(otf_packed[:, [0, -1]], dtype=np.float32)


@njit(cache=True, nogil=True, boundscheck=False)
def _fold_kernel(spectrum, otf_pairs, otf_edges, factor, folded):
    """:func:`_fold_packed_rows`: band sums ``((b0 + b1) + b2) + ...`` of the OTF-multiplied spectrum."""
    rows, cols = spectrum.shape
    short = rows // factor
    pairs = otf_pairs.shape[1]
    for row in range(short):
        out = folded[row]
        for band in range(factor):
            values = spectrum[band * short + row]
            weights = otf_pairs[band * short + row]
            if band == 0:
                for pair in range(pairs):
                    weight = weights[pair]
                    out[2 * pair + 1] = values[2 * pair + 1] * weight
                    out[2 * pair + 2] = values[2 * pair + 2] * weight
            else:
                for pair in range(pairs):
                    weight = weights[pair]
                    out[2 * pair + 1] += values[2 * pair + 1] * weight
                    out[2 * pair + 2] += values[2 * pair + 2] * weight
    half = short // 2
    for edge in range(2):
        col = 0 if edge == 0 else cols - 1
        for folded_row in range(half + 1):
            real = 0.0
            imag = 0.0
            for band in range(factor):
                frequency = folded_row + band * short
                conjugate = frequency > rows // 2
                if conjugate:
                    frequency = rows - frequency
                if frequency == 0:
                    re_index, im_index = 0, -1
                elif frequency == rows // 2:
                    re_index, im_index = rows - 1, -1
                else:
                    re_index, im_index = 2 * frequency - 1, 2 * frequency
                part_re = spectrum[re_index, col] * otf_edges[re_index, edge]
                part_im = np.float32(0.0)
                if im_index >= 0:
                    part_im = spectrum[im_index, col] * otf_edges[im_index, edge]
                    if conjugate:
                        part_im = -part_im
                if band == 0:
                    real = np.float64(part_re)
                    imag = np.float64(part_im)
                else:
                    real += np.float64(part_re)
                    imag += np.float64(part_im)
            if folded_row == 0:
                folded[0, col] = real
            elif folded_row == half:
                folded[short - 1, col] = real
            else:
                folded[2 * folded_row - 1, col] = real
                folded[2 * folded_row, col] = imag


@njit(cache=True, nogil=True, boundscheck=False)
def _mirrored_running_sums(field, pad_px, binning_rows, padded, block_sums, gain, with_rate, rate_plain, rate_ramp,
                           plain_offset, ramp_offset, bit_states, smear_count, first_smear, second_smear, smear_plain,
                           smear_ramp, smear_sums):
    """The padded, mirrored field's circular ``binning_rows``-row running sums, and the frame's block sums.

    ``padded[r] = sum_{j < b} E[(r + j) mod R]`` where ``E`` is the field mirrored (``f e d | d e f``,
    OpenCV's BORDER_REFLECT) ``pad_px`` beyond its first row and column and on to the padded shape
    ``(R, C)``; pairs for ``b = 4`` (``(E0 + E1) + (E2 + E3)``), else in order. ``block_sums[k]`` is the
    sum of the frame's rows ``k b .. k b + b - 1`` (the running sum at padded row ``pad_px + k b``).
    With ``with_rate``, the block sums of the rate ``field x gain`` (+ the offsets), plain and
    ramp-weighted, charge moving toward the last row, and the field's extremes (its bit-pattern state,
    :mod:`simulator.detector.float_bits`, in ``bit_states[0]``), as
    :func:`simulator.detector.charge_transfer.checked_block_rate_sums`; so for ``smear_count`` (0 .. 2)
    other fields (``first_smear``, ``second_smear``: their rate sums, block sums and states into
    ``smear_plain[i]``, ``smear_ramp[i]``, ``smear_sums[i]``, ``bit_states[i + 1]``). The rate sums come first,
    a field at a time (:func:`_field_rate_sums`: simple loops along each row, which the compiler vectorises;
    one pass over all the fields sharing each gain row ran 1.6x slower), so that the padded field, written
    last, is still in cache for the transform that reads it next.
    """
    rows, cols = field.shape
    padded_rows, padded_cols = padded.shape
    right = padded_cols - pad_px - cols
    sources = np.empty(binning_rows, dtype=np.int64)
    if with_rate:
        _field_rate_sums(field, gain, binning_rows, rate_plain, rate_ramp, rate_plain, False, bit_states[0],
                         plain_offset, ramp_offset)
        for index in range(smear_count):
            _field_rate_sums(first_smear if index == 0 else second_smear, gain, binning_rows, smear_plain[index],
                             smear_ramp[index], smear_sums[index], True, bit_states[index + 1], plain_offset, ramp_offset)
    for padded_row in range(padded_rows):
        for offset in range(binning_rows):
            source = (padded_row + offset) % padded_rows - pad_px
            if source < 0:
                source = -source - 1
            elif source >= rows:
                source = 2 * rows - source - 1
            sources[offset] = source
        out = padded[padded_row, pad_px:pad_px + cols]
        first = field[sources[0]]
        if binning_rows == 4:
            second, third, fourth = field[sources[1]], field[sources[2]], field[sources[3]]
            for col in range(cols):
                out[col] = (first[col] + second[col]) + (third[col] + fourth[col])
        else:
            for col in range(cols):
                out[col] = first[col]
            for offset in range(1, binning_rows):
                values = field[sources[offset]]
                for col in range(cols):
                    out[col] += values[col]
        left_margin = padded[padded_row, :pad_px]
        for col in range(pad_px):
            left_margin[col] = out[pad_px - 1 - col]
        right_margin = padded[padded_row, pad_px + cols:]
        for col in range(right):
            right_margin[col] = out[cols - 1 - col]
        frame_row = padded_row - pad_px
        if 0 <= frame_row < rows and frame_row % binning_rows == 0:
            sums = block_sums[frame_row // binning_rows]
            for col in range(cols):
                sums[col] = out[col]


@njit(cache=True, nogil=True, boundscheck=False)
def _field_rate_sums(field, gain, binning_rows, plain, ramp, field_sums, with_field, bit_state, plain_offset,
                     ramp_offset):
    """One field's rate sums for :func:`_mirrored_running_sums` (and its block sums with ``with_field``).

    Per frame row: the rate ``field x gain`` into its block's plain and ramp-weighted sums, the row's bit
    patterns into the field's extremes (:func:`simulator.detector.float_bits.add_row`); after a block's
    last row the offsets (when not 0).
    """
    rows, cols = field.shape
    for frame_row in range(rows):
        block, offset = frame_row // binning_rows, frame_row % binning_rows
        values, block_plain, block_ramp = field[frame_row], plain[block], ramp[block]
        add_row_to_block(values, gain[frame_row], offset == 0, block_plain, block_ramp, with_field,
                         field_sums[block if with_field else 0])
        float_bits.add_row(values, bit_state)
        if offset == binning_rows - 1 and plain_offset != 0.0:
            for col in range(cols):
                block_plain[col] += plain_offset
                block_ramp[col] += ramp_offset


def binned_blur_sums(field_w_m2_sr_um: np.ndarray, camera: Camera, binning_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Block sums of ``binning_rows`` rows of a full-frame field seen through the optics, exact, and of the field.

    ``Y(k, c) = sum_{j < b} B(k b + j, c)`` with ``B`` = :func:`blur_field` before its clip at 0. The
    blur and the block sum commute: the padded field's ``b``-row running sum (circular, as the DFT sees
    it) is transformed, multiplied by the OTF (:func:`_otf_packed`, as :func:`blur_field`), folded to
    every ``b``-th row (:func:`_fold_packed_rows`: sampling in space is folding in frequency) and
    transformed back at ``1 / b`` of the rows. Exact to float32 rounding; the inverse DFT costs a
    quarter of :func:`blur_field`'s and no full-resolution blurred field is made. Sums below 0
    (ringing next to a sky edge) are set to 0. The padding with the running sum, and the OTF product
    with the fold, are each one compiled pass (numba) around OpenCV's two transforms
    (:func:`binned_blur_rate_sums`).

    Parameters
    ----------
    field_w_m2_sr_um : ndarray, shape (height, width), float32, finite, >= 0
        Radiance (W m^-2 sr^-1 um^-1), full frame (the caller checks it:
        :func:`simulator.detector.charge_transfer.checked_block_rate_sums`).
    camera : Camera
        The camera.
    binning_rows : int
        Rows per block ``b``; divides the height, the padded height (an even number of times) and the
        row margin.

    Returns
    -------
    (blurred, plain) : two ndarrays, float32, shape (height / b, width)
        Block sums of the blurred field and of the field itself (W m^-2 sr^-1 um^-1 summed over ``b`` rows).
    """
    sums = binned_blur_rate_sums(field_w_m2_sr_um, camera, binning_rows)
    return np.maximum(sums.blurred, np.float32(0.0)), sums.plain


@dataclass(frozen=True)
class BinnedBlurSums:
    """What :func:`binned_blur_rate_sums` gives.

    Attributes
    ----------
    blurred : ndarray, float32, shape (height / b, width)
        Block sums of the blurred field before the clip at 0 (a view into the inverse transform's output).
    plain : ndarray, float32, shape (height / b, width)
        Block sums of the field itself.
    rate_plain, rate_ramp : ndarray, float32, shape (height / b, width), or None
        With a gain: the block sums of the rate ``field x gain + offset``, plain and ramp-weighted, as
        :func:`simulator.detector.charge_transfer.block_rate_sums` (charge moving toward the last row).
    smallest, largest : float
        With a gain: the field's minimum and maximum, both NaN when a value is not finite (else NaN).
    smear : tuple of (plain, ramp, radiance sums, smallest, largest)
        Per other field given (a smear period's): its rate sums, block sums and extremes, as
        :func:`simulator.detector.charge_transfer.checked_block_rate_sums`.
    """

    blurred: np.ndarray
    plain: np.ndarray
    rate_plain: np.ndarray | None = None
    rate_ramp: np.ndarray | None = None
    smallest: float = float("nan")
    largest: float = float("nan")
    smear: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, float, float], ...] = ()


def binned_blur_rate_sums(field_w_m2_sr_um: np.ndarray, camera: Camera, binning_rows: int,
                          gain: np.ndarray | None = None, offset_e_per_s: float = 0.0,
                          smear_fields: tuple[np.ndarray, ...] = (), reuse: bool = False) -> BinnedBlurSums:
    """:func:`binned_blur_sums`' transform, before the clip, and with a gain the rate's block sums from the same pass.

    The frame is read once: each padded row's running sum (:func:`_mirrored_running_sums`), and with
    ``gain`` the rate sums and extremes of the frame rows it reads. The OTF is applied with the fold,
    scaled by ``1 / b`` (a power of two for ``b`` = 4: the same bits as scaling the result).

    Parameters
    ----------
    field_w_m2_sr_um : ndarray, shape (height, width)
        Radiance (W m^-2 sr^-1 um^-1), full frame.
    camera : Camera
        The camera.
    binning_rows : int
        Rows per block ``b`` (as :func:`binned_blur_sums`).
    gain : ndarray, shape (height, width), optional
        Rate per unit radiance of every pixel (e-/s per W m^-2 sr^-1 um^-1).
    offset_e_per_s : float, optional
        A rate added to every pixel (dark current, e-/s), with ``gain``.
    smear_fields : tuple of up to two ndarrays, shape (height, width), optional
        With ``gain``: other fields (the smear periods') whose rate sums come from the same pass (not blurred).
    reuse : bool, optional
        Give every array in this thread's scratch arrays (:func:`simulator.scratch.scratch`: a fresh 1 MiB
        array costs its page faults, ~0.3 ms here), valid until the next call with ``reuse``; else new
        arrays, except ``blurred``, a view of the fold's scratch array, which the inverse transform overwrites
        in place (valid until the next fold).

    Returns
    -------
    BinnedBlurSums
        The block sums (the blurred ones not clipped at 0).
    """
    field = np.ascontiguousarray(field_w_m2_sr_um, dtype=np.float32)
    rows, cols = field.shape
    padded_shape = _padded_shape(rows, cols, PAD_PX)
    if padded_shape[0] % (2 * binning_rows) or padded_shape[1] % 2 or PAD_PX % binning_rows or rows % binning_rows:
        raise ValueError(f"binned blur: {binning_rows}-row blocks do not tile the padded {padded_shape} grid")
    blocks = rows // binning_rows
    # the full-frame intermediate in this thread's scratch array (a fresh 4 MiB array costs page faults)
    running = scratch("psf_running", padded_shape)              # sum of rows r .. r + b - 1

    def output(name: str, shape: tuple[int, ...]) -> np.ndarray:
        return scratch(name, shape) if reuse else np.empty(shape, dtype=np.float32)

    plain = output("psf_block_sums", (blocks, cols))
    with_rate = gain is not None
    rate_rows = blocks if with_rate else 1
    rate_plain = output("psf_rate_plain", (rate_rows, cols))
    rate_ramp = output("psf_rate_ramp", (rate_rows, cols))
    gains = np.ascontiguousarray(gain, dtype=np.float32) if with_rate else field
    if len(smear_fields) > 2 or (smear_fields and not with_rate):
        raise ValueError("binned blur: up to two smear fields, with a gain")
    smears = [np.ascontiguousarray(smear, dtype=np.float32) for smear in smear_fields]
    for smear in smears:
        if smear.shape != field.shape:
            raise ValueError(f"binned blur: a smear field of shape {smear.shape}; expected {field.shape}")
    smear_rows = (len(smears), blocks, cols) if smears else (1, 1, cols)
    smear_plain, smear_ramp, smear_sums = (output(f"psf_smear_{name}", smear_rows) for name in ("plain", "ramp", "sums"))
    bit_states = float_bits.new_state(3)             # the field's, then the smear fields'
    padding = smears + [field] * (2 - len(smears))
    _mirrored_running_sums(field, PAD_PX, binning_rows, running, plain, gains, with_rate, rate_plain, rate_ramp,
                           np.float32(binning_rows * offset_e_per_s),
                           np.float32(binning_rows * (binning_rows + 1) / 2 * offset_e_per_s), bit_states,
                           len(smears), padding[0], padding[1], smear_plain, smear_ramp, smear_sums)
    spectrum = cv2.dft(running, dst=running)
    folded = _fold_packed_rows(spectrum, binning_rows, _otf_packed(camera, padded_shape, camera.pixel_pitch_m,
                                                                   1.0 / binning_rows))
    sampled = cv2.idft(folded, dst=folded, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)   # in place: same bits, ~0.1 ms less
    first = PAD_PX // binning_rows
    blurred = sampled[first:first + blocks, PAD_PX:PAD_PX + cols]
    if not with_rate:
        return BinnedBlurSums(blurred, plain)
    smear_read = tuple((smear_plain[index], smear_ramp[index], smear_sums[index],
                        *float_bits.extremes(bit_states[index + 1], smears[index])) for index in range(len(smears)))
    return BinnedBlurSums(blurred, plain, rate_plain, rate_ramp, *float_bits.extremes(bit_states[0], field), smear_read)


def _checked(field_w_m2_sr_um: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A field checked for the blur: raises ValueError on a negative finite value.

    Returns (field as float32, the field with non-finite pixels set to 0, mask of those pixels or None).
    """
    field = np.asarray(field_w_m2_sr_um, dtype=np.float32)
    finite = bool(np.isfinite(field.sum()))
    bad = None if finite else ~np.isfinite(field)
    work = field if bad is None else np.where(bad, np.float32(0.0), field)
    if float(work.min()) < 0.0:      # the chain's own check would no longer see it once blurred and clipped
        raise ValueError(f"radiance field has negative values (min {float(work.min()):.4g} "
                         "W m^-2 sr^-1 um^-1); radiance must be >= 0")
    return field, np.ascontiguousarray(work), bad


def _finished(blurred: np.ndarray, field: np.ndarray, bad: np.ndarray | None) -> np.ndarray:
    """Clip the band-limited filter's small negative ringing to 0 and put the non-finite pixels back."""
    out = np.maximum(blurred, np.float32(0.0))
    if bad is not None:
        out[bad] = field[bad]
    return out


def blur_field(field_w_m2_sr_um: np.ndarray, camera: Camera) -> np.ndarray:
    """A radiance field seen through the optics (module doc).

    Parameters
    ----------
    field_w_m2_sr_um : ndarray, shape (height, width) or (height / b, width) per binning block
        Pixel-area-averaged radiance, W m^-2 sr^-1 um^-1.
    camera : Camera

    Returns
    -------
    ndarray, float32, same shape, >= 0 where the field is finite; NaN and inf pixels are kept as they
    are (the chain reads them black / saturated) and take no part in the blur.

    Raises
    ------
    ValueError
        A finite value of the field is negative.
    """
    field, work, bad = _checked(field_w_m2_sr_um)
    rows, cols = field.shape
    row_pitch_m = camera.pixel_pitch_m * camera.height_px / rows
    pad_rows = int(np.ceil(PAD_PX * camera.pixel_pitch_m / row_pitch_m))
    padded_shape = _padded_shape(rows, cols, pad_rows)
    padded = cv2.copyMakeBorder(work, pad_rows, padded_shape[0] - rows - pad_rows,
                                PAD_PX, padded_shape[1] - cols - PAD_PX, cv2.BORDER_REFLECT)   # mirror: f e d | d e f
    spectrum = cv2.dft(padded)
    spectrum *= _otf_packed(camera, padded_shape, row_pitch_m)
    blurred = cv2.idft(spectrum, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    return _finished(blurred[pad_rows:pad_rows + rows, PAD_PX:PAD_PX + cols], field, bad)


def blur_field_along_rows(field_w_m2_sr_um: np.ndarray, camera: Camera) -> np.ndarray:
    """A smear-period radiance field through the optics' line-spread function across columns only.

    ``OTF(f_x, 0)`` along each row; the module doc's "Smear fields" says why this is the PSF's whole
    effect on smear.

    Parameters
    ----------
    field_w_m2_sr_um : ndarray, shape (height, width) or (height / b, width)
        Radiance (W m^-2 sr^-1 um^-1), as :func:`blur_field`.
    camera : Camera
        The camera.

    Returns
    -------
    ndarray, float32, same shape
        The blurred field, as :func:`blur_field`.

    Raises
    ------
    ValueError
        A finite value of the field is negative.
    """
    import scipy.fft

    field, work, bad = _checked(field_w_m2_sr_um)
    cols = field.shape[1]
    padded_cols = scipy.fft.next_fast_len(cols + 2 * PAD_PX)
    padded = cv2.copyMakeBorder(work, 0, 0, PAD_PX, padded_cols - cols - PAD_PX, cv2.BORDER_REFLECT)
    spectrum = cv2.dft(padded, flags=cv2.DFT_ROWS)
    spectrum *= _row_otf_packed(camera, padded_cols)
    blurred = cv2.idft(spectrum, flags=cv2.DFT_ROWS | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    return _finished(blurred[:, PAD_PX:PAD_PX + cols], field, bad)


def row_blurred_block_sums(block_sums: np.ndarray, camera: Camera) -> np.ndarray:
    """:func:`blur_field_along_rows` of a smear field's finite, non-negative block sums, before its clip at 0.

    The binned path's form: the sums come from a field checked on the way (no check here), and the
    clip is the caller's (:func:`simulator.detector.charge_transfer.add_blur_change`).

    Parameters
    ----------
    block_sums : ndarray, shape (height / b, width)
        Block sums of a smear field's radiance (W m^-2 sr^-1 um^-1), finite and >= 0.
    camera : Camera
        The camera.

    Returns
    -------
    ndarray, float32, shape of ``block_sums``
        The sums through the line-spread function, not clipped: a view with strided rows of this thread's
        scratch array, valid until the next call.
    """
    import scipy.fft

    sums = np.asarray(block_sums, dtype=np.float32)
    cols = sums.shape[1]
    padded_cols = scipy.fft.next_fast_len(cols + 2 * PAD_PX)
    padded = cv2.copyMakeBorder(sums, 0, 0, PAD_PX, padded_cols - cols - PAD_PX, cv2.BORDER_REFLECT,
                                dst=scratch("psf_row_blur", (sums.shape[0], padded_cols)))
    spectrum = cv2.dft(padded, dst=padded, flags=cv2.DFT_ROWS)
    spectrum *= _row_otf_packed(camera, padded_cols)
    blurred = cv2.idft(spectrum, dst=spectrum, flags=cv2.DFT_ROWS | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    return blurred[:, PAD_PX:PAD_PX + cols]


def row_blurred_block_rate_sums(fields: tuple[np.ndarray, ...], camera: Camera, block_gain: np.ndarray,
                                offset_e_per_s: float, binning_rows: int, toward_last_row: bool,
                                ) -> list[tuple[np.ndarray, np.ndarray, float]] | None:
    """The rate block sums of smear fields given per binning block, through the line-spread function.

    Per field ``F`` (block means): the chain's ``rate = max(L(F), 0) x block gain + offset``, with ``L``
    :func:`blur_field_along_rows`' filter, and the sums of a block-mean rate, ``b x rate`` and
    ``b (b + 1) / 2 x rate`` (:func:`simulator.detector.charge_transfer.block_rate_sums`' plain and
    ramp-weighted sums of ``b`` equal rows), in the order the charge moves (blocks reversed when it moves
    toward the first row). The same float32 operations as the three steps one after the other, but the
    fields share one row transform (each row is transformed alone: stacking rows changes no bit) and
    the clip, the rate and both sums are one compiled pass.

    Parameters
    ----------
    fields : tuple of one or two ndarrays, shape (H / b, W)
        Smear-period radiance per binning block (W m^-2 sr^-1 um^-1).
    camera : Camera
        The camera.
    block_gain : ndarray, shape (H / b, W), float32
        Mean gain of each block (e-/s per W m^-2 sr^-1 um^-1), image order.
    offset_e_per_s : float
        Rate added to every pixel (dark current, e-/s).
    binning_rows : int
        Rows per block ``b``.
    toward_last_row : bool
        The charge moves toward the last row.

    Returns
    -------
    list of (plain, ramp, largest) or None
        Per field: the plain and ramp-weighted sums (float32 (H / b, W), e-/s; this thread's scratch
        arrays, valid until the next call) and the largest blurred radiance; None when a field or a rate
        is not finite, or negative (the caller's step-by-step path repairs or reports it).
    """
    import scipy.fft

    count = len(fields)
    if not 1 <= count <= 2:
        raise ValueError(f"row-blurred rate sums: one or two smear fields; got {count}")
    rows, cols = np.shape(fields[0])
    padded_cols = scipy.fft.next_fast_len(cols + 2 * PAD_PX)
    stacked = scratch("psf_smear_rows", (count * rows, padded_cols))
    for index, radiance in enumerate(fields):
        field = np.asarray(radiance, dtype=np.float32)
        if field.shape != (rows, cols):
            raise ValueError(f"row-blurred rate sums: fields of shapes {field.shape} and {(rows, cols)}")
        if not np.isfinite(field.sum()) or float(field.min()) < 0.0:     # as _checked: the steps repair or refuse
            return None
        cv2.copyMakeBorder(field, 0, 0, PAD_PX, padded_cols - cols - PAD_PX, cv2.BORDER_REFLECT,
                           dst=stacked[index * rows:(index + 1) * rows])
    spectrum = cv2.dft(stacked, dst=stacked, flags=cv2.DFT_ROWS)
    spectrum *= _row_otf_packed(camera, padded_cols)
    blurred = cv2.idft(spectrum, dst=spectrum, flags=cv2.DFT_ROWS | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    gain = np.ascontiguousarray(block_gain, dtype=np.float32)
    results = []
    for index in range(count):
        plain = scratch(f"psf_smear_rate_plain_{index}", (rows, cols))
        ramp = scratch(f"psf_smear_rate_ramp_{index}", (rows, cols))
        field_blurred = blurred[index * rows:(index + 1) * rows, PAD_PX:PAD_PX + cols]
        _clipped_block_rate_sums(field_blurred, gain, np.float32(offset_e_per_s), bool(offset_e_per_s),
                                 np.float32(binning_rows), np.float32(binning_rows * (binning_rows + 1) / 2),
                                 toward_last_row, plain, ramp)
        largest = max(float(field_blurred.max()), 0.0)      # the clipped field's (NaN propagates)
        if not (np.isfinite(largest) and np.isfinite(plain.sum())) or float(plain.min()) < 0.0:
            return None
        results.append((plain, ramp, largest))
    return results


@njit(cache=True, nogil=True, boundscheck=False)
def _clipped_block_rate_sums(blurred, gain, offset, with_offset, plain_factor, ramp_factor, toward_last_row, plain,
                             ramp):
    """:func:`row_blurred_block_rate_sums`' pass over one field's blurred rows.

    ``r = max(B, 0) x g (+ offset)``, ``plain = plain_factor x r``, ``ramp = ramp_factor x r`` (rows reversed
    unless ``toward_last_row``). ``max(B, 0)`` as np.maximum's bits: ``-0.0`` gives ``+0.0`` (its SIMD max),
    a NaN stays NaN.
    """
    rows, cols = blurred.shape
    zero = np.float32(0.0)
    for row in range(rows):
        target = row if toward_last_row else rows - 1 - row
        values, gains, out_plain, out_ramp = blurred[row], gain[row], plain[target], ramp[target]
        if with_offset:
            for col in range(cols):
                value = values[col]
                rate = (zero if value <= zero else value) * gains[col] + offset
                out_plain[col] = rate * plain_factor
                out_ramp[col] = rate * ramp_factor
        else:
            for col in range(cols):
                value = values[col]
                rate = (zero if value <= zero else value) * gains[col]
                out_plain[col] = rate * plain_factor
                out_ramp[col] = rate * ramp_factor


def blurred_fields(fields: RadianceFields, camera: Camera) -> RadianceFields:
    """The three period fields seen through the optics.

    The exposure field goes through the PSF; a flush or transfer field that is the exposure field's own
    object shares its blurred copy, any other one goes through the line-spread function across columns
    (module doc, "Smear fields"). Fields that are one object stay one object.

    Parameters
    ----------
    fields : RadianceFields
        Radiance (W m^-2 sr^-1 um^-1) of the three periods, (H, W) or per binning block (H / b, W).
    camera : Camera
        The camera.

    Returns
    -------
    RadianceFields
        The blurred fields, float32, same shapes.
    """
    exposure = blur_field(fields.exposure, camera)
    flush = exposure if fields.flush is fields.exposure else blur_field_along_rows(fields.flush, camera)
    if fields.transfer is fields.exposure:
        transfer = exposure
    elif fields.transfer is fields.flush:
        transfer = flush
    else:
        transfer = blur_field_along_rows(fields.transfer, camera)
    return RadianceFields(flush, exposure, transfer)
