"""Set-up errors are not case failures: building an estimator that cannot be loaded here (a module that
does not import, a module whose import raises, bad reference parameters, a command program that is
missing or not executable) raises EstimatorSetupError naming the estimator, the error and the fix; a
program that cannot be started during a case raises it from run_estimator; an exception of the plug-in
*during* a case stays that estimator's failed run. And what the campaign ships of a plug-in: its
top-level module or package, never the project's or an installed package."""
from __future__ import annotations

import io
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from campaign.run.plugin_setup import shipped_code
from estimators.contract import EstimatorInputs
from estimators.entries import EstimatorSpec
from estimators.plugins import EstimatorSetupError, build_estimator, module_root, run_estimator

REPO = Path(__file__).resolve().parents[2]

OK_ANSWER = ('def estimate(inputs):\n    return {"velocity_east_mps": 1.0, "velocity_north_mps": 2.0, '
             '"valid": True, "reason": "ok"}\n')


@pytest.fixture
def plugin_dir(tmp_path, monkeypatch):
    """A directory on sys.path with a module, a package and a module whose import raises."""
    (tmp_path / "h2_single.py").write_text(OK_ANSWER)
    package = tmp_path / "h2_package"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "est.py").write_text("from ..helper import ANSWER\n\ndef estimate(inputs):\n    return ANSWER\n")
    (package / "helper.py").write_text('ANSWER = {"velocity_east_mps": 0.5, "velocity_north_mps": 0.0, '
                                       '"valid": True, "reason": "ok"}\n')
    (package / "__pycache__").mkdir()
    (package / "__pycache__" / "junk.pyc").write_bytes(b"x")
    (tmp_path / "h2_needs_licence.py").write_text("import h2_licence_client_not_installed\n" + OK_ANSWER)
    (tmp_path / "h2_raises_on_import.py").write_text('raise RuntimeError("licence server unreachable")\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(REPO))      # the project for isolated plug-ins, never tmp_path
    yield tmp_path
    for name in [name for name in sys.modules if name.startswith(("h2_single", "h2_package", "h2_needs", "h2_raises"))]:
        del sys.modules[name]


@pytest.mark.parametrize("target, error", [
    ("h2_no_such_module:estimate", "ModuleNotFoundError: No module named 'h2_no_such_module'"),
    ("h2_needs_licence:estimate", "ModuleNotFoundError: No module named 'h2_licence_client_not_installed'"),
    ("h2_raises_on_import:estimate", "RuntimeError: licence server unreachable"),
    ("h2_single:no_such_function", "AttributeError"),
])
@pytest.mark.parametrize("isolate", [False, True])
def test_python_plugin_that_does_not_load_is_a_setup_error(plugin_dir, target, error, isolate):
    spec = EstimatorSpec(name="mine", kind="python", callable=target, isolate=isolate)
    with pytest.raises(EstimatorSetupError) as raised:
        build_estimator(spec)
    line = str(raised.value)
    assert "\n" not in line and line.startswith("estimator mine: cannot be set up: ") and error in line, line
    assert f"make {target.split(':')[0]!r} and what it imports importable on every worker" in line


def test_reference_with_bad_parameters_is_a_setup_error():
    with pytest.raises(EstimatorSetupError, match="^estimator ref: cannot be set up: .*min_correlation"):
        build_estimator(EstimatorSpec(name="ref", kind="reference", parameters={"min_correlation": "high"}))


def test_command_program_missing_or_not_executable_is_a_setup_error(tmp_path):
    script = tmp_path / "flight.sh"
    script.write_text("#!/bin/sh\nexit 0\n")
    script.chmod(0o644)
    for program, error in ((str(tmp_path / "missing"), "FileNotFoundError"), (str(script), "PermissionError")):
        spec = EstimatorSpec(name="flight", kind="command", argv=(program, "{output}"))
        with pytest.raises(EstimatorSetupError) as raised:
            build_estimator(spec)
        assert str(raised.value).startswith(f"estimator flight: cannot be set up: {error}: {program!r}"), raised.value
        assert "with execute permission on every worker" in str(raised.value)
    script.chmod(0o755)
    assert build_estimator(EstimatorSpec(name="flight", kind="command", argv=(str(script), "{output}"))).argv[0] == str(script)


@pytest.fixture(scope="module")
def inputs(mer_a):
    descent = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(41)), np.random.default_rng(42))
    return EstimatorInputs(images=tuple(descent.images), image_times_s=np.array([m.time_s for m in descent.truth.images]),
                           measurements=descent.truth, camera=mer_a)


def test_program_that_cannot_start_during_a_case_raises_but_its_crash_is_a_failed_run(tmp_path, inputs):
    """Removed after the build: the case cannot start it (set-up, raised); a program that starts and exits
    non-zero is that case's failed run (recorded, not raised)."""
    script = tmp_path / "flight.sh"
    script.write_text("#!/bin/sh\necho 'cannot lock the camera model' >&2\nexit 3\n")
    script.chmod(0o755)
    estimator = build_estimator(EstimatorSpec(name="flight", kind="command", argv=(str(script), "{output}")))
    run = run_estimator("flight", estimator, inputs)
    assert run.output is None and run.failure == "estimator_failed"
    assert run.error == "estimator flight: exit status 3: cannot lock the camera model"
    script.unlink()
    with pytest.raises(EstimatorSetupError, match=r"^estimator flight: cannot be set up: cannot start .*flight\.sh"):
        run_estimator("flight", estimator, inputs)


def test_isolated_plugin_gets_its_module_root_on_the_child_path(plugin_dir, inputs):
    """The child interpreter finds a package plug-in only through the root given to it (the test process's
    PYTHONPATH does not hold plugin_dir): the answer is the package helper's."""
    spec = EstimatorSpec(name="pkg", kind="python", callable="h2_package.sub.est:estimate", isolate=True)
    estimator = build_estimator(spec)
    assert estimator.python_path == (str(plugin_dir),)
    build_estimator(EstimatorSpec(name="one", kind="python", callable="h2_single:estimate"))
    assert module_root("h2_package.sub.est") == (str(plugin_dir),) and module_root("h2_single") == (str(plugin_dir),)
    run = run_estimator("pkg", estimator, inputs)
    assert run.error == "" and (run.output.velocity_east_mps, run.output.velocity_north_mps) == (0.5, 0.0)


def test_shipped_code_is_the_top_level_module_or_package(plugin_dir):
    specs = [EstimatorSpec(name="one", kind="python", callable="h2_single:estimate"),
             EstimatorSpec(name="two", kind="python", callable="h2_package.sub.est:estimate"),
             EstimatorSpec(name="three", kind="python", callable="h2_package.helper:ANSWER"),
             EstimatorSpec(name="pc", kind="python", callable="estimators.phase_correlation:estimate"),
             EstimatorSpec(name="installed", kind="python", callable="numpy.linalg:norm"),
             EstimatorSpec(name="missing", kind="python", callable="h2_no_such_module:estimate"),
             EstimatorSpec(name="dimes", kind="reference")]
    shipped = {code.module: code for code in shipped_code(specs)}
    assert sorted(shipped) == ["h2_package", "h2_single"]
    package = shipped["h2_package"]
    assert package.estimators == ("two", "three") and package.imports == ("h2_package.helper", "h2_package.sub.est")
    assert sorted(zipfile.ZipFile(io.BytesIO(package.data)).namelist()) == [
        "h2_package/__init__.py", "h2_package/helper.py", "h2_package/sub/__init__.py", "h2_package/sub/est.py"]
    single = zipfile.ZipFile(io.BytesIO(shipped["h2_single"].data))
    assert single.namelist() == ["h2_single.py"] and single.read("h2_single.py").decode() == OK_ANSWER
