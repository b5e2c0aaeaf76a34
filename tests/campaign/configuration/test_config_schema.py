"""`campaign schema`: the JSON Schema generated from the one declaration of each table accepts every shipped
TOML file and rejects the mistakes the loaders reject (checked by an independent validator, jsonschema)."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import jsonschema
import pytest

from campaign.cli import main
from campaign.configuration.schemas import SCHEMA_TABLES, table_schema

REPO = Path(__file__).resolve().parents[3]
SITEDATA = REPO / "sitedata"

SHIPPED = [
    ("campaign_file", SITEDATA / "gusev.toml"), ("campaign_file", SITEDATA / "meridiani.toml"),
    ("campaign_file", SITEDATA / "examples" / "real_moc.toml"),
    ("camera", SITEDATA / "cameras" / "mer_a.toml"), ("camera", SITEDATA / "cameras" / "mer_b.toml"),
    ("campaign_file", SITEDATA / "examples" / "compare_estimators.toml"),
    ("campaign_file", SITEDATA / "examples" / "my_estimator_gusev.toml"),
    ("sweep", SITEDATA / "sweeps" / "nightly.toml"), ("sweep", SITEDATA / "sweeps" / "atmosphere_gusev.toml"),
    ("sweep", SITEDATA / "sweeps" / "flat_field_meridiani.toml"),
    ("trajectory_set", SITEDATA / "trajectories" / "edl_gusev.toml"),
    ("trajectory_set", SITEDATA / "trajectories" / "edl_meridiani.toml"),
    ("terrain_sidecar", SITEDATA / "examples" / "M0100115.sidecar.toml"),
]


def _validator(name: str) -> jsonschema.Draft202012Validator:
    schema = table_schema(name)
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


@pytest.mark.parametrize("name, path", SHIPPED, ids=lambda value: getattr(value, "name", value))
def test_every_shipped_file_satisfies_its_schema(name, path):
    data = tomllib.loads(path.read_text())
    errors = list(_validator(name).iter_errors(data))
    assert not errors, [error.message for error in errors]


@pytest.mark.parametrize("name, path, edit", [
    ("camera", SITEDATA / "cameras" / "mer_a.toml", ("radial_distortion", "radial_distorsion")),
    ("camera", SITEDATA / "cameras" / "mer_a.toml", ("f_number = 12.0", "f_number = 0.1")),
    ("camera", SITEDATA / "cameras" / "mer_a.toml", ("adc_bits = 12", "adc_bits = 12.5")),
    ("camera", SITEDATA / "cameras" / "mer_a.toml", ('transfer_direction = "toward_last_row"', 'transfer_direction = "up"')),
    ("campaign_file", SITEDATA / "gusev.toml", ("elevation_deg = 57.1", "elevation_deg = -3.0")),
    ("campaign_file", SITEDATA / "gusev.toml", ('preset = "gcp"', 'preset = "gxx"')),
    ("campaign_file", SITEDATA / "gusev.toml", ("[site.sun]", "[campaign]\nseeed = 3\n[site.sun]")),
    ("trajectory_set", SITEDATA / "trajectories" / "edl_gusev.toml", ("bridle_length_m = 20.0", "bridle_length_m = 0.5")),
    ("sweep", SITEDATA / "sweeps" / "nightly.toml", ('mode = "grid"', 'mode = "zigzag"')),
    ("campaign_file", SITEDATA / "examples" / "compare_estimators.toml", ('kind = "python"', 'kind = "rust"')),
    ("campaign_file", SITEDATA / "examples" / "my_estimator_gusev.toml", ('base = "gusev"', 'bass = "gusev"')),
    ("campaign_file", SITEDATA / "examples" / "my_estimator_gusev.toml", ('path = "."', 'path = 1')),
    ("campaign_file", SITEDATA / "gusev.toml", ("[site.sun]", "[scene.atmosphere]\norbital_optical_depth = 11.0\n[site.sun]")),
    ("campaign_file", SITEDATA / "gusev.toml", ("[site.sun]", "[estimator]\nflat_field = \"magic\"\n[site.sun]")),
])
def test_schema_rejects_what_the_loader_rejects(name, path, edit):
    text = path.read_text()
    assert edit[0] in text
    data = tomllib.loads(text.replace(edit[0], edit[1], 1))
    assert list(_validator(name).iter_errors(data)), f"{name}: {edit} accepted by the schema"


def test_schema_carries_units_ranges_and_defaults():
    sensors = table_schema("sensors")["properties"]
    bias = sensors["attitude_bias_sigma_deg"]
    assert bias["default"] == 1.0 and bias["minimum"] == 0.0 and bias["maximum"] == 30.0
    assert "(deg)" in bias["description"]
    scene = table_schema("scene")
    assert set(scene["properties"]["fidelity"]["enum"]) == {"reference", "high", "default", "fast"}
    assert scene["additionalProperties"] is False


def test_schema_command_prints_one_table_or_all(capsys):
    assert main(["schema", "camera"]) == 0
    camera = json.loads(capsys.readouterr().out)
    assert camera["$schema"].endswith("2020-12/schema") and "geometry" in camera["properties"]
    assert main(["schema"]) == 0
    everything = json.loads(capsys.readouterr().out)
    assert set(everything) == set(SCHEMA_TABLES) and everything["camera"] == camera
    with pytest.raises(SystemExit) as exit_info:
        main(["schema", "nope"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "invalid choice: 'nope'" in err


def test_the_schema_loads_only_what_the_tables_declare():
    """Declaring every table imports no numerical or run stack: scipy, numba, dask, pandas, pyarrow and matplotlib are
    loaded by the functions that compute, read or run with them (`campaign schema` answers in well under a
    second: benchmarks/bench_cli.py)."""
    import subprocess
    import sys

    probe = ("import sys\nfrom campaign.configuration.schemas import SCHEMA_TABLES, schema_model\n"
             "models = [schema_model(name) for name in SCHEMA_TABLES]\n"
             "print(sorted({name.split('.')[0] for name in sys.modules} & "
             "{'scipy', 'numba', 'dask', 'distributed', 'pandas', 'pyarrow', 'matplotlib'}))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]", result.stdout
