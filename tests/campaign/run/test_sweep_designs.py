"""Designed sweeps (``[sweep] mode = "sobol"`` / ``"morris"``): their points, their validation at the edge,
repeated configurations sharing one store, and a small Sobol sweep run end to end on a real cluster."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from campaign.cli import main
from campaign.configuration.sweep_file import load_sweep
from campaign.run.sweep import distinct_points
from config_tables.errors import ConfigError

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"
TINY_CASES = "[sweep.cases]\ngcp = 2\ngdcp = 1\ngkep = 0\n"      # 3 cases per point
THREE_AXES = ('"sensors.attitude_bias_sigma_deg" = [0.25, 2.0]\n'
              '"scene.off_nominal.dust_particle_count" = [0, 100]\n'
              '"scene.off_nominal.angular_rate_multiplier" = [1.0, 40.0]\n')


def _sweep_file(directory: Path, sweep_lines: str, axes: str = THREE_AXES) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "design.toml"
    path.write_text(f'[sweep]\nbase = "{GUSEV}"\n{sweep_lines}\n{TINY_CASES}\n[axes]\n{axes}')
    return path


def test_sobol_and_morris_point_counts(tmp_path):
    """Saltelli without second order: N (D + 2) points; Morris: N (D + 1); every value inside its range."""
    sobol = load_sweep(_sweep_file(tmp_path / "s", 'mode = "sobol"\nsamples = 4'))
    assert len(sobol.points) == 4 * (3 + 2) and sobol.design_samples == 4
    morris = load_sweep(_sweep_file(tmp_path / "m", 'mode = "morris"\nsamples = 3'))
    assert len(morris.points) == 3 * (3 + 1)
    for point in sobol.points + morris.points:
        assert 0.25 <= point.values["sensors.attitude_bias_sigma_deg"] <= 2.0
        assert point.values["scene.off_nominal.dust_particle_count"] in range(0, 101)
        assert 1.0 <= point.values["scene.off_nominal.angular_rate_multiplier"] <= 40.0


@pytest.mark.parametrize("sweep_lines, axes, expected", [
    ('mode = "sobol"', THREE_AXES, r"sweep.samples = None; allowed: an integer >= 2 with mode \"sobol\""),
    ('mode = "grid"\nsamples = 4', THREE_AXES, r"sweep.samples = 4; allowed: .* none with mode \"grid\""),
    ('mode = "sobol"\nsamples = 6', THREE_AXES, "allowed: a power of two"),
    ('mode = "sobol"\nsamples = 4', '"sensors.attitude_bias_sigma_deg" = [0.25, 1.0, 2.0]\n',
     r"axes.sensors.attitude_bias_sigma_deg = \[0.25, 1.0, 2.0\]: a designed sweep .* allowed: \[low, high\]"),
    ('mode = "morris"\nsamples = 4', '"sensors.attitude_bias_sigma_deg" = [2.0, 0.25]\n', "low < high"),
])
def test_bad_design_is_one_line_naming_the_file(tmp_path, sweep_lines, axes, expected):
    path = _sweep_file(tmp_path, sweep_lines, axes)
    with pytest.raises(ConfigError, match=expected) as raised:
        load_sweep(path)
    assert str(path) in str(raised.value) and "\n" not in str(raised.value)


def test_repeated_configurations_share_one_store(tmp_path):
    """An integer axis of two values sampled 12 times: 12 design rows, 2 configurations, 2 stores run."""
    spec = load_sweep(_sweep_file(tmp_path, 'mode = "sobol"\nsamples = 4',
                                  '"scene.off_nominal.dust_particle_count" = [0, 1]\n'))
    assert len(spec.points) == 12
    stores = {point.config.output_dir for point in spec.points}
    assert len(stores) == 2
    assert {point.config.output_dir for point in distinct_points(spec)} == stores
    assert len(distinct_points(spec)) == 2


@pytest.mark.cluster
@pytest.mark.slow
def test_small_sobol_sweep_end_to_end(tmp_path, capsys, warm_scheduler):
    """Three axes, N = 2: 10 points of 3 cases on a 2-worker cluster (the test process's warm one,
    ``warm_scheduler`` in tests/conftest.py); the sweep prints S1 and ST with intervals for every axis (or says
    why an outcome has nothing to attribute) and writes them to design_indices.csv."""
    path = _sweep_file(tmp_path, 'mode = "sobol"\nsamples = 2')
    out = tmp_path / "out"
    code = main(["sweep", str(path), "--output", str(out), "--scheduler", warm_scheduler, "--no-progress"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "first-order S1 and total ST Sobol indices" in printed
    description = json.loads((out / "sweep.json").read_text())
    assert description["mode"] == "sobol" and description["design"] == {"samples": 2, "seed": 0}
    assert len(description["points"]) == 10
    indices = pd.read_csv(out / "design_indices.csv")
    analysed = set(indices["outcome"])
    for outcome in ("pct_valid", "false_valid", "error_mps"):
        assert outcome in analysed or f"dimes: {outcome}:" in printed
    for outcome in analysed:
        rows = indices[indices["outcome"] == outcome]
        assert set(rows["input"]) == {"sensors.attitude_bias_sigma_deg", "scene.off_nominal.dust_particle_count",
                                      "scene.off_nominal.angular_rate_multiplier"}
        assert set(rows["index"]) == {"S1", "ST"}
        assert (rows["low"] <= rows["value"]).all() and (rows["value"] <= rows["high"]).all()
    assert "Sobol indices" in (out / "sensitivity.md").read_text()
