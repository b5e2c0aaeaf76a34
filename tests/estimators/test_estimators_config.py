"""``[estimator]`` calibration keys and ``[[estimators]]`` entries: validated at the edge into specs, bad
entries one line naming the file and the field; the configuration hash follows the estimator list."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from campaign.configuration.campaign_file import campaign_config_from_data
from config_tables.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
GUSEV = REPO / "sitedata" / "gusev.toml"
PLUGINS = Path(__file__).resolve().parents[1] / "plugins"


def _config(extra: dict):
    data = tomllib.loads(GUSEV.read_text())
    data.update(extra)
    return campaign_config_from_data(data, GUSEV, source="test.toml")


def test_default_is_the_reference_estimator_with_a_calibrated_flat_field():
    config = _config({"estimator": {"min_correlation": 0.8}})
    assert config.estimator_names == ["dimes"]
    assert config.estimators[0].kind == "reference" and config.estimators[0].parameters == {"min_correlation": 0.8}
    assert (config.calibration.flat_field, config.calibration.flat_field_frames) == ("calibrated", 16)
    assert config.estimator.min_correlation == 0.8


def test_estimators_list_in_order_with_reference_defaults_from_the_estimator_table():
    config = _config({
        "estimator": {"flat_field": "truth", "flat_field_frames": 4, "min_correlation": 0.8},
        "estimators": [
            {"name": "strict", "kind": "reference", "parameters": {"min_correlation": 0.9}},
            {"name": "pc", "kind": "python", "callable": "estimators.phase_correlation:estimate",
             "parameters": {"min_response": 0.1}},
            {"name": "flight", "kind": "command", "argv": ["{python}", "{config_dir}/x.py", "{images}", "{output}"],
             "timeout_s": 5, "image_format": "raw"},
        ]})
    assert config.estimator_names == ["strict", "pc", "flight"]
    strict, pc, flight = config.estimators
    assert strict.parameters == {"min_correlation": 0.9}
    assert pc.parameters == {"min_response": 0.1} and not pc.isolate
    assert flight.argv[1] == f"{GUSEV.parent.resolve()}/x.py" and flight.timeout_s == 5.0
    assert config.calibration.flat_field == "truth" and config.calibration.flat_field_frames == 4


def test_hash_changes_with_the_estimator_list_and_calibration():
    one = _config({})
    two = _config({"estimators": [{"name": "dimes", "kind": "reference"},
                                  {"name": "pc", "kind": "python", "callable": "estimators.phase_correlation:estimate"}]})
    truth = _config({"estimator": {"flat_field": "truth"}})
    assert len({one.config_hash, two.config_hash, truth.config_hash}) == 3


@pytest.mark.parametrize("extra, expected", [
    ({"estimator": {"flat_field": "magic"}}, "estimator.flat_field = 'magic' is not allowed; allowed: calibrated, none, truth"),
    ({"estimator": {"flat_field_frames": 0}}, "estimator.flat_field_frames = 0 is out of range"),
    ({"estimators": [{"name": "a", "kind": "rust"}]}, "estimators[0].kind = 'rust' is not allowed; allowed: reference, python, command"),
    ({"estimators": [{"name": "a", "kind": "reference"}, {"name": "a", "kind": "reference"}]},
     "estimators[1].name = 'a' is used twice"),
    ({"estimators": [{"name": "a b", "kind": "reference"}]}, "estimators[0].name = 'a b' is not allowed"),
    ({"estimators": [{"kind": "reference"}]}, "estimators[0].name is missing"),
    ({"estimators": [{"name": "a", "kind": "reference", "parameters": {"min_correlation": 3.0}}]},
     "estimators[0].parameters.min_correlation = 3 is out of range"),
    ({"estimators": [{"name": "a", "kind": "reference", "colour": "red"}]},
     "estimators[0].colour is not a known field; allowed: name, parameters, kind"),
    ({"estimators": [{"name": "a", "kind": "python", "callable": "no_colon"}]},
     "estimators[0].callable = 'no_colon' is not allowed; allowed: 'package.module:function'"),
    ({"estimators": [{"name": "a", "kind": "python", "callable": "nowhere.module:f"}]},
     "estimators[0].callable = 'nowhere.module:f': module 'nowhere.module' cannot be imported"),
    ({"estimators": [{"name": "a", "kind": "python", "callable": "estimators.contract:nothing"}]},
     "estimators.contract has no callable 'nothing'"),
    ({"estimators": [{"name": "a", "kind": "command"}]}, "estimators[0].argv is missing"),
    ({"estimators": [{"name": "a", "kind": "command", "argv": ["{python}", "{imgs}"]}]},
     "estimators[0].argv [1] = '{imgs}' uses an unknown placeholder {imgs}"),
    ({"estimators": [{"name": "a", "kind": "command", "argv": ["{python}", "--in={images}"]}]},
     "{images} must be a whole argument"),
    ({"estimators": [{"name": "a", "kind": "command", "argv": ["/no/such/estimator", "{output}"]}]},
     "estimators[0].argv [0] = '/no/such/estimator' is not an executable file or a program on PATH"),
    ({"estimators": [{"name": "a", "kind": "command", "argv": ["{python}"], "timeout_s": 0}]},
     "estimators[0].timeout_s = 0 is out of range"),
    ({"estimators": [{"name": "a", "kind": "command", "argv": ["{python}"], "image_format": "jpeg"}]},
     "estimators[0].image_format = 'jpeg' is not allowed; allowed: png, npy, raw"),
    ({"estimators": {"name": "a"}}, "estimators must be a list; got dict"),
])
def test_bad_estimator_entries_are_one_line_naming_file_and_field(extra, expected):
    with pytest.raises(ConfigError) as error:
        _config(extra)
    message = str(error.value)
    assert message.startswith("test.toml: ") and expected in message and "\n" not in message, message
