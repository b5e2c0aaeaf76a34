"""A refused configuration change says what changed: the differing fields old -> new, a changed input file's
or plug-in's bytes, and whether only some estimators changed (and why they are not run again alone)."""
import hashlib
import shutil
import sys
from pathlib import Path

import pytest

from campaign.configuration.campaign_file import load_campaign_config
from campaign.configuration.differences import configuration_changes, describe_change, only_estimators
from campaign.run.orchestrate import manifest_for
from campaign.run.planning import plan_campaign
from campaign.store.campaign_store import CampaignStore
from campaign.store.errors import StoreError

REPO = Path(__file__).resolve().parents[3]
PLUGIN = '''def estimate(inputs):
    """IMU velocity at the last image (m/s), with the stated uncertainty parameters["sigma"]."""
    last = inputs.measurements.images[-1].imu_velocity_mps
    return {"velocity_east_mps": float(last[0]), "velocity_north_mps": float(last[1]), "valid": True,
            "reason": "ok", "velocity_uncertainty_mps": inputs.parameters["sigma"]}
'''
ESTIMATORS = '''
[[estimators]]
name = "dimes"
kind = "reference"

[[estimators]]
name = "mine"
kind = "python"
path = "."
callable = "h32_differences_plugin:estimate"
parameters = {{ sigma = {sigma} }}
'''


@pytest.fixture
def campaign_dir(tmp_path, monkeypatch):
    """A directory with the plug-in module and a writer of campaign files built on the shipped Gusev site."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    (tmp_path / "h32_differences_plugin.py").write_text(PLUGIN)
    yield tmp_path
    sys.modules.pop("h32_differences_plugin", None)


def _manifest(directory: Path, name: str, extra: str = "", sigma: float = 2.0, base: str = "gusev") -> dict:
    path = directory / f"{name}.toml"
    path.write_text(f'base = "{base}"\n{extra}\n' + ESTIMATORS.format(sigma=sigma))
    return manifest_for(load_campaign_config(path, cases_scale=0.02))


def test_a_plugin_parameter_change_names_the_field_and_the_estimator(campaign_dir):
    old, new = _manifest(campaign_dir, "old"), _manifest(campaign_dir, "new", sigma=3.5)
    changes = configuration_changes(old, new)
    assert [str(change) for change in changes] == ["estimators[1].parameters.sigma (estimator mine): 2.0 -> 3.5"]
    assert only_estimators(changes) == {"mine"}
    text = describe_change(old, new)
    assert f"(configuration hash {old['config_hash'][:12]} -> {new['config_hash'][:12]})" in text
    assert "only the parameters or code of estimator mine changed" in text
    assert "not its rendered images" in text and "\n" not in text


def test_a_reference_parameter_touches_the_reference_entries_only(campaign_dir):
    old = _manifest(campaign_dir, "old")
    new = _manifest(campaign_dir, "new", extra="[estimator]\nmin_correlation = 0.8")
    changes = configuration_changes(old, new)
    assert [str(change) for change in changes] == ["estimator.min_correlation: 0.7 -> 0.8"]
    assert only_estimators(changes) == {"dimes"}


def test_a_change_of_the_cases_names_every_field_and_no_estimator(campaign_dir):
    old = _manifest(campaign_dir, "old")
    new = _manifest(campaign_dir, "new", extra="[sensors]\nimu_velocity_bias_sigma_mps = 3.0\n"
                    "[estimator]\nflat_field = \"none\"")
    changes = configuration_changes(old, new)
    assert [str(change) for change in changes] == ["sensors.imu_velocity_bias_sigma_mps: 2.0 -> 3.0",
                                                   'estimator.flat_field: "calibrated" -> "none"']
    assert only_estimators(changes) is None
    assert "only the parameters" not in describe_change(old, new)


def test_an_added_estimator_and_ignored_fields(campaign_dir):
    """An added estimator is named; what the hash ignores (case counts, output directory, [execution]) is not."""
    site = campaign_dir / "site.toml"
    site.write_text('base = "gusev"\n')
    old = manifest_for(load_campaign_config(site))
    new = _manifest(campaign_dir, "new", extra="[campaign]\noutput_dir = \"elsewhere\"\n[execution]\nretries = 3")
    assert [str(change) for change in configuration_changes(old, new)] == [
        "estimators.mine: (none) -> (added)"]


def test_a_changed_camera_file_is_named_by_its_bytes(campaign_dir):
    """Two copies of the Gusev site whose camera files differ by one byte: same tables, different files."""
    digests = {}
    for name, edited in (("a", False), ("b", True)):
        site_dir = campaign_dir / name
        shutil.copytree(REPO / "sitedata" / "cameras", site_dir / "cameras")
        camera = site_dir / "cameras" / "mer_a.toml"
        if edited:
            camera.write_text(camera.read_text() + "\n# another byte\n")
        (site_dir / "trajectories").symlink_to(REPO / "sitedata" / "trajectories")
        shutil.copy(REPO / "sitedata" / "gusev.toml", site_dir / "gusev.toml")
        digests[name] = hashlib.sha256(camera.read_bytes()).hexdigest()
    old = manifest_for(load_campaign_config(campaign_dir / "a" / "gusev.toml"))
    new = manifest_for(load_campaign_config(campaign_dir / "b" / "gusev.toml"))
    assert [str(change) for change in configuration_changes(old, new)] == [
        f"site.camera (file bytes): sha256 {digests['a'][:12]} -> sha256 {digests['b'][:12]}"]


def test_a_store_written_before_hash_inputs_were_recorded(campaign_dir):
    old, new = _manifest(campaign_dir, "old"), _manifest(campaign_dir, "new")
    old = {key: value for key, value in old.items() if key != "hash_inputs"}
    old["config_hash"] = "0" * 64
    assert "the tables are the same, so an input file's bytes" in describe_change(old, new)
    assert "(this store does not record which)" in describe_change(old, new)


def test_the_store_refusal_names_the_change_and_what_to_do(campaign_dir):
    """A real store: prepared with one configuration, checked with another."""
    first = load_campaign_config(_write_campaign(campaign_dir, "old", 2.0), cases_scale=0.02)
    second = load_campaign_config(_write_campaign(campaign_dir, "new", 4.0), cases_scale=0.02)
    store = CampaignStore(campaign_dir / "store")
    with store.lock():
        store.prepare(manifest_for(first), plan_campaign(first)[1])
    with pytest.raises(StoreError) as caught:
        store.check(manifest_for(second), plan_campaign(second)[1])
    text = str(caught.value)
    assert text.startswith(f"{store.root}: holds a campaign with another configuration: "
                           "estimators[1].parameters.sigma (estimator mine): 2.0 -> 4.0 (configuration hash ")
    assert "only the parameters or code of estimator mine changed" in text
    assert "`campaign submit --fresh`" in text and "another output directory (--output)" in text


def _write_campaign(directory: Path, name: str, sigma: float) -> Path:
    path = directory / f"{name}.toml"
    path.write_text('base = "gusev"\n' + ESTIMATORS.format(sigma=sigma))
    return path


def test_the_calibration_keys_are_the_calibration_tables():
    """differences.py names them without importing the models (the store imports it): the same keys."""
    from campaign.configuration import differences
    from campaign.configuration.estimators import CalibrationConfig

    assert differences.CALIBRATION_KEYS == tuple(CalibrationConfig.model_fields)
