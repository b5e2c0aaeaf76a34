"""Camera chain: ms per 1024x1024 -> 1024x256 image with the exact optics PSF (targets <= 5 ms still, <= 9 ms
moving, one thread), its accuracy against the full-resolution stages, and the chain against ESA's Pyxel
detector simulator (target: ours, PSF off, >= 50x faster, measured back to back).

Our chain (:func:`simulator.detector.camera_chain.render_image`): optics PSF, cos^4 falloff, PRNU, dark
current, fast-flush / exposure / transfer smear, 4-row binning, shot and read noise, gain, offset and the
12-bit ADC. The ``still`` row gives the three CCD periods one radiance field, the ``moving`` row three
different ones, the ``saturating`` row a scene bright enough for the per-pixel full-well path (no target).
Each speed row also times the full-resolution stages (``expected_charge_e(full_resolution=True)``, every
pixel blurred then binned: the chain before the binned path) interleaved with it, and gives the ratio.

Accuracy rows (``camera_chain/binned_vs_full_resolution``): the expected DN of the binned path (the PSF
folded into the binning, :data:`simulator.detector.camera_chain.BINNED_STAGES`) against the full-resolution
stages, RMS and max over the fields of the Gusev fidelity cases (two per class, as ``bench_fidelity``;
target <= 0.02 DN RMS), and on the speed rows' white-noise texture (no target: a pixel-scale texture at
17 % contrast is the worst case of the one term the binned path does not keep, the in-block covariance
of the blur's change and the PRNU).

Start-up row (``camera_chain/start_up``): the chain's compiled passes (numba, cached on disk beside the
sources) cost a fresh process (a campaign worker) the import of numba and the load of the cached machine code
at its first image; a fresh process (the cache already written) reports its CPU seconds to import the chain
and to render its first still image, and the second image's for comparison (no target).

Pyxel peer (``pip install -e ".[peer]"``; a row says it is skipped when ``pyxel`` cannot be imported):
Pyxel's exposure mode (``pyxel.run_mode``) on a CCD of the same size, pixel, quantum efficiency, dark
current, full well, read noise, gain and bit depth, its photon input set from memory (the photon rate
our chain's optics stage gives for the same radiance) by :func:`pyxel_photons_from_array`, then Pyxel's
own models: photon shot noise -> photo-electrons (QE) + dark current -> charge collection + full well ->
charge measurement + output-node noise -> amplifier + ADC. Pyxel's charge-transfer models are CTI models
(CDM, ArCTIc), which our chain does not simulate, and it has no frame-transfer smear, on-chip binning or
optics PSF: the stage is left out, so the peer chain does less work than ours and the ratio is
conservative; our chain is timed with the PSF off (the same physics as the peer's) and on.
``pyxel_models_ms`` times Pyxel's model pipeline alone (no exposure bookkeeping or xarray result);
the targets use it, the smaller of the two Pyxel figures.
"""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from benchmarks.targets import CAMERA_MOVING_MS, CAMERA_MS, CAMERA_RMS_DN, PYXEL_SPEEDUP, target_columns
from flight_interface.camera import Camera, load_camera
from simulator.detector import optics
from simulator.detector.camera_chain import CameraEffects, expected_charge_e, read_out, render_image
from simulator.detector.readout import expected_dn
from simulator.fields import RadianceFields

CAMERA = Path(__file__).resolve().parents[1] / "sitedata" / "cameras" / "mer_a.toml"
PEER_REPEATS = 5
SPEED_REPEATS = 15
ADC_RANGE_V = 10.0               # Pyxel's ADC input range; the volts per electron below give our camera's e-/DN


def run() -> list[dict]:
    camera = load_camera(CAMERA)
    rng = np.random.default_rng(0)
    texture = (30.0 + 5.0 * rng.standard_normal((1024, 1024))).astype(np.float32)
    still = RadianceFields(texture, texture, texture)
    moving = RadianceFields(texture, np.roll(texture, 1, axis=1), np.roll(texture, 2, axis=1))
    bright = np.full((1024, 1024), 400.0, dtype=np.float32)  # saturating: full-resolution path
    rows = []
    targets = {"still_camera_1_field": CAMERA_MS, "moving_3_fields": CAMERA_MOVING_MS}
    for name, fields in (("still_camera_1_field", still), ("moving_3_fields", moving),
                         ("saturating_full_res_path", RadianceFields(bright, bright, bright))):
        ours, full = _paired_ms(camera, fields, SPEED_REPEATS)
        row = {"name": f"camera_chain/{name}", "ms_per_image": ours, "full_resolution_ms": full,
               "ratio_to_full_resolution": ours / full}
        if name in targets:
            row.update(target_columns(ours, targets[name], "ms"))
        rows.append(row)
    rows += accuracy_rows(camera, texture)
    rows.append(start_up_row())
    rows += pyxel_peer_rows(camera, texture, {"psf_off_still": (still, CameraEffects(optics_psf=False)),
                                              "still": (still, CameraEffects()),
                                              "moving": (moving, CameraEffects())})
    return rows


def _paired_ms(camera: Camera, fields: RadianceFields, repeats: int) -> tuple[float, float]:
    """Median ms per image of the chain and of the chain through its full-resolution stages, interleaved."""
    def ours():
        return render_image(camera, fields, np.random.default_rng(1))

    def full():
        return read_out(camera, expected_charge_e(camera, fields, full_resolution=True), np.random.default_rng(1))

    ours(), full()
    times: dict[str, list[float]] = {"ours": [], "full": []}
    for _ in range(repeats):
        times["ours"].append(_seconds(ours))
        times["full"].append(_seconds(full))
    return 1e3 * float(np.median(times["ours"])), 1e3 * float(np.median(times["full"]))


def _expected_dn_error(camera: Camera, fields: RadianceFields) -> np.ndarray:
    """Expected DN of the binned path minus that of the full-resolution stages, float64 (H / b, W)."""
    binned = expected_dn(expected_charge_e(camera, fields), camera.electronics)
    full = expected_dn(expected_charge_e(camera, fields, full_resolution=True), camera.electronics)
    return binned.astype(np.float64) - full


def accuracy_rows(camera: Camera, texture: np.ndarray) -> list[dict]:
    """The binned path against the full-resolution stages: the Gusev fidelity cases' fields, and the texture."""
    from benchmarks.bench_fidelity import _cases
    from campaign.case.compute import simulate_case_inputs
    from campaign.case.inputs import PlanRow

    config, resources, plan_rows = _cases()
    rms, peak = [], []
    for record in plan_rows:
        for image in simulate_case_inputs(resources, PlanRow.from_record(record), config.scene).images:
            error = _expected_dn_error(resources.camera, image.radiance)
            rms.append(float(np.sqrt(np.mean(error ** 2))))
            peak.append(float(np.abs(error).max()))
    texture_error = _expected_dn_error(camera, RadianceFields(texture, texture, texture))
    return [
        {"name": "camera_chain/binned_vs_full_resolution", "images": len(rms), "rms_dn_mean": float(np.mean(rms)),
         "max_dn": float(np.max(peak)), **target_columns(float(np.max(rms)), CAMERA_RMS_DN, "DN")},
        {"name": "camera_chain/binned_vs_full_resolution_white_noise_texture",
         "rms_dn": float(np.sqrt(np.mean(texture_error ** 2))), "max_dn": float(np.abs(texture_error).max())},
    ]


START_UP_SCRIPT = """
import json, time
start = time.process_time()
import numpy as np
from flight_interface.camera import load_camera
from simulator.detector.camera_chain import render_image
from simulator.fields import RadianceFields
imported = time.process_time()
camera = load_camera({camera!r})
texture = (30.0 + 5.0 * np.random.default_rng(0).standard_normal((1024, 1024))).astype(np.float32)
fields = RadianceFields(texture, texture, texture)
ready = time.process_time()
render_image(camera, fields, np.random.default_rng(1))
first = time.process_time()
render_image(camera, fields, np.random.default_rng(1))
second = time.process_time()
print(json.dumps({{"import_cpu_s": imported - start, "first_image_cpu_s": first - ready,
                   "second_image_cpu_s": second - first}}))
"""


def start_up_row() -> dict:
    """CPU seconds of a fresh process: importing the chain, its first still image (with what it loads), its second.

    Run twice; the second run's figures (the compiled passes' cache written by then, as in a campaign's workers).
    """
    script = START_UP_SCRIPT.format(camera=str(CAMERA))
    repo = str(Path(__file__).resolve().parents[1])
    figures: dict = {}
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=repo, check=True)
        figures = json.loads(done.stdout.strip().splitlines()[-1])
    return {"name": "camera_chain/start_up", **figures}


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


def pyxel_peer_rows(camera: Camera, radiance: np.ndarray,
                    ours: dict[str, tuple[RadianceFields, CameraEffects]]) -> list[dict]:
    """Rows timing Pyxel's detector chain and ours back to back, or one row saying why the peer is skipped.

    Interleaved, medians of :data:`PEER_REPEATS`; ``ours`` maps a row name to the fields and the chain's
    switches. Only the PSF-off row carries the target (the physics Pyxel's chain has).
    """
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
            for name, (fields, effects) in ours.items():
                times[name].append(_seconds(lambda f=fields, e=effects: render_image(camera, f, np.random.default_rng(1),
                                                                                    e)))
    median_ms = {key: 1e3 * float(np.median(values)) for key, values in times.items()}
    rows = []
    for name in ours:
        speedup = median_ms["models"] / median_ms[name]
        row = {"name": f"camera_chain/pyxel_peer_{name}", "ours_ms": median_ms[name],
               "pyxel_models_ms": median_ms["models"], "pyxel_exposure_mode_ms": median_ms["exposure"],
               "speedup": speedup, "speedup_vs_exposure_mode": median_ms["exposure"] / median_ms[name]}
        if name.startswith("psf_off"):
            row.update(target_columns(speedup, PYXEL_SPEEDUP, "x", at_most=False))
        rows.append(row)
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
