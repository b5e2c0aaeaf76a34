"""Pre-processing of a raw DIMES image: bin to 256 x 256 and flatten.

The camera returns ``(height / b) x width`` DN, rows binned ``b``:1 on chip (1024 x 256 for MER,
b = 4). Here columns are summed ``b``:1 as well, giving a square ``256 x 256`` image, then:

1. the ADC offset and the modelled dark charge are removed: image-area dark generated during fast
   flush, exposure and frame transfer (uniform rate ``d`` per pixel), and the storage-area dark of
   the readout ramp (binned row ``k`` of ``n`` waits ``readout_s * (n - k) / n`` when charge moves
   toward the last row);
2. the fast-flush and frame-transfer smear is inverted. With block sums ``G_k`` of the generation
   rate (scene assumed the same during the three periods and uniform inside a b-row block)::

       Q_k = alpha G_k + beta sum_{j<k} G_j + gamma sum_{j>k} G_j
       alpha = T_e + (T_f + T_t)(b + 1) / (2N),  beta = T_f b / N,  gamma = T_t b / N

   (N full-frame rows; rows reversed for transfer toward the first row). Writing
   ``P_k = sum_{j<k} G_j`` and ``S = sum_j G_j`` gives ``G_k = (Q_k - gamma S - (beta - gamma) P_k) / D``
   with ``D = alpha - gamma``: a first-order recursion (one ``lfilter`` pass) that is linear in the
   unknown column total ``S``, fixed by ``sum_k G_k = S``;
3. the result is divided by the binned relative response: the measured flat field when the
   estimator is given one (a calibration product, :mod:`flight_interface.calibration`), else the
   design cos^4 falloff of the camera model (pixel response non-uniformity then stays in the image).

The flattened image is in DN of the exposure alone, for the whole ``b x b`` block (so about
``b`` times the raw DN of a flat scene). Pixels within ``saturation_margin_dn`` of saturation and
pixels with less than ``min_signal_dn`` flattened signal (sky, deep shadow) are flagged.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dimes_velocity import compiled
from dimes_velocity.config import EstimatorConfig
from flight_interface.calibration import readout_flat_field
from flight_interface.camera import Camera


@dataclass(frozen=True)
class Flattening:
    """Per-camera constants of the flattening (computed once per camera and configuration).

    Attributes
    ----------
    binning : int
        Row binning on chip = column binning applied here.
    raw_shape : (int, int)
        Shape of the raw image (rows, columns).
    response : ndarray, float32, (n, n)
        Mean relative response of each binned block: the flat field's, or the design falloff's when
        there is no flat field (ones when not removed).
    storage_dark_dn : ndarray, float32, (n, 1)
        Storage-area dark charge of each binned row, DN summed over ``binning`` columns.
    area_dark_e_per_s : float
        Image-area dark generation of a whole block (e-/s), removed after smear inversion.
    alpha_s, beta_s, gamma_s : float
        Smear model coefficients (s); beta = gamma = 0 when smear removal is off.
    toward_last_row : bool
        Frame transfer moves charge toward the last row.
    adc_offset_dn, gain_e_per_dn, read_noise_e, exposure_s : float
        ADC offset (DN), gain (e-/DN), read noise (e- rms) and exposure (s).
    saturation_dn : float
        Raw DN at or above which a pixel is treated as saturated.
    """

    binning: int
    raw_shape: tuple[int, int]
    response: np.ndarray
    storage_dark_dn: np.ndarray
    area_dark_e_per_s: float
    alpha_s: float
    beta_s: float
    gamma_s: float
    toward_last_row: bool
    adc_offset_dn: float
    gain_e_per_dn: float
    read_noise_e: float
    exposure_s: float
    saturation_dn: float
    _inverse_response: np.ndarray = field(init=False, repr=False, compare=False)   # set by __post_init__
    _noise_scale: np.ndarray = field(init=False, repr=False, compare=False)

    @property
    def inverse_response(self) -> np.ndarray:
        """``1 / response``, float32, (n, n)."""
        return self._inverse_response

    @property
    def noise_scale(self) -> np.ndarray:
        """Charge noise (e-) of a block -> flattened DN, float32, (n, n)."""
        return self._noise_scale

    def __post_init__(self):
        inverse = (1.0 / self.response).astype(np.float32)
        object.__setattr__(self, "_inverse_response", inverse)
        scale = self.exposure_s / self.alpha_s / self.gain_e_per_dn
        object.__setattr__(self, "_noise_scale", (scale * inverse).astype(np.float32))


def make_flattening(camera: Camera, config: EstimatorConfig, flat_field: np.ndarray | None = None) -> Flattening:
    """Constants of :func:`flatten` for ``camera``.

    Parameters
    ----------
    camera : Camera
        The camera as designed (binning, timing, electronics, falloff).
    config : EstimatorConfig
        Which corrections to make (falloff, dark, smear) and the saturation margin.
    flat_field : ndarray, optional
        Measured relative response of each read-out pixel, shape ``camera.binned_shape`` (or full
        frame), about 1 on axis (:mod:`flight_interface.calibration`). None: divide by the design
        cos^4 falloff only (``camera.falloff_map``, ~0.5 s on first use).

    Returns
    -------
    Flattening
        The per-camera constants.

    Raises
    ------
    ValueError
        The width is not a multiple of the row binning.
    CalibrationError
        An unusable flat field.
    """
    binning = camera.binning_rows
    rows, columns = camera.height_px, camera.width_px
    if columns % binning:
        raise ValueError(f"camera {camera.source}: width {columns} is not a multiple of the binning {binning}")
    n_rows, n_cols = rows // binning, columns // binning
    if config.remove_falloff:
        source = camera.falloff_map if flat_field is None else flat_field
        readout = readout_flat_field(source, (n_rows, columns), "flat field" if flat_field is not None else "falloff")
        response = readout.astype(np.float64).reshape(n_rows, n_cols, binning).mean(axis=2)
    else:
        response = np.ones((n_rows, n_cols))
    electronics, timing = camera.electronics, camera.timing
    dark_rate = electronics.dark_current_e_per_s() if config.remove_dark else 0.0
    order = np.arange(n_rows, dtype=np.float64)
    waits = (n_rows - order) / n_rows if timing.transfer_toward_last_row else (order + 1.0) / n_rows
    storage_dark_e = binning * binning * dark_rate * timing.readout_s * waits   # b rows x b columns
    t_f, t_e, t_t = timing.fast_flush_s, timing.exposure_s, timing.frame_transfer_s
    if not config.remove_smear:
        t_f = t_t = 0.0
    alpha = t_e + (t_f + t_t) * (binning + 1) / (2.0 * rows)
    sat_charge = min(electronics.binned_full_well_e, binning * electronics.full_well_e)
    saturation = min(float(electronics.max_dn), sat_charge / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn)
    return Flattening(
        binning=binning, raw_shape=(n_rows, columns),
        response=np.maximum(response, 1e-3).astype(np.float32),
        storage_dark_dn=(storage_dark_e / electronics.adc_gain_e_per_dn).astype(np.float32)[:, None],
        area_dark_e_per_s=binning * binning * dark_rate,
        alpha_s=alpha, beta_s=t_f * binning / rows, gamma_s=t_t * binning / rows,
        toward_last_row=timing.transfer_toward_last_row,
        adc_offset_dn=electronics.adc_offset_dn, gain_e_per_dn=electronics.adc_gain_e_per_dn,
        read_noise_e=electronics.read_noise_e, exposure_s=t_e,
        saturation_dn=saturation - config.saturation_margin_dn,
    )


@dataclass(frozen=True)
class FlatImage:
    """A binned, flattened image.

    Attributes
    ----------
    signal_dn : ndarray, float32, (n, n)
        Exposure-only signal of each binned block (DN), radiance-proportional.
    excluded : ndarray, uint8, (n, n)
        1 where a block is saturated or has no signal.
    saturated_fraction, dark_fraction : float
        Fractions of blocks saturated / below ``min_signal_dn``.
    charge_e : ndarray, float32, (n, n)
        Collected charge of each block before flattening (e-), for the noise model.
    variance_floor_e2 : float
        Read and quantisation noise variance of a block (e-^2).
    noise_scale : ndarray, float32, (n, n)
        Converts the charge noise (e-) of a block into flattened DN.
    """

    signal_dn: np.ndarray
    excluded: np.ndarray
    saturated_fraction: float
    dark_fraction: float
    charge_e: np.ndarray
    variance_floor_e2: float
    noise_scale: np.ndarray

    @property
    def noise_dn(self) -> np.ndarray:
        """Expected noise standard deviation of ``signal_dn`` (shot + read + quantisation), DN, (n, n)."""
        return np.sqrt(np.maximum(self.charge_e, 0.0) + np.float32(self.variance_floor_e2)) * self.noise_scale

    def noise_dn_at(self, row: int, column: int) -> float:
        """:attr:`noise_dn` of one block.

        Parameters
        ----------
        row, column : int
            The block (binned pixels).

        Returns
        -------
        float
            Expected noise standard deviation of its ``signal_dn`` (DN).
        """
        charge = max(float(self.charge_e[row, column]), 0.0)
        return float(np.sqrt(charge + self.variance_floor_e2) * self.noise_scale[row, column])


def bin_columns(raw_dn: np.ndarray, binning: int, highest: float | None = None) -> np.ndarray:
    """Sum ``binning`` adjacent columns: (rows, cols) -> (rows, cols / binning), float32.

    The sum runs left to right in float32 (exact for integer DN: sums below 2^24). Unsigned integer
    images whose sums cannot overflow their own type (``highest``: the image's maximum, when known)
    are summed in that type and converted once; other integer images of up to 16 bits are added into
    the float32 result directly, without a float32 copy of the raw image.

    Parameters
    ----------
    raw_dn : ndarray, shape (rows, cols)
        Raw image (DN), any integer or float dtype.
    binning : int
        Columns summed; divides ``cols``.
    highest : float or None, optional
        The image's maximum (DN), when known.

    Returns
    -------
    ndarray, shape (rows, cols / binning), float32
        The column sums (DN).
    """
    raw = np.asarray(raw_dn)
    if raw.dtype.kind == "u" and raw.dtype.itemsize <= 2:
        if highest is None:
            highest = float(raw.max()) if raw.size else 0.0
        if highest * binning <= np.iinfo(raw.dtype).max:          # exact in the raw integer type
            summed = np.add(raw[:, 0::binning], raw[:, 1::binning]) if binning > 1 else raw.copy()
            for offset in range(2, binning):
                summed += raw[:, offset::binning]
            return summed.astype(np.float32)
    if raw.dtype.kind in "ui" and raw.dtype.itemsize <= 2:
        total = raw[:, 0::binning].astype(np.float32)
        for offset in range(1, binning):
            np.add(total, raw[:, offset::binning], out=total)
        return total
    raw = raw.astype(np.float32)
    total = raw[:, 0::binning].copy()
    for offset in range(1, binning):
        total += raw[:, offset::binning]
    return total


def unsmear(charge_e: np.ndarray, flattening: Flattening) -> np.ndarray:
    """Invert the fast-flush / frame-transfer smear (module docstring).

    Parameters
    ----------
    charge_e : ndarray, shape (n, n), float32
        Collected charge of each binned block (e-), offset and storage dark removed.
    flattening : Flattening
        The smear coefficients and transfer direction.

    Returns
    -------
    ndarray, shape (n, n), float32
        Charge generation rate of each block during the exposure (e-/s).
    """
    alpha, beta, gamma = flattening.alpha_s, flattening.beta_s, flattening.gamma_s
    if beta == 0.0 and gamma == 0.0:
        return charge_e / np.float32(alpha)
    d = alpha - gamma
    ratio = (beta - gamma) / d
    n_rows = charge_e.shape[0]
    if ratio == 0.0:   # equal flush and transfer times (MER): G_k = (Q_k - gamma S) / d
        total = charge_e.sum(axis=0, dtype=np.float64) / (d + n_rows * gamma)
        rates = np.subtract(charge_e, (gamma * total).astype(np.float32)[None, :], dtype=np.float32)
        return np.divide(rates, np.float32(d), out=rates)
    q = charge_e if flattening.toward_last_row else charge_e[::-1]

    # scipy.signal takes ~0.7 s to import (it loads scipy.stats): loaded here, at the first smear
    # correction, so that every command line that merely validates a campaign file starts fast
    from scipy.signal import lfilter

    def solve(u: np.ndarray) -> np.ndarray:
        running = lfilter([1.0], [1.0, -(1.0 - ratio)], u, axis=0)   # P_{k+1}
        before = np.zeros_like(running)
        before[1:] = running[:-1]
        return u - ratio * before

    rates_q = solve(q.astype(np.float64) / d)                   # S = 0 part
    rates_s = solve(np.full((n_rows, 1), -gamma / d))            # per unit S
    total = rates_q.sum(axis=0) / (1.0 - rates_s.sum())
    rates = rates_q + rates_s * total[None, :]
    rates = rates if flattening.toward_last_row else rates[::-1]
    return rates.astype(np.float32)


def flatten(raw_dn: np.ndarray, flattening: Flattening, config: EstimatorConfig) -> FlatImage:
    """Bin and flatten one raw image.

    Parameters
    ----------
    raw_dn : ndarray, shape ``flattening.raw_shape``
        The read-out image (DN), any integer or float dtype.
    flattening : Flattening
        The camera's constants (:func:`make_flattening`).
    config : EstimatorConfig
        ``min_signal_dn``: blocks below it are excluded.

    Returns
    -------
    FlatImage
        The flattened signal, excluded blocks and noise model.
    """
    b = flattening.binning
    gain = np.float32(flattening.gain_e_per_dn)
    raw = np.asarray(raw_dn)
    alpha, beta, gamma = flattening.alpha_s, flattening.beta_s, flattening.gamma_s
    no_smear = beta == 0.0 and gamma == 0.0
    compiled_pass = raw.dtype.kind in "ui" and raw.dtype.itemsize <= 2 and (no_smear or beta == gamma)
    highest = raw.max()
    if compiled_pass:      # integer DN, no smear or MER's equal times: the same float32 bits in two compiled passes
        offset_dn = np.float32(b * flattening.adc_offset_dn)
        if b == 4 and raw.dtype == np.uint16 and raw.flags.c_contiguous:
            charge_e = compiled.binned_charge_u16x4(raw.view(np.uint64), offset_dn, flattening.storage_dark_dn, gain)
        else:
            charge_e = compiled.binned_charge(raw, b, offset_dn, flattening.storage_dark_dn, gain)
    if highest >= flattening.saturation_dn:
        brightest = raw[:, 0::b]
        for offset in range(1, b):
            brightest = np.maximum(brightest, raw[:, offset::b])
        saturated: np.ndarray | None = brightest >= flattening.saturation_dn
    else:
        saturated = None                    # no block saturated
    if compiled_pass:
        d = alpha - gamma
        signal, dark, dark_count = compiled.flattened_signal(
            charge_e, not no_smear, d + charge_e.shape[0] * gamma, gamma, np.float32(alpha if no_smear else d),
            np.float32(flattening.area_dark_e_per_s), np.float32(flattening.exposure_s) / gain,
            flattening.inverse_response, np.float32(config.min_signal_dn))
        excluded = np.bitwise_or(saturated, dark) if saturated is not None else dark
    else:
        # the same float32 operations in the same order as written out in the module docstring, in place
        summed_dn = bin_columns(raw, b, float(highest))
        summed_dn -= np.float32(b * flattening.adc_offset_dn)
        summed_dn -= flattening.storage_dark_dn
        charge_e = np.multiply(summed_dn, gain, out=summed_dn)
        signal = unsmear(charge_e, flattening)
        signal -= np.float32(flattening.area_dark_e_per_s)
        signal *= np.float32(flattening.exposure_s) / gain
        signal *= flattening.inverse_response
        dark_mask = signal < np.float32(config.min_signal_dn)
        dark_count = int(np.count_nonzero(dark_mask))
        excluded = (np.bitwise_or(saturated, dark_mask) if saturated is not None else dark_mask).view(np.uint8)
    return FlatImage(signal_dn=signal, excluded=excluded,
                     saturated_fraction=float(np.count_nonzero(saturated)) / saturated.size if saturated is not None
                     else 0.0,
                     dark_fraction=float(dark_count) / signal.size, charge_e=charge_e,
                     variance_floor_e2=float(b * flattening.read_noise_e**2 + b * flattening.gain_e_per_dn**2 / 12.0),
                     noise_scale=flattening.noise_scale)
