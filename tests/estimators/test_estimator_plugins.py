"""Pluggable estimators: the output contract, an external command (a small Python script run as a
program) and Python callables plugged in, and every way of breaking the contract giving that
estimator a clear failed result (never an exception for the campaign): writes into the read-only
inputs, ``sys.exit``, ``KeyboardInterrupt``, implausible answers."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from dimes_velocity import DimesEstimator
from dimes_velocity.config import EstimatorConfig
from estimators.contract import (
    ContractViolation,
    EstimatorInputs,
    ImplausibleOutput,
    check_plausible,
    read_only_inputs,
    validate_output,
)
from estimators.entries import EstimatorSpec
from estimators.phase_correlation import estimate as phase_correlation
from estimators.plugins import build_estimator, run_estimator
from flight_interface.calibration import CalibrationProducts
from simulator.calibration import simulate_flat_field

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"
SCRIPT = PLUGINS / "command_estimator.py"
BIAS = [2.5, -1.5]


@pytest.fixture(autouse=True)
def plugins_importable(monkeypatch):
    """tests/plugins on sys.path and PYTHONPATH (isolated callables run in a fresh interpreter)."""
    monkeypatch.syspath_prepend(str(PLUGINS))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGINS), str(PLUGINS.parents[1]),
                                                                   os.environ.get("PYTHONPATH", "")])))


@pytest.fixture(scope="module")
def inputs(mer_a):
    descent = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(41)), np.random.default_rng(42))
    flat = simulate_flat_field(mer_a, 1, np.random.default_rng(43))
    return EstimatorInputs(images=tuple(descent.images),
                           image_times_s=np.array([m.time_s for m in descent.truth.images]),
                           measurements=descent.truth, camera=mer_a,
                           calibration=CalibrationProducts(flat, "calibrated: 1 frames"))


def _expected_velocity(inputs):
    last = inputs.measurements.images[-1].imu_velocity_mps
    return last[0] - BIAS[0], last[1] - BIAS[1]


def _command(mode: str, timeout_s: float = 60.0, **options) -> EstimatorSpec:
    argv = ("{python}", str(SCRIPT), mode, "{measurements}", "{flat_field}", "{parameters}", "{output}", "{images}")
    return EstimatorSpec(name=f"cmd_{mode}", kind="command", argv=argv, timeout_s=timeout_s,
                         parameters=options.pop("parameters", {"bias": BIAS}), **options)


# --- the output contract ----------------------------------------------------------------------------
GOOD = {"velocity_east_mps": 1.0, "velocity_north_mps": -2.0, "valid": True, "reason": "ok"}


@pytest.mark.parametrize("change, message", [
    ({"valid": None}, "field 'valid' must be true or false"),
    ({"valid": "yes"}, "field 'valid' must be true or false"),
    ({"velocity_east_mps": "12"}, "field 'velocity_east_mps' must be a number"),
    ({"velocity_north_mps": math.nan}, "field 'velocity_north_mps' must be finite when valid"),
    ({"reason": ""}, "field 'reason' must be a non-empty string"),
    ({"reason": "probably fine"}, "field 'reason' must be 'ok' when valid"),
    ({"features": {"a": 1}}, "field 'features' must be a list of objects"),
    ({"features": [{"correlation": "high"}]}, "features[0].correlation must be a number"),
])
def test_contract_violations_name_the_field(change, message):
    with pytest.raises(ContractViolation) as error:
        validate_output({**GOOD, **change})
    assert message in str(error.value)


def test_missing_fields_are_named_and_an_invalid_result_may_have_no_velocity():
    with pytest.raises(ContractViolation, match="missing fields 'valid', 'reason'"):
        validate_output({"velocity_east_mps": 1.0, "velocity_north_mps": 2.0})
    output = validate_output({"velocity_east_mps": None, "velocity_north_mps": None, "valid": False,
                              "reason": "low_texture", "timings": {"total_ms": 3}})
    assert not output.valid and output.velocity_east_mps is None and output.reason == "low_texture"


# --- an external command ----------------------------------------------------------------------------
@pytest.mark.parametrize("image_format, flat_field_format", [("png", "npy"), ("npy", "tiff"), ("raw", "fits")])
def test_command_estimator_reads_the_files_and_its_answer_is_kept(inputs, image_format, flat_field_format):
    spec = _command("ok", image_format=image_format, flat_field_format=flat_field_format)
    run = run_estimator(spec.name, build_estimator(spec), inputs)
    assert run.error == "" and run.output.valid and run.output.reason == "ok"
    assert (run.output.velocity_east_mps, run.output.velocity_north_mps) == pytest.approx(_expected_velocity(inputs))
    brightness = [feature["brightness_dn"] for feature in run.output.features]
    assert brightness == pytest.approx([float(np.mean(image)) for image in inputs.images], rel=1e-12)
    flat_means = [feature["contrast_dn"] for feature in run.output.features]
    assert flat_means == pytest.approx([float(np.mean(inputs.calibration.flat_field))] * 3, rel=1e-6)


@pytest.mark.parametrize("mode, message", [
    ("missing", "missing field 'reason'"),
    ("wrong_type", "field 'valid' must be true or false; got str 'yes'"),
    ("exit", "exit status 3: flight estimator: cannot lock the camera model"),
    ("no_output", "wrote no result file"),
    ("bad_json", "result file is not valid JSON"),
    ("segfault", "killed by signal SIGSEGV"),
])
def test_command_contract_violations_give_a_clear_failed_result(inputs, mode, message):
    spec = _command(mode)
    run = run_estimator(spec.name, build_estimator(spec), inputs)
    assert run.output is None
    assert run.error.startswith(f"estimator cmd_{mode}: ") and message in run.error, run.error


def test_command_timeout_kills_the_program_and_what_it_started(inputs, tmp_path):
    pid_file = tmp_path / "child.pid"
    spec = _command("sleep_with_child", timeout_s=1.5, parameters={"pid_file": str(pid_file)})
    started = time.perf_counter()
    run = run_estimator(spec.name, build_estimator(spec), inputs)
    assert run.output is None and "timeout: no result within 1.5 s" in run.error
    assert time.perf_counter() - started < 15.0
    child = int(pid_file.read_text())
    for _ in range(50):                       # SIGKILL of the process group: the grandchild goes too
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail(f"grandchild {child} survived the timeout")


# --- Python callables -------------------------------------------------------------------------------
def test_python_callable_in_process_and_isolated_give_the_same_answer(inputs):
    answers = []
    for isolate in (False, True):
        spec = EstimatorSpec(name="imu", kind="python", callable="python_estimators:imu_minus_bias",
                             isolate=isolate, parameters={"bias": BIAS})
        run = run_estimator(spec.name, build_estimator(spec), inputs)
        assert run.error == "" and run.output.valid, run.error
        assert (run.output.velocity_east_mps, run.output.velocity_north_mps) == pytest.approx(_expected_velocity(inputs))
        answers.append(run.output)
    assert answers[0].features == answers[1].features       # images and flat field went through the files intact


@pytest.mark.parametrize("target, isolate, timeout_s, message", [
    ("python_estimators:raises", False, 60.0,
     "crashed: RuntimeError: flight code assertion: attitude quaternion not normalised"),
    ("python_estimators:forgets_valid", False, 60.0, "missing field 'valid'"),
    ("python_estimators:forgets_valid", True, 60.0, "exit status 1: contract violation: missing field 'valid'"),
    ("python_estimators:hangs", True, 2.0, "timeout: no result within 2 s"),
])
def test_python_callable_violations_give_a_clear_failed_result(inputs, target, isolate, timeout_s, message):
    spec = EstimatorSpec(name="plugin", kind="python", callable=target, isolate=isolate, timeout_s=timeout_s)
    run = run_estimator(spec.name, build_estimator(spec), inputs)
    assert run.output is None and run.error.startswith("estimator plugin: ") and message in run.error, run.error


def test_reference_behind_the_contract_matches_the_reference_estimator(inputs):
    from dimes_velocity import DimesEstimator

    spec = EstimatorSpec(name="dimes", kind="reference", parameters={"features_per_pair": 3})
    run = run_estimator(spec.name, build_estimator(spec), inputs)
    from dimes_velocity.config import EstimatorConfig

    direct = DimesEstimator(inputs.camera, EstimatorConfig(features_per_pair=3),
                            inputs.calibration.flat_field).estimate(list(inputs.images), inputs.measurements)
    assert run.output.valid == direct.valid and run.output.reason == direct.reason
    assert run.output.velocity_east_mps == direct.velocity_east_mps
    assert len(run.output.features) == len(direct.features)


# --- isolation: read-only inputs, anything raised, implausible answers ------------------------------
@pytest.mark.parametrize("target, failure, message", [
    ("python_estimators:halves_image", "estimator_failed", "crashed: ValueError: output array is read-only"),
    ("python_estimators:scales_flat", "estimator_failed", "crashed: ValueError: output array is read-only"),
    ("python_estimators:changes_imu", "estimator_failed", "crashed: ValueError: assignment destination is read-only"),
    ("python_estimators:exits", "estimator_failed", "crashed: SystemExit(3)"),
    ("python_estimators:interrupts", "estimator_failed", "crashed: KeyboardInterrupt()"),
    ("python_estimators:too_fast", "implausible", "horizontal speed 1e+30 m/s of a valid answer is not below the "
                                                  "bound 130 m/s"),
    ("python_estimators:negative_uncertainty", "implausible",
     "field 'velocity_uncertainty_mps' must be finite and >= 0 when given; got -1.0"),
])
def test_a_plugin_that_writes_its_inputs_exits_or_answers_implausibly_fails_only_its_own_result(
        inputs, target, failure, message):
    reference = build_estimator(EstimatorSpec(name="dimes", kind="reference"))
    before = run_estimator("dimes", reference, inputs, 130.0)
    kept = [np.array(image) for image in inputs.images], np.array(inputs.calibration.flat_field)
    imu = np.array(inputs.measurements.images[-1].imu_velocity_mps)
    spec = EstimatorSpec(name="plugin", kind="python", callable=target, parameters={"bias": BIAS})
    run = run_estimator(spec.name, build_estimator(spec), inputs, 130.0)
    assert run.output is None and run.failure == failure, run
    assert run.error.startswith("estimator plugin: ") and message in run.error, run.error
    assert all(np.array_equal(image, copy) for image, copy in zip(inputs.images, kept[0]))
    assert np.array_equal(inputs.calibration.flat_field, kept[1])
    assert np.array_equal(inputs.measurements.images[-1].imu_velocity_mps, imu)
    after = run_estimator("dimes", reference, inputs, 130.0)
    assert after.error == "" and repr(after.output) == repr(before.output)      # repr: NaN features equal


def test_the_reference_and_the_example_run_on_read_only_inputs_with_unchanged_answers(inputs):
    """Both only read their inputs: on read-only inputs (as every estimator gets them) their answers are
    those of a direct call on writable inputs, and plausible."""
    writable = EstimatorInputs(images=tuple(np.array(image) for image in inputs.images),
                               image_times_s=np.array(inputs.image_times_s), measurements=inputs.measurements,
                               camera=inputs.camera, calibration=CalibrationProducts(
                                   np.array(inputs.calibration.flat_field), "calibrated: 1 frames"))
    direct = DimesEstimator(inputs.camera, EstimatorConfig(), writable.calibration.flat_field).estimate(
        list(writable.images), writable.measurements)
    run = run_estimator("dimes", build_estimator(EstimatorSpec(name="dimes", kind="reference")), inputs, 130.0)
    assert run.error == "" and run.output.valid == direct.valid and run.output.valid
    assert (run.output.velocity_east_mps, run.output.velocity_north_mps) == (direct.velocity_east_mps,
                                                                             direct.velocity_north_mps)
    spec = EstimatorSpec(name="pc", kind="python", callable="estimators.phase_correlation:estimate")
    run = run_estimator(spec.name, build_estimator(spec), inputs, 130.0)
    assert run.error == "" and repr(run.output) == repr(validate_output(phase_correlation(writable)))


def test_read_only_inputs_are_views_and_plausibility_bounds_only_valid_answers(inputs):
    frozen = read_only_inputs(inputs)
    assert all(np.shares_memory(a, b) and not a.flags.writeable for a, b in zip(frozen.images, inputs.images))
    assert not frozen.calibration.flat_field.flags.writeable and inputs.calibration.flat_field.flags.writeable
    assert not frozen.measurements.images[0].attitude_quat.flags.writeable
    invalid = validate_output({"velocity_east_mps": 1e30, "velocity_north_mps": 0.0, "valid": False, "reason": "x"})
    assert check_plausible(invalid, 130.0) is invalid
    with pytest.raises(ImplausibleOutput, match="not below the bound 130 m/s"):
        check_plausible(validate_output({**GOOD, "velocity_east_mps": 130.0, "velocity_north_mps": 0.0}), 130.0)
    with pytest.raises(ImplausibleOutput, match="must be finite when valid"):
        validate_output({**GOOD, "velocity_east_mps": math.inf})
