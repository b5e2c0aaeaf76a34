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
      readout.read_out_dn                  shot noise at binned resolution (Poisson; Gaussian above
                                           1000 e- unless exact_poisson) + output amplifier noise, then
                                           full well, gain, offset, rounding, 12-bit clip -> uint16 (256, 1024)
                                           (fused in float32 for the Gaussian default)

:func:`expected_charge_e` runs :data:`CHARGE_STAGES` (no random draw); :func:`render_image` adds
:func:`read_out`.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from flight_interface.camera import Camera
from flight_interface.camera_file import Timing
from simulator.derived_cache import DERIVED
from simulator.detector import blooming, charge_generation, charge_transfer, optics, psf, readout
from simulator.detector.effects import CameraEffects
from simulator.fields import RadianceFields, bin_rows, block_means
from simulator.off_nominal import OffNominalArtefacts, hot_pixels, particle_hits

PERIODS = ("flush", "exposure", "transfer")
BLOCK_EXPOSURE_BOUND_FACTOR = 1.5   # max pixel / max block mean allowance for an exposure given per block
SATURATING_RATE_E_PER_S = 1.0e30   # stands for an overflowing (or infinite) generation rate: fills any well


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
    block_sums : dict, optional
        The binned path's per-period block sums (period name -> (plain sums, in-block ramp-weighted sums,
        sums for the gain, largest field value)), set by the binned generation stage; None when the
        full-resolution stages take the image.
    storage_dark_added : bool, optional
        The storage dark is in ``charge_e`` already (added in :func:`collect_binned_charge`'s pass), so
        :func:`add_storage_dark` leaves it.
    """

    camera: Camera
    effects: CameraEffects
    artefacts: OffNominalArtefacts | None
    radiance: RadianceFields
    dark_rate_e_per_s: float = 0.0
    rates: RadianceFields | None = None
    timing: Timing | None = None
    charge_e: np.ndarray | None = field(default=None, repr=False)
    block_sums: dict | None = field(default=None, repr=False)
    storage_dark_added: bool = False

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
        Reads ``dark_rate_e_per_s``; updates ``charge_e`` (in place when it is float32, the chain's own array).

    Returns
    -------
    None
    """
    if state.dark_rate_e_per_s and not state.storage_dark_added:
        assert state.charge_e is not None
        dark = _storage_dark_e(state.camera, state.dark_rate_e_per_s)
        if state.charge_e.dtype == np.float32 and state.charge_e.flags.writeable:
            np.add(state.charge_e, dark, out=state.charge_e)
        else:
            state.charge_e = state.charge_e + dark


def _storage_dark_e(camera: Camera, dark_rate: float) -> np.ndarray:
    """:func:`charge_generation.storage_dark_e`, cached per camera and rate."""
    cache = DERIVED.of(camera, "render")
    key = ("storage_dark", float(dark_rate))
    if key not in cache:
        cache[key] = charge_generation.storage_dark_e(camera, dark_rate)
        cache[key].setflags(write=False)
    return cache[key]


def binned_path_applies(state: ChainState) -> bool:
    """Whether the binned path (:data:`BINNED_STAGES`) can take this image.

    It takes an image whose exposure field is full frame; the full-resolution stages take an exposure
    given per binning block (already at binned resolution) and, from :func:`collect_binned_charge`, an
    image where a pixel may reach full well.

    Parameters
    ----------
    state : ChainState
        Reads ``radiance`` and the camera.

    Returns
    -------
    bool
        True when :data:`BINNED_STAGES` apply.
    """
    camera = state.camera
    return np.shape(state.radiance.exposure) == (camera.height_px, camera.width_px) and camera.binning_rows > 1


def _binned_period_sums(state: ChainState, radiance: np.ndarray, gains: dict, blur: str, dark_rate: float,
                        smear_fields: tuple[np.ndarray, ...] = (), period: str = "exposure",
                        ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float] | None]:
    """Block sums of one full-frame period field for :func:`binned_rate_sums`, and of smear fields read with it.

    Per field (the first, then ``smear_fields``): (plain, ramp, exposure-ordered plain, max pixel radiance),
    or None when the field is not finite (the full-resolution stages read it). The first field is blurred
    as ``blur`` says ("psf", "rows" or "none"); ``smear_fields`` (only with "psf", charge moving toward the
    last row) are read in the same pass (:func:`psf.binned_blur_rate_sums`) and blurred along their rows.
    The sums are this thread's scratch arrays (``period`` names the separate pass's), dead after the image.
    """
    camera = state.camera
    b = camera.binning_rows
    toward_last = camera.timing.transfer_toward_last_row
    blur_sums = None
    if blur == "psf" and toward_last:     # the field read once for the rate sums and the blur
        blur_sums = psf.binned_blur_rate_sums(radiance, camera, b, gains["pixel"], dark_rate, smear_fields, reuse=True)
        assert blur_sums.rate_plain is not None and blur_sums.rate_ramp is not None
        read: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, float, float]] = [
            (blur_sums.rate_plain, blur_sums.rate_ramp, blur_sums.plain, blur_sums.smallest, blur_sums.largest),
            *blur_sums.smear]
        blurs = [blur] + ["rows"] * len(smear_fields)
    else:
        if smear_fields:
            raise ValueError("smear fields are read with a PSF-blurred exposure, charge moving toward the last row")
        read = [charge_transfer.checked_block_rate_sums(radiance, gains["pixel"], b, toward_last, dark_rate,
                                                        radiance_sums=blur == "rows", scratch_name=f"rate_{period}")]
        blurs = [blur]
    results: list[tuple[np.ndarray, np.ndarray, np.ndarray, float] | None] = []
    for (plain, ramp, radiance_sums, smallest, largest), field_blur in zip(read, blurs):
        if not np.isfinite(largest):
            results.append(None)
            continue
        if smallest < 0.0:
            raise ValueError(f"radiance field has negative values (min {smallest:.4g} W m^-2 sr^-1 um^-1); "
                             "radiance must be >= 0")
        blurred_and_not: tuple[np.ndarray, np.ndarray] | None = None
        if field_blur == "psf":
            if blur_sums is None:
                blur_sums = psf.binned_blur_rate_sums(radiance, camera, b, reuse=True)
            blurred_and_not = (blur_sums.blurred, blur_sums.plain)
        elif field_blur == "rows":    # along each row: commutes with the block sum, and with the block order
            assert radiance_sums is not None
            unblurred = _flip_blocks(radiance_sums, toward_last)       # image order
            blurred_and_not = (psf.row_blurred_block_sums(unblurred, camera), unblurred)
        if blurred_and_not is not None:      # the blur's change of each block's radiance, then of its charge rate
            charge_transfer.add_blur_change(plain, ramp, *blurred_and_not, _block_gain(state, gains), toward_last, b)
        results.append((plain, ramp, plain if toward_last else plain[::-1], largest))
    return results


def binned_rate_sums(state: ChainState) -> None:
    """Stage of the binned path: the block sums of the three periods' rates, PSF folded into the binning.

    Each full-frame field ``F`` gives, per ``b``-row block, the plain and ramp-weighted sums of
    ``F x gain + dark`` (:func:`charge_transfer.block_rate_sums`, one pass) plus the blur's change of
    the block: the block gain times (the block sum of the blurred field - that of ``F``). The blurred
    block sums are exact: for the exposure the PSF's spectrum folded into the binning
    (:func:`psf.binned_blur_sums`); a smear field's line-spread blur commutes with the block sum and
    runs on the block sums (:func:`psf.blur_field_along_rows`). What is not exact is where in the block
    the blur moves light: it is taken spread over the block's gains, which drops the covariance of the
    blur's in-block change with the in-block PRNU (``sum_j (B_j - F_j) (g_j - g_mean)``, a ~1 %
    weighting of a sub-pixel change; bench row ``camera_chain/binned_vs_full_resolution``), and its
    in-block ramp weighting of the smear (a 1 / N term). Block-mean smear fields go through
    :func:`generation_rate` as in the full-resolution path; hot pixels add to their blocks' sums.

    Parameters
    ----------
    state : ChainState
        Reads ``radiance``; sets ``dark_rate_e_per_s``, ``timing`` and ``block_sums`` (None when a field is
        not finite: the full-resolution stages take the image).

    Returns
    -------
    None
    """
    camera, effects, fields = state.camera, state.effects, state.radiance
    b, rows = camera.binning_rows, camera.height_px
    state.dark_rate_e_per_s = (charge_generation.dark_rate_e_per_s(camera, effects.dark_current_scale)
                               if effects.dark_current else 0.0)
    gains = _gains(state)
    full_frame = (rows, camera.width_px)
    smear_fields: list[np.ndarray] = []         # distinct full-frame smear fields, read in the exposure's pass
    if effects.smear and effects.optics_psf and camera.timing.transfer_toward_last_row:
        for period in ("flush", "transfer"):
            radiance = getattr(fields, period)
            if (np.shape(radiance) == full_frame and radiance is not fields.exposure
                    and not any(radiance is other for other in smear_fields)):
                smear_fields.append(radiance)
    period_sums = _binned_period_sums(state, fields.exposure, gains, "psf" if effects.optics_psf else "none",
                                      state.dark_rate_e_per_s, tuple(smear_fields))
    exposure = period_sums[0]
    if exposure is None:
        state.block_sums = None
        return
    read_with_exposure = {id(field): result for field, result in zip(smear_fields, period_sums[1:])}
    sums = {"exposure": exposure}
    state.timing = camera.timing
    if not effects.smear:
        zero = np.zeros_like(exposure[0])
        sums["flush"] = sums["transfer"] = (zero, zero, zero, 0.0)
        state.timing = camera.timing.model_copy(update={"fast_flush_s": 0.0, "frame_transfer_s": 0.0})
    else:
        block_smear = _row_blurred_block_smear(state, gains)
        for period in ("flush", "transfer"):
            radiance = getattr(fields, period)
            shared = [other for other in ("exposure", "flush") if other in sums and radiance is getattr(fields, other)]
            if shared:
                sums[period] = sums[shared[0]]
                continue
            if id(radiance) in block_smear:
                sums[period] = block_smear[id(radiance)]
                continue
            if np.shape(radiance) != full_frame:        # per block: the full-resolution stages' way
                field = psf.blur_field_along_rows(radiance, camera) if effects.optics_psf else radiance
                rate = _flip_blocks(generation_rate(state, field), camera.timing.transfer_toward_last_row)
                plain, ramp = charge_transfer._block_sums(rate, b, rows)
                sums[period] = (plain, ramp, plain, float(np.max(field)))
                continue
            if id(radiance) in read_with_exposure:
                smear_sums = read_with_exposure[id(radiance)]
            else:
                smear_sums = _binned_period_sums(state, radiance, gains, "rows" if effects.optics_psf else "none",
                                                 state.dark_rate_e_per_s, period=period)[0]
            if smear_sums is None:
                state.block_sums = None
                return
            sums[period] = smear_sums
    hot = state.artefacts.hot_pixels if state.artefacts is not None else None
    if hot is not None:
        for block_sums in {id(value): value for value in sums.values()}.values():
            _add_hot_pixels(block_sums[0], block_sums[1], hot, camera)
    state.block_sums = sums


def _row_blurred_block_smear(state: ChainState, gains: dict) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """The block sums of the smear fields given per binning block, by :func:`psf.row_blurred_block_rate_sums`.

    ``id(field) -> (plain, ramp, plain, largest)`` as :func:`binned_rate_sums` keeps them: the distinct
    per-block flush and transfer fields through one row transform, with the optics' blur on and no hot
    pixels; empty otherwise, or when a field is not finite or negative (then each goes the step-by-step
    way: :func:`psf.blur_field_along_rows`, :func:`generation_rate`, the sums of its block-mean rate).
    """
    camera, effects, fields = state.camera, state.effects, state.radiance
    if not effects.optics_psf or (state.artefacts is not None and state.artefacts.hot_pixels is not None):
        return {}
    distinct: list[np.ndarray] = []
    for period in ("flush", "transfer"):
        radiance = getattr(fields, period)
        if np.shape(radiance) == state.block_shape and not any(radiance is other for other in distinct):
            distinct.append(radiance)
    if not distinct:
        return {}
    sums = psf.row_blurred_block_rate_sums(tuple(distinct), camera, _block_gain(state, gains),
                                           state.dark_rate_e_per_s, camera.binning_rows,
                                           camera.timing.transfer_toward_last_row)
    if sums is None:
        return {}
    return {id(field): (plain, ramp, plain, largest) for field, (plain, ramp, largest) in zip(distinct, sums)}


def _max_gain(state: ChainState) -> float:
    """The largest pixel gain (e-/s per W m^-2 sr^-1 um^-1), cached with the gains."""
    gains = _gains(state)
    dust = state.artefacts.dust_transmission if state.artefacts is not None else None
    cache: dict = gains if dust is not None else DERIVED.of(state.camera, "render")
    key = ("max_gain", bool(state.effects.falloff), bool(state.effects.prnu))
    if key not in cache:
        cache[key] = float(np.max(gains["pixel"]))
    return float(cache[key])


def _flip_blocks(rate: np.ndarray, toward_last_row: bool) -> np.ndarray:
    return rate if toward_last_row else rate[::-1]


def _add_hot_pixels(plain: np.ndarray, ramp: np.ndarray, hot, camera: Camera) -> None:
    """Add the hot pixels' dark rate to a period's plain and ramp block sums in place (charge-move order)."""
    b = camera.binning_rows
    rows, cols = np.divmod(hot.flat_index, camera.width_px)
    if not camera.timing.transfer_toward_last_row:
        rows = camera.height_px - 1 - rows
    np.add.at(plain, (rows // b, cols), hot.rate_e_per_s)
    np.add.at(ramp, (rows // b, cols), hot.rate_e_per_s * (b - rows % b).astype(np.float32))


def collect_binned_charge(state: ChainState) -> None:
    """Stage of the binned path: the binned charge from the block sums, when no pixel can reach full well.

    The bound on a pixel's charge is the exposure's brightest pixel through the optics' kernel
    (``max F x max gain x sum |k|``, :func:`psf.kernel_abs_sum`) plus the largest column smear; when it
    reaches full well ``charge_e`` stays None and the full-resolution stages take the image (blooming).

    Parameters
    ----------
    state : ChainState
        Reads ``block_sums``, ``timing``; sets ``charge_e`` ((H / b, W), e-) or leaves it None. Without particle
        hits the storage dark is added in the same pass (the bits of :func:`add_storage_dark`'s addition;
        ``storage_dark_added``).

    Returns
    -------
    None
    """
    camera, artefacts, sums, timing = state.camera, state.artefacts, state.block_sums, state.timing
    if sums is None:
        return
    assert timing is not None
    hits = artefacts.particle_hits if artefacts is not None and artefacts.particle_hits is not None else None
    rows = camera.height_px
    kernel = psf.kernel_abs_sum(camera) if state.effects.optics_psf else 1.0
    exposure_pixel = float(sums["exposure"][3]) * _max_gain(state) * kernel + state.dark_rate_e_per_s
    bound = timing.exposure_s * exposure_pixel
    column_sums: dict[int, float] = {}        # a shared field's sums once
    for period, duration in (("flush", timing.fast_flush_s), ("transfer", timing.frame_transfer_s)):
        if duration:
            plain = sums[period][0]
            if id(plain) not in column_sums:
                column_sums[id(plain)] = charge_transfer.column_sum_max(plain)
            bound += duration / rows * column_sums[id(plain)]
    if hits is not None:
        bound += hits.max_pixel_charge_e
    if not bound <= camera.electronics.full_well_e:      # (a NaN bound too)
        return
    fuse_dark = bool(state.dark_rate_e_per_s) and hits is None      # (hits are added before the storage dark)
    charge = charge_transfer.binned_charge_from_sums(
        sums["flush"][:2], sums["exposure"][2], sums["transfer"][:2], timing, camera.binning_rows, rows,
        _storage_dark_e(camera, state.dark_rate_e_per_s) if fuse_dark else None)
    if hits is not None:
        particle_hits.add_to_binned(charge, hits, camera.binning_rows)
    state.charge_e = charge
    state.storage_dark_added = fuse_dark


#: The stages from radiance to mean binned charge at full resolution, in the order the light meets them.
CHARGE_STAGES: tuple[Callable[[ChainState], None], ...] = (
    check_radiance, optics_blur, generation_rates, collect_charge, add_storage_dark)
#: The binned path's stages between :func:`check_radiance` and :func:`add_storage_dark`: the same chain
#: with the PSF folded into the binning (:func:`binned_rate_sums`); it leaves ``charge_e`` None for an
#: image the full-resolution stages must take (a pixel may reach full well, a field is not finite).
BINNED_STAGES: tuple[Callable[[ChainState], None], ...] = (binned_rate_sums, collect_binned_charge)


def expected_charge_e(camera: Camera, radiance: RadianceInput, effects: CameraEffects = CameraEffects(),
                      artefacts: OffNominalArtefacts | None = None, full_resolution: bool = False) -> np.ndarray:
    """The mean charge of every binned pixel, from the radiance fields of the image's three CCD periods.

    Everything of the chain before the noise (no random draw): :data:`BINNED_STAGES` when
    :func:`binned_path_applies` (and they find no pixel that may reach full well), else
    :data:`CHARGE_STAGES`.

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
    full_resolution : bool, optional
        Run :data:`CHARGE_STAGES` even where the binned path applies (the reference it is measured against).

    Returns
    -------
    ndarray, float32 or float64, shape (height / b, width)
        Charge per binned pixel (e-), before full-well and ADC clipping.
    """
    state = ChainState(camera, effects, artefacts, as_radiance_fields(radiance))
    check_radiance(state)
    if not full_resolution and binned_path_applies(state):
        for stage in BINNED_STAGES:
            stage(state)
    if state.charge_e is None:
        for stage in CHARGE_STAGES[1:-1]:
            stage(state)
    add_storage_dark(state)
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
    dn, expected = readout.read_out_dn(rng, charge_e, camera.electronics, effects.shot_noise, effects.read_noise,
                                       effects.exact_poisson)
    return RenderedImage(dn=dn, expected_dn=expected, expected_charge_e=charge_e.astype(np.float32, copy=False))
