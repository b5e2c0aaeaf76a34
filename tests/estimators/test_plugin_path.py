"""A python estimator's ``path``: its module is imported from a directory named relative to the campaign file,
the module is shipped to workers from wherever it lives, and an import error says where plug-ins are looked for."""
import hashlib
import sys
import uuid
from pathlib import Path

import pytest

from campaign.configuration.campaign_file import load_campaign_config
from campaign.run.plugin_setup import _is_installed, shipped_code
from config_tables.errors import ConfigError

PLUGIN = '''def estimate(inputs):
    """IMU velocity at the last image (m/s)."""
    last = inputs.measurements.images[-1].imu_velocity_mps
    return {"velocity_east_mps": float(last[0]), "velocity_north_mps": float(last[1]), "valid": True, "reason": "ok"}
'''


def _campaign(directory: Path, module: str, path_line: str) -> Path:
    campaign = directory / "mine.toml"
    campaign.write_text(f'base = "gusev"\n[[estimators]]\nname = "mine"\nkind = "python"\n{path_line}\n'
                        f'callable = "{module}:estimate"\n')
    return campaign


@pytest.fixture
def module_name(monkeypatch):
    """A fresh module name; sys.path (which a `path` extends) is restored afterwards."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    name = f"h32plugin_{uuid.uuid4().hex[:10]}"
    yield name
    sys.modules.pop(name, None)


def test_path_relative_to_the_campaign_file(tmp_path, module_name, monkeypatch):
    """path = "plugins" beside the campaign file, loaded from another working directory: found, its
    bytes in the configuration hash (not its directory), and shipped to the workers."""
    (tmp_path / "campaigns" / "plugins").mkdir(parents=True)
    module_file = tmp_path / "campaigns" / "plugins" / f"{module_name}.py"
    module_file.write_text(PLUGIN)
    campaign = _campaign(tmp_path / "campaigns", module_name, 'path = "plugins"')
    monkeypatch.chdir(tmp_path)
    config = load_campaign_config(campaign)
    assert Path(sys.modules[module_name].__file__).samefile(module_file)
    assert config.hash_inputs["estimator_code_digests"] == {
        f"mine:{module_file.name}": hashlib.sha256(module_file.read_bytes()).hexdigest()}
    shipped = shipped_code(config.estimators)
    assert [code.module for code in shipped] == [module_name] and Path(shipped[0].source).samefile(module_file)


def test_same_module_name_from_another_directory_is_refused(tmp_path, module_name):
    """Two directories with a module of one name: the second campaign would silently run the first's code."""
    for name in ("one", "two"):
        (tmp_path / name).mkdir()
        (tmp_path / name / f"{module_name}.py").write_text(PLUGIN)
    load_campaign_config(_campaign(tmp_path / "one", module_name, 'path = "."'))
    with pytest.raises(ConfigError, match=f"module '{module_name}' is imported from .*one.*, not from path"):
        load_campaign_config(_campaign(tmp_path / "two", module_name, 'path = "."'))


def test_import_error_says_where_plugins_are_looked_for(tmp_path, module_name):
    (tmp_path / "plugins").mkdir()
    campaign = _campaign(tmp_path, module_name, "")
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(campaign)
    text = str(caught.value)
    assert f"module '{module_name}' cannot be imported (ModuleNotFoundError" in text
    assert "looked for in the directories of sys.path" in text and 'path = "DIR" in this [[estimators]] entry' in text
    assert "\n" not in text
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(_campaign(tmp_path, module_name, 'path = "plugins"'))
    assert f"looked for in path '{tmp_path / 'plugins'}' of this entry, then" in str(caught.value)


def test_path_must_be_a_directory(tmp_path, module_name):
    with pytest.raises(ConfigError, match=r"mine.toml: estimators\[0\].path = '.*nowhere' is not a directory; allowed"):
        load_campaign_config(_campaign(tmp_path, module_name, 'path = "nowhere"'))


def test_a_module_inside_an_installed_package_is_shipped(tmp_path):
    """Only a module at the top of site-packages is the workers' environment; one deeper inside (a plug-in
    beside a campaign file in an installed package's data) is not on the workers' sys.path."""
    top = tmp_path / "site-packages" / "mod.py"
    deep = tmp_path / "site-packages" / "sitedata" / "examples" / "my_estimator.py"
    deep.parent.mkdir(parents=True)
    top.write_text("")
    deep.write_text("")
    assert _is_installed(top) and not _is_installed(deep)
