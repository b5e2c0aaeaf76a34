"""Camera chain: ms per 1024x1024 -> 1024x256 image (target <= 4 ms, still and moving, one thread), and
the same chain against ESA's Pyxel detector simulator (target: ours >= 50x faster, measured back to back).

Our chain (:func:`simulator.detector.camera_chain.render_image`): optics PSF, cos^4 falloff, PRNU, dark
current, fast-flush / exposure / transfer smear, 4-row binning, shot and read noise, gain, offset and the
12-bit ADC. The ``still`` row gives the three CCD periods one radiance field, the ``moving`` row three
different ones, the ``saturating`` row a scene bright enough for the per-pixel full-well path (no target).

Pyxel peer (``pip install -e ".[peer]"``; a row says it is skipped when ``pyxel`` cannot be imported):
Pyxel's exposure mode (``pyxel.run_mode``) on a CCD of the same size, pixel, quantum efficiency, dark
current, full well, read noise, gain and bit depth, its photon input set from memory (the photon rate
our chain's optics stage gives for the same radiance) by :func:`pyxel_photons_from_array`, then Pyxel's
own models: photon shot noise -> photo-electrons (QE) + dark current -> charge collection + full well ->
charge measurement + output-node noise -> amplifier + ADC. Pyxel's charge-transfer models are CTI models
(CDM, ArCTIc), which our chain does not simulate, and it has no frame-transfer smear or on-chip binning:
the stage is left out, so the peer chain does less work than ours and the ratio is conservative.
``pyxel_models_ms`` times Pyxel's model pipeline alone (no exposure bookkeeping or xarray result);
the targets use it, the smaller of the two Pyxel figures.
"""
from __future__ import annotations

import importlib.util
import time
import warnings
from pathlib import Path

import numpy as np

from benchmarks.targets import CAMERA_MS, PYXEL_SPEEDUP, target_columns
from benchmarks.timing import median_ms
from flight_interface.camera import Camera, load_camera
from simulator.detector import optics
from simulator.detector.camera_chain import render_image
from simulator.fields import RadianceFields

CAMERA = Path(__file__).resolve().parents[1] / "sitedata" / "cameras" / "mer_a.toml"
PEER_REPEATS = 5
ADC_RANGE_V = 10.0               # Pyxel's ADC input range; the volts per electron below give our camera's e-/DN


def run() -> list[dict]:
    camera = load_camera(CAMERA)
    rng = np.random.default_rng(0)
    texture = (30.0 + 5.0 * rng.standard_normal((1024, 1024))).astype(np.float32)
    still = RadianceFields(texture, texture, texture)
    moving = RadianceFields(texture, np.roll(texture, 1, axis=1), np.roll(texture, 2, axis=1))
    bright = np.full((1024, 1024), 400.0, dtype=np.float32)  # saturating: full-resolution path
    rows = []
    for name, fields in (("still_camera_1_field", still), ("moving_3_fields", moving),
                         ("saturating_full_res_path", RadianceFields(bright, bright, bright))):
        ms = median_ms(lambda: render_image(camera, fields, np.random.default_rng(1)), 15)  # noqa: B023 - called here
        row = {"name": f"camera_chain/{name}", "ms_per_image": ms}
        if not name.startswith("saturating"):
            row.update(target_columns(ms, CAMERA_MS, "ms"))
        rows.append(row)
    rows += pyxel_peer_rows(camera, texture, {"still": still, "moving": moving})
    return rows


# ---------------------------------------------------------------------------------------------- Pyxel peer

def pyxel_photons_from_array(detector, photons_per_s: np.ndarray) -> None:
    """Pyxel photon-collection model: the photon array of this exposure from an in-memory rate.

    Parameters
    ----------
    detector : pyxel.detectors.Detector
    photons_per_s : ndarray, shape (rows, columns)
        Photons per second arriving in each pixel (the exposure's ``detector.time_step`` multiplies it).
    """
    detector.photon.array = photons_per_s * detector.time_step


def pyxel_peer_rows(camera: Camera, radiance: np.ndarray, ours: dict[str, RadianceFields]) -> list[dict]:
    """Rows timing Pyxel's detector chain and ours back to back (interleaved, medians of
    :data:`PEER_REPEATS`), or one row saying why the peer is skipped."""
    if importlib.util.find_spec("pyxel") is None:
        return [{"name": "camera_chain/pyxel_peer", "skipped": "pyxel not installed: pip install -e '.[peer]'"}]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")             # Pyxel's import warns about optional packages
        run_exposure, run_models = _pyxel_chain(camera, radiance)   # runs the exposure once (warm)
        run_models()
        times: dict[str, list[float]] = {"exposure": [], "models": [], **{name: [] for name in ours}}
        for _ in range(PEER_REPEATS):
            times["exposure"].append(_seconds(run_exposure))
            times["models"].append(_seconds(run_models))
            for name, fields in ours.items():
                times[name].append(_seconds(lambda f=fields: render_image(camera, f, np.random.default_rng(1))))
    median_ms = {key: 1e3 * float(np.median(values)) for key, values in times.items()}
    rows = []
    for name in ours:
        speedup = median_ms["models"] / median_ms[name]
        rows.append({"name": f"camera_chain/pyxel_peer_{name}", "ours_ms": median_ms[name],
                     "pyxel_models_ms": median_ms["models"], "pyxel_exposure_mode_ms": median_ms["exposure"],
                     "speedup_vs_exposure_mode": median_ms["exposure"] / median_ms[name],
                     **target_columns(speedup, PYXEL_SPEEDUP, "x", at_most=False)})
    return rows


def _seconds(function) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def _pyxel_chain(camera: Camera, radiance: np.ndarray):
    """(run exposure mode, run the model pipeline alone): two callables on one Pyxel CCD like ``camera``
    (the exposure is run once here); both return the 12-bit image (DN, one per pixel, not binned)."""
    import pyxel
    from pyxel.detectors import CCD, CCDGeometry, Characteristics, Environment
    from pyxel.detectors.charge_to_volt_settings import ChargeToVoltSettings
    from pyxel.exposure import Exposure, Readout
    from pyxel.pipelines import DetectionPipeline, ModelFunction, Processor

    electronics = camera.electronics
    volts_per_e = ADC_RANGE_V / 2 ** electronics.adc_bits / electronics.adc_gain_e_per_dn
    quantum_efficiency = camera.radiometry.mean_quantum_efficiency
    photons_per_s = (optics.photoelectron_rate(radiance, camera) / quantum_efficiency).astype(np.float64)
    detector = CCD(geometry=CCDGeometry(row=camera.height_px, col=camera.width_px,
                                        pixel_vert_size=camera.detector.pixel_pitch_m * 1e6,
                                        pixel_horz_size=camera.detector.pixel_pitch_m * 1e6),
                   environment=Environment(temperature=273.15 + electronics.ccd_temperature_c),
                   characteristics=Characteristics(quantum_efficiency=quantum_efficiency,
                                                   charge_to_volt=ChargeToVoltSettings(value=volts_per_e),
                                                   pre_amplification=1.0, full_well_capacity=electronics.full_well_e,
                                                   adc_bit_resolution=electronics.adc_bits,
                                                   adc_voltage_range=(0.0, ADC_RANGE_V)))

    def model(function: str, **arguments) -> ModelFunction:
        return ModelFunction(func=function, name=function.rsplit(".", 1)[-1], arguments=arguments)

    models = "pyxel.models"
    pipeline = DetectionPipeline(
        photon_collection=[model(f"{__name__}.pyxel_photons_from_array", photons_per_s=photons_per_s),
                           model(f"{models}.photon_collection.shot_noise", type="poisson", seed=1)],
        charge_generation=[model(f"{models}.charge_generation.simple_conversion", binomial_sampling=False),
                           model(f"{models}.charge_generation.simple_dark_current",
                                 dark_rate=electronics.dark_current_ref_e_per_s, seed=2)],
        charge_collection=[model(f"{models}.charge_collection.simple_collection"),
                           model(f"{models}.charge_collection.simple_full_well")],
        charge_measurement=[model(f"{models}.charge_measurement.simple_measurement"),
                            model(f"{models}.charge_measurement.output_node_noise",
                                  std_deviation=electronics.read_noise_e * volts_per_e, seed=3)],
        readout_electronics=[model(f"{models}.readout_electronics.simple_amplifier"),
                             model(f"{models}.readout_electronics.simple_adc", data_type="uint16")])
    exposure = Exposure(readout=Readout(times=[camera.timing.exposure_s]))

    def run_exposure():
        return pyxel.run_mode(mode=exposure, detector=detector, pipeline=pipeline)["bucket"]["image"].values[0]

    processor = Processor(detector=detector, pipeline=pipeline)
    run_exposure()                # sets the detector's readout properties (time step), which run_models reuses

    def run_models():
        detector.empty()
        detector.time_step = camera.timing.exposure_s
        processor.run_pipeline(debug=False)
        return detector.image.array

    return run_exposure, run_models
