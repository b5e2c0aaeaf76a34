"""The camera chain in one place: radiance fields of the three CCD periods -> 12-bit binned image.

The chain is an ordered list of small stage functions (:data:`CHARGE_STAGES`, then :func:`read_out`),
in the style of ESA Pyxel's detector pipeline: each stage reads and updates one :class:`ChainState`
(the camera as the light passes through it). Follow the light::

    radiance (W m^-2 sr^-1 um^-1)          flush, exposure, transfer fields, (1024, 1024) or per block (256, 1024)
      check_radiance                       shapes: full frame or binning-block means
      optics_blur                          psf.blurred_fields: the optics point-spread function
      generation_rates                     x optics.photoelectron_rate (cos^4 falloff, absolute response)
                                           x charge_generation PRNU x dust transmission (off-nominal)
                                           + dark rate (+ hot pixels)                          (e-/s)
      collect_charge                       charge_transfer: fast-flush + exposure + transfer smear,
                                           4-row binning (+ particle hits); per pixel with blooming
                                           at full well when a pixel may saturate              (e-)
      add_storage_dark                     charge_generation.storage_dark_e: dark while waiting for read-out
    read_out
      readout.noisy_charge_e               shot noise at binned resolution (Poisson; Gaussian above
                                           1000 e- unless exact_poisson) + output amplifier noise
      readout.digitize                     full well, gain, offset, rounding, 12-bit clip -> uint16 (256, 1024)

:func:`expected_charge_e` runs :data:`CHARGE_STAGES` (no random draw); :func:`render_image` adds
:func:`read_out`.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from pydantic import Field

from config_tables.models import ConfigModel
from flight_interface.camera import Camera
from flight_interface.camera_file import Timing
from simulator.derived_cache import DERIVED
from simulator.detector import blooming, charge_generation, charge_transfer, optics, psf, readout
from simulator.fields import RadianceFields, bin_rows, block_means
from simulator.off_nominal import OffNominalArtefacts, hot_pixels, particle_hits

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
    """Radiance fields from any of the accepted forms.

    Parameters
    ----------
    radiance : RadianceFields, sequence of 3 arrays, or callable
        The fields, a (flush, exposure, transfer) sequence, or a callable ``period -> field``.

    Returns
    -------
    RadianceFields
        The three fields (the same arrays).
    """
    if isinstance(radiance, RadianceFields):
        return radiance
    if callable(radiance):
        return RadianceFields(*(radiance(period) for period in PERIODS))
    fields = list(radiance)
    if len(fields) != 3:
        raise ValueError(f"radiance: expected 3 fields (flush, exposure, transfer); got {len(fields)}")
    return RadianceFields(*fields)


def pixel_gain(camera: Camera, falloff: bool = True, prnu: bool = True, per_block: bool = False) -> np.ndarray:
    """Photo-electron rate per unit radiance of every pixel: responsivity x cos^4 falloff x PRNU.

    Parameters
    ----------
    camera : Camera
        The camera (cached per camera).
    falloff : bool, optional
        Include the cos^4 falloff.
    prnu : bool, optional
        Include the pixel response non-uniformity.
    per_block : bool, optional
        Give the mean over each binning block instead.

    Returns
    -------
    ndarray, shape (H, W) or (H / b, W), float32, read-only
        Gain (e-/s per W m^-2 sr^-1 um^-1).
    """
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
                 effects: CameraEffects = CameraEffects(), artefacts: OffNominalArtefacts | None = None) -> RenderedImage:
    """Render one descent image from the radiance fields of its three CCD periods.

    :func:`read_out` of :func:`expected_charge_e`.

    Parameters
    ----------
    camera : Camera
        The descent camera.
    radiance : RadianceFields, sequence of 3 arrays, or callable
        Radiance (W m^-2 sr^-1 um^-1) of the fast flush, exposure and frame transfer, as
        :func:`expected_charge_e`.
    rng : numpy.random.Generator
        Noise stream of the image (shot noise, then read noise).
    effects : CameraEffects, optional
        Switches of the chain (default: all on).
    artefacts : OffNominalArtefacts, optional
        Off-nominal artefacts of this image, as :func:`expected_charge_e`.

    Returns
    -------
    RenderedImage
        The read-out image (uint16 DN, binned (height / b, width)) with its expected DN and charge.
    """
    return read_out(camera, expected_charge_e(camera, radiance, effects, artefacts), rng, effects)


@dataclass
class ChainState:
    """The camera as the light passes through it: what each stage of :data:`CHARGE_STAGES` reads and updates.

    Parameters
    ----------
    camera : Camera
        The descent camera.
    effects : CameraEffects
        Switches of the chain.
    artefacts : OffNominalArtefacts or None
        Off-nominal artefacts of the image (dust, hot pixels, particle hits, blooming switch).
    radiance : RadianceFields
        Radiance (W m^-2 sr^-1 um^-1) of the three periods, (H, W) or per binning block (H / b, W).
    dark_rate_e_per_s : float, optional
        Dark current rate of every pixel (e-/s), set by :func:`generation_rates`.
    rates : RadianceFields, optional
        Charge generation rates of the three periods (e-/s per pixel, or per pixel mean of a block),
        set by :func:`generation_rates`; a field shared by several periods gives one shared rate.
    timing : Timing, optional
        The CCD timing the charge is collected with (smear off: no flush, no transfer).
    charge_e : ndarray, shape (H / b, W), optional
        Mean charge per binned pixel (e-), set by :func:`collect_charge`.
    """

    camera: Camera
    effects: CameraEffects
    artefacts: OffNominalArtefacts | None
    radiance: RadianceFields
    dark_rate_e_per_s: float = 0.0
    rates: RadianceFields | None = None
    timing: Timing | None = None
    charge_e: np.ndarray | None = field(default=None, repr=False)

    @property
    def block_shape(self) -> tuple[int, int]:
        """Shape (H / b, W) of a field given per binning block."""
        return (self.camera.height_px // self.camera.binning_rows, self.camera.width_px)


def check_radiance(state: ChainState) -> None:
    """Stage: every period's radiance field is a full frame (H, W) or per binning block (H / b, W).

    Parameters
    ----------
    state : ChainState
        Reads ``radiance``.

    Returns
    -------
    None

    Raises
    ------
    ValueError
        When a field has another shape.
    """
    camera = state.camera
    allowed = ((camera.height_px, camera.width_px), state.block_shape)
    for period in PERIODS:
        radiance = getattr(state.radiance, period)
        if np.shape(radiance) not in allowed:
            raise ValueError(f"radiance {period} field has shape {np.shape(radiance)}; expected "
                             f"{' or '.join(map(str, allowed))}")


def optics_blur(state: ChainState) -> None:
    """Stage: the optics' point-spread function on the radiance fields (:func:`psf.blurred_fields`).

    Parameters
    ----------
    state : ChainState
        Updates ``radiance`` (fields that were one object stay one object).

    Returns
    -------
    None
    """
    if state.effects.optics_psf:
        state.radiance = psf.blurred_fields(state.radiance, state.camera)


def _gains(state: ChainState) -> dict[str, np.ndarray]:
    """Photo-electron rate per unit radiance, e-/s per W m^-2 sr^-1 um^-1.

    ``"pixel"`` (H, W) and ``"block"`` (its block means, (H / b, W), made when first asked for), responsivity x falloff x PRNU
    x dust transmission. With dust they are cached on the dust map (the same in a case's three images).
    """
    camera, effects = state.camera, state.effects
    dust = state.artefacts.dust_transmission if state.artefacts is not None else None
    if dust is None:
        return {"pixel": pixel_gain(camera, effects.falloff, effects.prnu)}
    cache = DERIVED.of(dust, "render")
    key = ("gains", bool(effects.falloff), bool(effects.prnu))
    entry = cache.get(key)
    if entry is None or entry["camera"] is not camera:
        entry = cache[key] = {"camera": camera, "pixel": pixel_gain(camera, effects.falloff, effects.prnu) * dust}
    return entry


def _block_gain(state: ChainState, gains: dict) -> np.ndarray:
    """Mean over each binning block of the pixels' gain (responsivity x falloff x dust x PRNU), (H / b, W)."""
    dust = state.artefacts.dust_transmission if state.artefacts is not None else None
    if dust is None:
        return pixel_gain(state.camera, state.effects.falloff, state.effects.prnu, per_block=True)
    if "block" not in gains:
        gains["block"] = block_means(gains["pixel"], state.camera.binning_rows)
    return gains["block"]


def generation_rate(state: ChainState, radiance: np.ndarray) -> np.ndarray:
    """Charge generation rate of one radiance field: radiance x gain + dark rate (+ hot pixels).

    Parameters
    ----------
    state : ChainState
        The camera, effects, artefacts and ``dark_rate_e_per_s``.
    radiance : ndarray, shape (H, W) or (H / b, W)
        Radiance (W m^-2 sr^-1 um^-1), full frame or per binning block (then multiplied by the
        block means of the gain).

    Returns
    -------
    ndarray, float32, same shape as ``radiance``
        Rate (e-/s). NaN radiance reads black; a rate beyond float32 (or +inf radiance) stands for a
        saturating pixel (:data:`SATURATING_RATE_E_PER_S`).

    Raises
    ------
    ValueError
        When the radiance has negative values.
    """
    block = np.shape(radiance) == state.block_shape   # a field given per binning block (its mean)
    gains = _gains(state)
    hot = state.artefacts.hot_pixels if state.artefacts is not None else None
    with np.errstate(over="ignore"):          # an overflowing rate becomes inf, saturated below
        rate = np.multiply(radiance, _block_gain(state, gains) if block else gains["pixel"], dtype=np.float32)
    if state.dark_rate_e_per_s:
        rate += np.float32(state.dark_rate_e_per_s)
    if hot is not None and block:
        hot_pixels.add_to_block_rate(rate, hot, state.camera.binning_rows)
    elif hot is not None:
        hot_pixels.add_to_rate(rate, hot)
    with np.errstate(over="ignore"):
        finite = np.isfinite(rate.sum())   # one cheap pass (a huge finite sum may overflow: harmless)
    if not finite:  # repair only when needed
        rate = np.nan_to_num(rate, nan=0.0, posinf=SATURATING_RATE_E_PER_S, neginf=-1.0)
    if float(rate.min()) < 0.0:
        raise ValueError(f"radiance field has negative values (min {float(np.min(radiance)):.4g} "
                         "W m^-2 sr^-1 um^-1); radiance must be >= 0")
    return rate


def generation_rates(state: ChainState) -> None:
    """Stage: photo-electron and dark generation rates of the three periods (:func:`generation_rate`).

    A field that is the same object as an earlier period's is converted once. With the smear off the
    flush and transfer rates are zero and the timing has no flush and no transfer.

    Parameters
    ----------
    state : ChainState
        Reads ``radiance``; sets ``dark_rate_e_per_s``, ``rates`` and ``timing``.

    Returns
    -------
    None
    """
    camera, effects, fields = state.camera, state.effects, state.radiance
    state.dark_rate_e_per_s = (charge_generation.dark_rate_e_per_s(camera, effects.dark_current_scale)
                               if effects.dark_current else 0.0)
    exposure = generation_rate(state, fields.exposure)
    if not effects.smear:
        zero = np.zeros_like(exposure)
        state.rates = RadianceFields(zero, exposure, zero)
        state.timing = camera.timing.model_copy(update={"fast_flush_s": 0.0, "frame_transfer_s": 0.0})
        return
    flush = exposure if fields.flush is fields.exposure else generation_rate(state, fields.flush)
    if fields.transfer is fields.exposure:
        transfer = exposure
    elif fields.transfer is fields.flush:
        transfer = flush
    else:
        transfer = generation_rate(state, fields.transfer)
    state.rates = RadianceFields(flush, exposure, transfer)
    state.timing = camera.timing


def collect_charge(state: ChainState) -> None:
    """Stage: charge collected in the three periods, moved through the frame transfer and binned.

    When no pixel can reach full well the binned charge comes from block sums
    (:func:`charge_transfer.binned_charge_e`); otherwise each pixel is collected
    (:func:`charge_transfer.pixel_charge_e`, an exposure given per block spread over its rows),
    bloomed along its column at full well (or clipped when blooming is off) and then binned. Particle
    hits add their charge before the full-well step.

    Parameters
    ----------
    state : ChainState
        Reads ``rates``, ``timing``; sets ``charge_e`` ((H / b, W), e-).

    Returns
    -------
    None
    """
    camera, artefacts, rates, timing = state.camera, state.artefacts, state.rates, state.timing
    assert rates is not None and timing is not None, "collect_charge runs after generation_rates"
    hits = artefacts.particle_hits if artefacts is not None and artefacts.particle_hits is not None else None
    block_exposure = rates.exposure.shape == state.block_shape
    bound = charge_transfer.max_pixel_charge_bound_e(rates.flush, rates.exposure, rates.transfer, timing)
    if block_exposure:   # a block mean hides its brightest pixel: PRNU and in-block structure, a safe factor
        bound *= BLOCK_EXPOSURE_BOUND_FACTOR
    if hits is not None:
        bound += hits.max_pixel_charge_e
    if bound <= camera.electronics.full_well_e:
        charge = charge_transfer.binned_charge_e(rates.flush, rates.exposure, rates.transfer, timing,
                                                 camera.binning_rows, camera.height_px)
        if hits is not None:
            particle_hits.add_to_binned(charge, hits, camera.binning_rows)
        state.charge_e = charge
        return
    rate_exposure = rates.exposure
    if block_exposure:   # each pixel of a block gets the block's mean field times its own gain
        rate_exposure = generation_rate(state, np.repeat(state.radiance.exposure, camera.binning_rows, axis=0))
    pixel = charge_transfer.pixel_charge_e(rates.flush, rate_exposure, rates.transfer, timing)
    if hits is not None:
        particle_hits.add_to_pixels(pixel, hits)
    if artefacts is None or artefacts.blooming:
        pixel = blooming.bloom_columns(pixel, camera.electronics.full_well_e)[0]
    else:
        pixel = np.minimum(pixel, np.float32(camera.electronics.full_well_e))
    state.charge_e = bin_rows(pixel, camera.binning_rows)


def add_storage_dark(state: ChainState) -> None:
    """Stage: dark charge gathered in the storage area while each row waits for read-out.

    Parameters
    ----------
    state : ChainState
        Reads ``dark_rate_e_per_s``; updates ``charge_e`` (a new array).

    Returns
    -------
    None
    """
    if state.dark_rate_e_per_s:
        state.charge_e = state.charge_e + charge_generation.storage_dark_e(state.camera, state.dark_rate_e_per_s)


#: The stages from radiance to mean binned charge, in the order the light meets them.
CHARGE_STAGES: tuple[Callable[[ChainState], None], ...] = (
    check_radiance, optics_blur, generation_rates, collect_charge, add_storage_dark)


def expected_charge_e(camera: Camera, radiance: RadianceInput, effects: CameraEffects = CameraEffects(),
                      artefacts: OffNominalArtefacts | None = None) -> np.ndarray:
    """The mean charge of every binned pixel, from the radiance fields of the image's three CCD periods.

    Runs :data:`CHARGE_STAGES`: everything of the chain before the noise (no random draw).

    Parameters
    ----------
    camera : Camera
        The descent camera.
    radiance : RadianceFields, sequence of 3 arrays, or callable
        Radiance (W m^-2 sr^-1 um^-1) per pixel, shape (height, width), during fast flush, exposure
        and frame transfer. Fields that are the same object are converted once. Any field may instead
        be given per binning block, shape (height / b, width), each block's mean radiance: smear and
        binning only see block sums, so the block mean is all that is needed, with each block's pixel
        gains averaged likewise (for the exposure this drops the in-block correlation of scene and
        PRNU, a second-order term; the scene gives a blurred exposure this way, simulator.scene.blur_warp).
        When a pixel may reach full well a block exposure is spread over its block's rows.
    effects : CameraEffects, optional
        Switches of the chain (default: all on).
    artefacts : simulator.off_nominal.OffNominalArtefacts, optional
        Off-nominal artefacts of this image: dust transmission (on the photo-electron rate, after
        falloff), hot pixels (extra dark rate), particle-hit charge, blooming (else per-pixel clip).
        None: none of them, blooming on.

    Returns
    -------
    ndarray, float32 or float64, shape (height / b, width)
        Charge per binned pixel (e-), before full-well and ADC clipping.
    """
    state = ChainState(camera, effects, artefacts, as_radiance_fields(radiance))
    for stage in CHARGE_STAGES:
        stage(state)
    assert state.charge_e is not None
    return state.charge_e


def read_out(camera: Camera, charge_e: np.ndarray, rng: np.random.Generator,
             effects: CameraEffects = CameraEffects()) -> RenderedImage:
    """Read out a binned image of mean charge: shot and read noise, full well, gain, offset, rounding, ADC range.

    The same charge read out again with the stream's next draws is another exposure of the same scene
    (what a calibration's repeated flat frames are).

    Parameters
    ----------
    camera : Camera
        The camera (its electronics).
    charge_e : ndarray, shape (height / b, width)
        Mean charge per binned pixel (e-), from :func:`expected_charge_e`.
    rng : numpy.random.Generator
        Noise stream: shot noise, then read noise.
    effects : CameraEffects, optional
        Noise switches (``shot_noise``, ``read_noise``, ``exact_poisson``).

    Returns
    -------
    RenderedImage
        DN (uint16), expected DN and the mean charge (float32), each (height / b, width).
    """
    electronics = camera.electronics
    noisy = readout.noisy_charge_e(rng, charge_e, electronics.read_noise_e, effects.shot_noise,
                                   effects.read_noise, effects.exact_poisson)
    return RenderedImage(
        dn=readout.digitize(noisy, electronics),
        expected_dn=readout.expected_dn(charge_e, electronics),
        expected_charge_e=charge_e.astype(np.float32),
    )
