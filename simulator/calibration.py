"""Simulated ground calibration: the flat field as a calibration campaign measures it.

A flight team never knows its detector's pixel response exactly; it measures it on the ground. Here
that measurement is simulated with the simulator's own camera chain
(:func:`simulator.detector.camera_chain.render_image`), so the estimator receives a flat field with
the errors a real one has:

* ``frames`` flat exposures of a uniform source, each with its own shot and read noise, 12-bit
  quantisation, offset and dark charge. The source is pulsed: it shines only during the exposure
  period (the usual way to take flats with a shutterless frame-transfer CCD), so there is no smear;
* ``frames`` dark exposures (source off) with their own noise;
* flat = mean(flats) - mean(darks), normalised by
  :func:`flight_interface.calibration.normalise_flat_field` (about 1 on the optical axis).

The source radiance puts the on-axis binned charge at :data:`FLAT_LEVEL_FRACTION` of the smallest
of the ADC range, the summing well and ``binning_rows`` pixel wells. Per read-out pixel the flat's
relative noise is then about ``1 / sqrt(frames * charge)``: 0.05 % for MER with 16 frames, against a
1 % PRNU per pixel (0.25 % per 4 x 4 block the reference estimator uses).

The truth, for comparison only (``[estimator] flat_field = "truth"``), is :func:`true_flat_field`.

Command line (writes a file ``python -m dimes_velocity --flat-field`` reads): :mod:`simulator.calibrate_flat_field`.
"""
from __future__ import annotations

import numpy as np

from flight_interface.calibration import normalise_flat_field, readout_flat_field
from flight_interface.camera import Camera
from simulator.detector.camera_chain import CameraEffects, expected_charge_e, pixel_gain, read_out
from simulator.fields import RadianceFields

#: On-axis binned charge of a flat exposure, as a fraction of the smallest charge capacity.
FLAT_LEVEL_FRACTION = 0.5
DEFAULT_FLAT_FRAMES = 16


def flat_source_radiance(camera: Camera) -> float:
    """Uniform source radiance giving :data:`FLAT_LEVEL_FRACTION` of full scale on axis.

    Parameters
    ----------
    camera : Camera
        The camera under calibration.

    Returns
    -------
    float
        Radiance (W m^-2 sr^-1 um^-1).
    """
    electronics = camera.electronics
    capacity_e = min((electronics.max_dn - electronics.adc_offset_dn) * electronics.adc_gain_e_per_dn,
                     electronics.binned_full_well_e, camera.binning_rows * electronics.full_well_e)
    charge_per_radiance = camera.binning_rows * camera.responsivity_e_per_s * camera.timing.exposure_s
    return FLAT_LEVEL_FRACTION * capacity_e / charge_per_radiance


def simulate_flat_field(camera: Camera, frames: int, rng: np.random.Generator,
                        effects: CameraEffects = CameraEffects()) -> np.ndarray:
    """Measure the flat field from ``frames`` simulated flat and ``frames`` dark exposures.

    Parameters
    ----------
    camera : Camera
    frames : int
        Flat exposures (and as many dark exposures), >= 1.
    rng : numpy.random.Generator
        Noise of all exposures, drawn in order: flat 1..N, then dark 1..N.
    effects : CameraEffects
        The camera chain's switches (the campaign's ``[scene.camera_effects]``: a calibration sees the
        detector as it is simulated); ``exact_poisson`` is kept, the noise switches too.

    Returns
    -------
    ndarray, float32, shape ``camera.binned_shape``: the normalised flat field.
    """
    if frames < 1:
        raise ValueError(f"flat-field frames = {frames}; allowed: >= 1")
    rows, columns = camera.binned_shape
    dark_block = np.zeros((rows, columns), np.float32)
    source = np.full((camera.height_px, camera.width_px), flat_source_radiance(camera), np.float32)
    lit = RadianceFields(flush=dark_block, exposure=source, transfer=dark_block)
    dark = RadianceFields(flush=dark_block, exposure=np.zeros_like(source), transfer=dark_block)
    total = np.zeros((rows, columns), np.float64)
    for fields, sign in ((lit, 1.0), (dark, -1.0)):
        charge_e = expected_charge_e(camera, fields, effects)     # the same scene every frame: one mean charge
        for _ in range(frames):
            total += sign * read_out(camera, charge_e, rng, effects).dn
    return normalise_flat_field(total / frames)


def true_flat_field(camera: Camera, effects: CameraEffects = CameraEffects()) -> np.ndarray:
    """The simulated detector's true relative response per read-out pixel: simulator truth.

    Parameters
    ----------
    camera : Camera
        The camera.
    effects : CameraEffects, optional
        Which of falloff and PRNU are on (default: both).

    Returns
    -------
    ndarray, shape ``camera.binned_shape``, float32
        Falloff x PRNU per binned pixel, about 1 on axis.
    """
    gain = pixel_gain(camera, effects.falloff, effects.prnu) / np.float32(camera.responsivity_e_per_s)
    return readout_flat_field(gain, camera.binned_shape, "true flat field")


if __name__ == "__main__":          # the old path of `python -m simulator.calibrate_flat_field`
    import runpy

    runpy.run_module("simulator.calibrate_flat_field", run_name="__main__", alter_sys=True)
