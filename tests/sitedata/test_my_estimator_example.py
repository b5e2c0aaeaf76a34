"""sitedata/examples/my_estimator_gusev.toml, as is: `campaign check-estimators` and `campaign submit` accept
it (real subprocesses, a working directory that is not the checkout, no PYTHONPATH to the plug-in)."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "sitedata" / "examples" / "my_estimator_gusev.toml"


def _campaign(*arguments: str, cwd: Path) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHONPATH": str(REPO)}      # the project, not the plug-in's directory
    return subprocess.run([sys.executable, "-m", "campaign.cli", *arguments], cwd=cwd, env=environment,
                          capture_output=True, text=True, timeout=600)


def test_the_example_is_short():
    lines = [line for line in EXAMPLE.read_text().splitlines() if line.strip() and not line.startswith("#")]
    assert len(lines) <= 12, lines


def test_check_estimators_accepts_the_example(tmp_path, warm_scheduler):
    """On a worker of the test process's warm cluster (``warm_scheduler``, tests/conftest.py): its workers were
    started without the example's directory on their path either, so the plug-in runs there only if shipped."""
    done = _campaign("check-estimators", str(EXAMPLE), "--cases", "1", "--scheduler", warm_scheduler, cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "estimator mine (python: my_estimator:estimate)" in done.stdout
    assert "all estimators keep the contract" in done.stdout


def test_submit_runs_the_example(tmp_path):
    """Both estimators on every case; the plug-in's answer is the last image's IMU velocity with the stated
    uncertainty of its parameters (2 m/s), so its error is the simulated IMU error at the third image."""
    out = tmp_path / "out"
    done = _campaign("submit", str(EXAMPLE), "--cases-scale", "0.02", "--workers", "1", "--no-progress",
                     "--output", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    results = pd.read_parquet(out / "results.parquet")
    # 0.02 x (186, 112, 78) rounded half up: 4 + 2 + 2 cases, two estimators each
    assert sorted(results["estimator"].value_counts().items()) == [("dimes", 8), ("mine", 8)]
    mine = results[results["estimator"] == "mine"]
    assert mine["valid"].all()
    np.testing.assert_array_equal(mine["velocity_uncertainty_mps"], 2.0)
    for axis in ("east", "north"):
        error = mine[f"estimate_velocity_{axis}_mps"] - mine[f"truth_velocity_{axis}_mps"]
        np.testing.assert_allclose(error, mine[f"sensor_imu_velocity_error_image3_{axis}_mps"], atol=0.01)
