"""`campaign check-estimators FILE [--cases N]`: every declared estimator on planned cases on the driver
and on a worker of a real one-worker cluster; exit 1 with the violations of broken plug-ins (an answer
breaking the contract, a module that does not import, an input changed behind the read-only view, a
worker answer that differs from the driver's), exit 0 on the shipped example; no store written."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from campaign.cli import main
from service_campaigns import REPO, campaign_file, file_tree

PLUGINS = REPO / "tests" / "plugins"
YES_ESTIMATOR = '''import json, sys
json.dump({"velocity_east_mps": 1.0, "velocity_north_mps": 0.0, "valid": "yes", "reason": "ok"}, open(sys.argv[1], "w"))
'''


def _check(directory: Path, *args) -> subprocess.CompletedProcess:
    """The command run in ``directory`` (so a store written by mistake would land there)."""
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PLUGINS), str(REPO)])}
    return subprocess.run([sys.executable, "-m", "campaign.cli", "check-estimators", *map(str, args)], cwd=directory,
                          capture_output=True, text=True, timeout=600, env=environment)


def _section(stdout: str, name: str) -> str:
    return stdout.split(f"\nestimator {name} (")[1].split("\nestimator ")[0]


@pytest.mark.cluster
@pytest.mark.slow
def test_broken_plugins_exit_1_with_their_violations_and_the_reference_passes(tmp_path):
    script = tmp_path / "yes_estimator.py"
    script.write_text(YES_ESTIMATOR)
    entries = [("dimes", 'kind = "reference"'), ("yes_man", f'kind = "command"\nargv = ["{sys.executable}", "{script}", "{{output}}"]'),
               ("missing", 'kind = "python"\ncallable = "h2_no_such_plugin_module:estimate"'),
               ("sneaky", 'kind = "python"\ncallable = "python_estimators:writes_through_base"'),
               ("two_faced", 'kind = "python"\ncallable = "python_estimators:differs_on_worker"')]
    extra = '[estimator]\nflat_field = "none"\n' + "".join(f'\n[[estimators]]\nname = "{name}"\n{body}\n' for name, body in entries)
    config = campaign_file(tmp_path, {"gcp": 1, "gdcp": 1, "gkep": 0}, extra=extra)
    before = file_tree(tmp_path)
    result = _check(tmp_path, config, "--cases", 1)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    assert file_tree(tmp_path) == before                                   # no store, nothing written
    out = result.stdout
    assert "5 estimators on 1 planned cases (0), on the driver and on the worker tcp://127.0.0.1:" in out
    dimes = _section(out, "dimes")
    assert "  PASS" in dimes and "images: 3 x (256, 1024) uint16, DN" in dimes and "image_times_s: (3,) float64, s" in dimes
    assert "imu_velocity_mps: (3,) float64, m/s" in dimes and "calibration.flat_field: none" in dimes
    assert dimes.count("case 0 driver: valid") == 1 and dimes.count("case 0 worker: valid") == 1
    yes_man = _section(out, "yes_man")
    assert "FAIL: 2 violations" in yes_man and "as files: images png" in yes_man
    assert yes_man.count("field 'valid' must be true or false; got str 'yes'") == 4       # answer + violation, x2 sides
    missing = _section(out, "missing")
    assert "FAIL: 2 violations" in missing
    assert "violation: set-up on the driver: estimator missing: cannot be set up: ModuleNotFoundError: No module named " \
           "'h2_no_such_plugin_module'" in missing
    assert "violation: set-up on the worker tcp://127.0.0.1:" in missing
    sneaky = _section(out, "sneaky")
    assert "FAIL: 2 violations" in sneaky and sneaky.count("changed its inputs images[0]") == 2
    two_faced = _section(out, "two_faced")
    assert "FAIL: 1 violations" in two_faced and "case 0: driver and worker answers differ" in two_faced
    assert out.rstrip().endswith("7 contract violations")


@pytest.mark.cluster
@pytest.mark.slow
def test_shipped_example_passes(tmp_path, warm_scheduler):
    """On a worker of the test process's warm cluster (``warm_scheduler``, tests/conftest.py; a fresh worker's
    set-up is what the broken plug-ins above test)."""
    before = file_tree(tmp_path)
    result = _check(tmp_path, REPO / "sitedata" / "examples" / "compare_estimators.toml", "--cases", 1,
                    "--scheduler", warm_scheduler)
    assert result.returncode == 0, result.stdout + result.stderr
    assert file_tree(tmp_path) == before
    assert result.stdout.count("  PASS") == 2 and result.stdout.rstrip().endswith("all estimators keep the contract")
    for name in ("dimes", "phase_correlation"):
        lines = [line for line in _section(result.stdout, name).splitlines() if line.startswith("  case ")]
        assert len(lines) == 2 and lines[0].split(": ", 1)[1].split("  [")[0] == lines[1].split(": ", 1)[1].split("  [")[0]


def test_cases_must_be_positive(capsys):
    assert main(["check-estimators", "x.toml", "--cases", "0"]) == 2
    assert capsys.readouterr().err.strip() == "campaign: error: --cases = 0 is not allowed; allowed: an integer >= 1"
