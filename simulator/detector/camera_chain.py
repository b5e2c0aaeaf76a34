"""The camera chain in one place: radiance fields of the three CCD periods -> 12-bit binned image.

Follow the light::

    radiance (W m^-2 sr^-1 um^-1)             flush, exposure, transfer fields, (1024, 1024)
      -> psf.blurred_fields                   optics point-spread function (diffraction over the band, blur)
      -> optics.photoelectron_rate            cos^4 falloff, absolute response      (e-/s)
      -> charge_generation.apply_prnu         pixel response non-uniformity
      -> x dust transmission (off-nominal)    simulator.off_nominal.dust
      -> + dark rate (+ hot pixels)           thermal electrons, temperature model   (e-/s)
      -> charge_transfer.binned_charge_e      fast-flush + exposure + transfer smear, 4-row binning (e-)
         (+ particle hits; per pixel with blooming at full well when a pixel may saturate)
      -> + charge_generation.storage_dark_e   dark gathered while waiting for read-out
      -> readout.noisy_charge_e               shot noise at binned resolution (Poisson; Gaussian above
                                              1000 e- unless exact_poisson) + output amplifier noise
      -> readout.digitize                     full well, gain, offset, rounding, 12-bit clip -> uint16 (256, 1024)
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from pydantic import Field

from flight_interface.camera import Camera
from flight_interface.tomlfields import ConfigModel
from simulator.derived_cache import DERIVED
from simulator.detector import blooming, charge_generation, charge_transfer, optics, psf, readout
from simulator.fields import RadianceFields, bin_rows, block_means
from simulator.off_nominal import hot_pixels, particle_hits

PERIODS = ("flush", "exposure", "transfer")
BLOCK_EXPOSURE_BOUND_FACTOR = 1.5   # max pixel / max block mean allowance for an exposure given per block
SATURATING_RATE_E_PER_S = 1.0e30   # stands for an overflowing (or infinite) generation rate: fills any well


class CameraEffects(ConfigModel):
    """``[scene.camera_effects]``: switches of the camera chain; all on is the nominal camera."""

    optics_psf: bool = True
    """The optics' point-spread function (the camera's [optics]; simulator.detector.psf)."""
    falloff: bool = True
    """cos^4 falloff with field angle."""
    prnu: bool = True
    """Pixel response non-uniformity."""
    dark_current: bool = True
    """Dark current (image and storage areas)."""
    dark_current_scale: float = Field(1.0, ge=0.0, le=1e6)
    """Multiplies the camera's dark current (excessive dark current: > 1)."""
    smear: bool = True
    """Fast-flush and frame-transfer smear."""
    shot_noise: bool = True
    """Photon and dark shot noise."""
    read_noise: bool = True
    """Output amplifier noise."""
    exact_poisson: bool = False
    """Poisson shot noise at every level (false: Gaussian above readout.GAUSSIAN_MIN_MEAN_E, a fidelity shortcut)."""


@dataclass(frozen=True)
class RenderedImage:
    """A read-out descent image.

    Attributes
    ----------
    dn : ndarray, uint16, shape (binned rows, width)
        The image as the camera returns it, 0 .. 2**bits - 1.
    expected_dn : ndarray, float32, same shape
        The noise-free DN (mean of ``dn`` over noise realisations, before rounding).
    expected_charge_e : ndarray, float32, same shape
        Mean charge per binned pixel (e-), before full-well and ADC clipping.
    """

    dn: np.ndarray
    expected_dn: np.ndarray
    expected_charge_e: np.ndarray


RadianceInput = RadianceFields | Sequence[np.ndarray] | Callable[[str], np.ndarray]


def as_radiance_fields(radiance: RadianceInput) -> RadianceFields:
    """Accept fields, a (flush, exposure, transfer) sequence, or a callable ``period -> field``."""
    if isinstance(radiance, RadianceFields):
        return radiance
    if callable(radiance):
        return RadianceFields(*(radiance(period) for period in PERIODS))
    fields = list(radiance)
    if len(fields) != 3:
        raise ValueError(f"radiance: expected 3 fields (flush, exposure, transfer); got {len(fields)}")
    return RadianceFields(*fields)


def pixel_gain(camera: Camera, falloff: bool = True, prnu: bool = True, per_block: bool = False) -> np.ndarray:
    """Photo-electron rate per unit radiance of every pixel, e-/s per W m^-2 sr^-1 um^-1, float32 (H, W)
    (or its mean over each binning block, (H/b, W)): responsivity x cos^4 falloff x PRNU (cached per camera)."""
    cache = DERIVED.of(camera, "render")
    key = ("gain", bool(falloff), bool(prnu), bool(per_block))
    if key not in cache:
        if per_block:
            full = pixel_gain(camera, falloff, prnu)
            cache[key] = block_means(full, camera.binning_rows)
        else:
            gain = optics.photoelectron_rate(np.ones((camera.height_px, camera.width_px), dtype=np.float32),
                                             camera, falloff=falloff)
            cache[key] = charge_generation.apply_prnu(gain, charge_generation.prnu_map(camera)) if prnu else gain
        cache[key].setflags(write=False)
    return cache[key]


def render_image(camera: Camera, radiance: RadianceInput, rng: np.random.Generator,
                 effects: CameraEffects = CameraEffects(), artefacts=None) -> RenderedImage:
    """Render one descent image from the radiance fields of its three CCD periods:
    :func:`read_out` of :func:`expected_charge_e` (parameters as there).

    Returns
    -------
    RenderedImage
    """
    return read_out(camera, expected_charge_e(camera, radiance, effects, artefacts), rng, effects)


def expected_charge_e(camera: Camera, radiance: RadianceInput, effects: CameraEffects = CameraEffects(),
                      artefacts=None) -> np.ndarray:
    """The mean charge of every binned pixel, from the radiance fields of the image's three CCD periods
    (everything of the chain before the noise: no random draw).

    Parameters
    ----------
    camera : Camera
    radiance : RadianceFields, sequence of 3 arrays, or callable
        Radiance (W m^-2 sr^-1 um^-1) per pixel, shape (height, width), during fast flush, exposure
        and frame transfer. Fields that are the same object are converted once. Any field may instead
        be given per binning block, shape (height / b, width), each block's mean radiance: smear and
        binning only see block sums, so the block mean is all that is needed, with each block's pixel
        gains averaged likewise (for the exposure this drops the in-block correlation of scene and
        PRNU, a second-order term; the scene gives a blurred exposure this way, simulator.scene.blur_warp).
        When a pixel may reach full well a block exposure is spread over its block's rows.
    effects : CameraEffects
    artefacts : simulator.off_nominal.OffNominalArtefacts, optional
        Off-nominal artefacts of this image: dust transmission (on the photo-electron rate, after
        falloff), hot pixels (extra dark rate), particle-hit charge, blooming (else per-pixel clip).
        None: none of them, blooming on.

    Returns
    -------
    ndarray, float32 or float64, shape (height / b, width)
        Charge per binned pixel (e-), before full-well and ADC clipping.
    """
    fields = as_radiance_fields(radiance)
    expected_shape = (camera.height_px, camera.width_px)
    block_shape = (camera.height_px // camera.binning_rows, camera.width_px)
    for period, field in zip(PERIODS, (fields.flush, fields.exposure, fields.transfer)):
        allowed = (expected_shape, block_shape)
        if np.shape(field) not in allowed:
            raise ValueError(f"radiance {period} field has shape {np.shape(field)}; expected "
                             f"{' or '.join(map(str, allowed))}")
    if effects.optics_psf:
        fields = psf.blurred_fields(fields, camera)

    dark_rate = (charge_generation.dark_rate_e_per_s(camera, effects.dark_current_scale)
                 if effects.dark_current else 0.0)
    rates: dict[int | str, np.ndarray] = {}
    dust = artefacts.dust_transmission if artefacts is not None else None
    hot = artefacts.hot_pixels if artefacts is not None else None
    hits = artefacts.particle_hits if artefacts is not None and artefacts.particle_hits is not None else None

    gain = pixel_gain(camera, effects.falloff, effects.prnu)           # responsivity x falloff x PRNU
    dusty: dict = {}
    if dust is not None:   # the case's dust is the same in its three images: its gain is made once (cached on it)
        dusty = DERIVED.of(dust, "render").setdefault((id(camera), bool(effects.falloff), bool(effects.prnu)), {})
        if "gain" not in dusty:
            dusty["gain"] = gain * dust
        gain = dusty["gain"]

    def block_gain() -> np.ndarray:
        """Mean over each binning block of the pixels' gain (responsivity x falloff x dust x PRNU), (H/b, W)."""
        if dust is None:
            return pixel_gain(camera, effects.falloff, effects.prnu, per_block=True)
        if "block_gain" not in dusty:
            dusty["block_gain"] = block_means(gain, camera.binning_rows)
        return dusty["block_gain"]

    def generation_rate(field: np.ndarray) -> np.ndarray:
        key = id(field)
        if key not in rates:
            block = np.shape(field) == block_shape   # a smear-period field given per binning block (its mean)
            with np.errstate(over="ignore"):          # an overflowing rate becomes inf, saturated below
                rate = np.multiply(field, block_gain() if block else gain, dtype=np.float32)
            if dark_rate:
                rate += np.float32(dark_rate)
            if hot is not None and block:
                hot_pixels.add_to_block_rate(rate, hot, camera.binning_rows)
            elif hot is not None:
                hot_pixels.add_to_rate(rate, hot)
            with np.errstate(over="ignore"):
                finite = np.isfinite(rate.sum())   # one cheap pass (a huge finite sum may overflow: harmless)
            if not finite:  # repair only when needed
                # NaN reads black; a rate beyond float32 (or +inf radiance) saturates the pixel
                rate = np.nan_to_num(rate, nan=0.0, posinf=SATURATING_RATE_E_PER_S, neginf=-1.0)
            if float(rate.min()) < 0.0:
                raise ValueError(f"radiance field has negative values (min {float(np.min(field)):.4g} "
                                 "W m^-2 sr^-1 um^-1); radiance must be >= 0")
            rates[key] = rate
        return rates[key]

    rate_exposure = generation_rate(fields.exposure)
    block_exposure = rate_exposure.shape == block_shape
    if effects.smear:
        rate_flush, rate_transfer = generation_rate(fields.flush), generation_rate(fields.transfer)
        timing = camera.timing
    else:
        rate_flush = rate_transfer = np.zeros_like(rate_exposure)
        timing = camera.timing.model_copy(update={"fast_flush_s": 0.0, "frame_transfer_s": 0.0})

    bound = charge_transfer.max_pixel_charge_bound_e(rate_flush, rate_exposure, rate_transfer, timing)
    if block_exposure:   # a block mean hides its brightest pixel: PRNU and in-block structure, a safe factor
        bound *= BLOCK_EXPOSURE_BOUND_FACTOR
    if hits is not None:
        bound += hits.max_pixel_charge_e
    if bound <= camera.electronics.full_well_e:
        charge = charge_transfer.binned_charge_e(rate_flush, rate_exposure, rate_transfer, timing,
                                                 camera.binning_rows, camera.height_px)
        if hits is not None:
            particle_hits.add_to_binned(charge, hits, camera.binning_rows)
    else:  # some pixel may saturate: bloom (or clip) each pixel at full well before binning
        if block_exposure:   # each pixel of a block gets the block's mean field times its own gain
            rate_exposure = generation_rate(np.repeat(fields.exposure, camera.binning_rows, axis=0))
        pixel = charge_transfer.pixel_charge_e(rate_flush, rate_exposure, rate_transfer, timing)
        if hits is not None:
            particle_hits.add_to_pixels(pixel, hits)
        if artefacts is None or artefacts.blooming:
            pixel = blooming.bloom_columns(pixel, camera.electronics.full_well_e)[0]
        else:
            pixel = np.minimum(pixel, np.float32(camera.electronics.full_well_e))
        charge = bin_rows(pixel, camera.binning_rows)
    if dark_rate:
        charge = charge + charge_generation.storage_dark_e(camera, dark_rate)
    return charge


def read_out(camera: Camera, charge_e: np.ndarray, rng: np.random.Generator,
             effects: CameraEffects = CameraEffects()) -> RenderedImage:
    """Read out a binned image of mean charge ``charge_e`` (e-, (height / b, width), from
    :func:`expected_charge_e`): shot and read noise from ``rng`` (in that order), full well, gain, offset,
    rounding and the ADC's range. The same charge read out again with the stream's next draws is
    another exposure of the same scene (what a calibration's repeated flat frames are)."""
    electronics = camera.electronics
    noisy = readout.noisy_charge_e(rng, charge_e, electronics.read_noise_e, effects.shot_noise,
                                   effects.read_noise, effects.exact_poisson)
    return RenderedImage(
        dn=readout.digitize(noisy, electronics),
        expected_dn=readout.expected_dn(charge_e, electronics),
        expected_charge_e=charge_e.astype(np.float32),
    )
