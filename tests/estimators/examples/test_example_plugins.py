"""The example plug-ins of docs/estimators.md (estimators/examples/) run through the real plug-in machinery.

Each example's own ``[[estimators]]`` entry (the TOML in its docstring, validated as a campaign file's
entry) is built with :func:`estimators.plugins.build_estimator` and run with
:func:`~estimators.plugins.run_estimator` on one simulated case, as a campaign worker does. The
expected answer is what the examples promise, computed here from the case: the IMU's horizontal velocity
at the last image (true velocity + the IMU bias put in), valid, with the stated uncertainty
``sqrt(2) x imu_bias_sigma_mps``; on dark images (every pixel at the ADC offset) invalid, ``no_signal``.
"""
from __future__ import annotations

import math
import textwrap
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pydantic import TypeAdapter
from synthetic_descent import constant_velocity_descent, random_ground

from estimators.contract import EstimatorInputs
from estimators.entries import EstimatorEntry, estimator_specs
from estimators.examples import minimal_command, minimal_python
from estimators.plugins import build_estimator, run_estimator
from flight_interface.calibration import CalibrationProducts
from flight_interface.measurements import DescentMeasurements
from simulator.calibration import simulate_flat_field

EXAMPLES = Path(minimal_python.__file__).parent
VELOCITY = (12.0, -7.0, -72.0)
IMU_BIAS = np.array([3.0, -2.0, 0.0])
pytestmark = pytest.mark.slow          # interpreters start (the commands and the isolated callable)


def docstring_entry(module) -> dict:
    """The ``[[estimators]]`` entry in a module's docstring (its first indented block), as TOML data."""
    lines = module.__doc__.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("    [[estimators]]"))
    end = next(i for i in range(start, len(lines)) if lines[i] and not lines[i].startswith("    "))
    return tomllib.loads(textwrap.dedent("\n".join(lines[start:end])))["estimators"][0]


@pytest.fixture(scope="module")
def inputs(mer_a):
    descent = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(51)), np.random.default_rng(52),
                                        velocity_mps=VELOCITY)
    images = tuple(replace(m, imu_velocity_mps=m.imu_velocity_mps + IMU_BIAS) for m in descent.truth.images)
    measurements = DescentMeasurements(images, descent.truth.sun_direction_world)
    flat = simulate_flat_field(mer_a, 1, np.random.default_rng(53))
    return EstimatorInputs(images=tuple(descent.images), image_times_s=np.array([m.time_s for m in images]),
                           measurements=measurements, camera=mer_a, calibration=CalibrationProducts(flat, "calibrated"))


def specs(**changes):
    """The two examples' entries as a campaign reads them (``{config_dir}`` = the examples' directory),
    plus the python one isolated in its own process."""
    entries = [docstring_entry(minimal_python), docstring_entry(minimal_command)]
    for entry in entries:
        entry.setdefault("parameters", {}).update(changes)
    adapter = TypeAdapter(EstimatorEntry)
    validated = [adapter.validate_python(entry, context={"base_dir": EXAMPLES}) for entry in entries]
    python, command = estimator_specs(validated, {}, "examples")
    return [python, replace(python, name="imu_only_isolated", isolate=True), command,
            *(replace(command, name=f"imu_only_{kind}", image_format=kind) for kind in ("png", "raw"))]


def test_each_example_answers_the_imu_velocity_with_its_stated_uncertainty(inputs):
    last = inputs.measurements.images[-1].imu_velocity_mps
    assert last[0] == pytest.approx(VELOCITY[0] + 3.0) and last[1] == pytest.approx(VELOCITY[1] - 2.0)
    answers = []
    for spec in specs(imu_bias_sigma_mps=1.5):
        run = run_estimator(spec.name, build_estimator(spec), inputs, max_horizontal_speed_mps=129.2)
        assert run.failure == "" and run.output is not None, run.error
        output = run.output
        assert output.valid and output.reason == "ok", spec.name
        assert (output.velocity_east_mps, output.velocity_north_mps) == (float(last[0]), float(last[1]))
        assert output.velocity_uncertainty_mps == pytest.approx(1.5 * math.sqrt(2.0))
        assert len(output.features) == 3 and all(f["status"] == "ok" for f in output.features)
        answers.append(output)
    # in process, isolated and as a program on npy, PNG and raw files: the same answer, every bit
    assert all(answer == answers[0] for answer in answers[1:])
    # a lit image: its flat-fielded mean is well above the 20 DN offset and inside the 12-bit range
    assert all(100.0 < f["brightness_dn"] < 4095.0 and f["contrast_dn"] > 0 for f in answers[0].features)


def test_each_example_declines_dark_images(inputs, mer_a):
    dark = tuple(np.full(mer_a.binned_shape, int(mer_a.electronics.adc_offset_dn), np.uint16) for _ in inputs.images)
    for spec in specs():
        run = run_estimator(spec.name, build_estimator(spec), replace(inputs, images=dark))
        assert run.output is not None and not run.output.valid and run.output.reason == "no_signal", run.error
