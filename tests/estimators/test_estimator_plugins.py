"""Pluggable estimators: the output contract, an external command (a small Python script run as a
program) and Python callables plugged in, and every way of breaking the contract giving that
estimator a clear failed result (never an exception for the campaign)."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from estimators.contract import ContractViolation, EstimatorInputs, validate_output
from estimators.plugins import build_estimator, run_estimator
from estimators.registry import EstimatorSpec
from flight_interface.calibration import CalibrationProducts
from simulator.calibration import simulate_flat_field
from simulator.synthetic_descent import constant_velocity_descent, random_ground

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
