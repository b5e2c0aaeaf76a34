"""`campaign sensitivity` on a small real campaign whose answers are known from physics:

- the velocity error of a valid velocity is dominated by the attitude-knowledge error (a tilt bias b gives
  e = V tan b, V the descent rate: docs/estimators.md, "The error statistic"), so the top-ranked input for
  the error is an attitude draw (a bias component or the total attitude error it makes), well above noise;
- on a site with a near-textureless class beside a normal one, the class decides validity: the class is the
  top-ranked input for ``valid`` and the only one distinguishable from noise among the first three.
"""
from __future__ import annotations

import pandas as pd
import pytest

from service_campaigns import REPO, run_campaign

pytestmark = [pytest.mark.slow, pytest.mark.cluster]

BLAND = "{ albedo_relative_spread = 0.003, crater_density_per_km2 = 0.0, rms_slope_deg = 0.5 }"
"""sitedata/examples/bland_ground.toml's near-textureless gcp ground."""
SITE = f"""
[site]
name = "Gusev"
camera = "{REPO}/sitedata/cameras/mer_a.toml"
trajectory_set = "{REPO}/sitedata/trajectories/gusev.parquet"

[site.sun]
azimuth_deg = 268.0
elevation_deg = 57.1
heliocentric_distance_au = 1.478

[[site.classes]]
name = "gcp"
ellipse_fraction = 0.5
cases = 40
terrain = {{ kind = "synthetic", preset = "gcp", seed = 4101 }}

[[site.classes]]
name = "bland"
ellipse_fraction = 0.5
cases = 40
terrain = {{ kind = "synthetic", preset = "gcp", seed = 4101, overrides = {BLAND} }}
"""
ATTITUDE_INPUTS = ("sensor_attitude_bias_", "sensor_attitude_error_")


@pytest.fixture(scope="module")
def analysed(tmp_path_factory, warm_scheduler):
    """The 80-case campaign (on the test process's warm two-worker cluster, ``warm_scheduler`` in
    tests/conftest.py) and its `campaign sensitivity` run."""
    directory = tmp_path_factory.mktemp("sensitivity")
    campaign = directory / "two_classes.toml"
    campaign.write_text(SITE)
    store = directory / "store"
    submitted = run_campaign("submit", campaign, "--scheduler", warm_scheduler, "--no-progress", "--output", store)
    assert submitted.returncode == 0, submitted.stderr
    result = run_campaign("sensitivity", store, "--resamples", "100")
    return store, result


def test_runs_and_writes_its_files(analysed):
    """Slow by design (the module's ``analysed`` fixture, about 110 s in a loaded suite run, is paid by this
    first test): 80 cases, since the physics checks below rank inputs against resampled noise."""
    store, result = analysed
    assert result.returncode == 0, result.stderr
    assert (store / "sensitivity.parquet").is_file()
    assert (store / "sensitivity_dimes.png").stat().st_size > 10_000
    assert (store / "sensitivity_top2_dimes.png").stat().st_size > 10_000
    table = pd.read_parquet(store / "sensitivity.parquet")
    assert set(table["output"]) == {"valid", "velocity_error_mps"}      # no false-valid case: nothing to rank
    assert "false_valid: the same value (0)" in result.stdout
    assert ((table["low"] <= table["index"] + 1e-9) & (table["index"] <= table["high"] + 1e-9)).all()


def test_attitude_error_dominates_the_velocity_error(analysed):
    store, _ = analysed
    table = pd.read_parquet(store / "sensitivity.parquet")
    error = table[table["output"] == "velocity_error_mps"].sort_values("rank")
    top = error.iloc[0]
    assert top["input"].startswith(ATTITUDE_INPUTS), error.head(5)
    assert not top["noise"] and top["p_value"] < 0.01
    # well above every input that is not an attitude draw
    others = error[~error["input"].str.startswith(ATTITUDE_INPUTS) & ~error["input"].str.startswith("sensor_attitude_random")]
    assert top["low"] > others["index"].max() - 0.02, error.head(8)


def test_bland_class_decides_validity(analysed):
    store, _ = analysed
    table = pd.read_parquet(store / "sensitivity.parquet")
    valid = table[table["output"] == "valid"].sort_values("rank")
    assert valid.iloc[0]["input"] == "class_name" and valid.iloc[0]["categorical"]
    assert not valid.iloc[0]["noise"]
    assert valid.iloc[1:]["noise"].all(), valid.head(5)
    assert valid.iloc[0]["low"] > valid.iloc[1]["index"]
