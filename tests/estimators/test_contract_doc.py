"""docs/estimators.md lists the whole estimator contract, so it cannot drift from the code.

Every field of the records a plug-in receives or returns (the contract's dataclasses, the camera's
tables, the measurements JSON keys, the command placeholders) must be named in backticks in the doc's
contract section; the result columns it names must exist; its inline python plug-in must be the
example file's code, line for line.
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from campaign.store.result_schema import RESULT_COLUMNS
from estimators.command import NAMES
from estimators.contract import FEATURE_METRICS, REQUIRED_KEYS, EstimatorInputs, EstimatorOutput
from estimators.examples import minimal_python
from file_formats import measurements_json
from flight_interface.cahvor import Cahvor
from flight_interface.calibration import CalibrationProducts
from flight_interface.camera import Camera
from flight_interface.camera_file import Detector, Electronics, Radiometry, Timing
from flight_interface.measurements import DescentMeasurements, ImageMeasurement

DOC = Path(__file__).resolve().parents[2] / "docs" / "estimators.md"


@pytest.fixture(scope="module")
def contract_section() -> str:
    text = DOC.read_text()
    return text[text.index("## The estimator contract"):text.index("## Plugging an estimator in")]


def named(section: str) -> set[str]:
    """Every backticked word of the section, and every word of a backticked phrase."""
    words = set()
    for quoted in re.findall(r"`([^`]+)`", section):
        words.add(quoted)
        words.update(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", quoted))
    return words


@pytest.mark.parametrize("record", [EstimatorInputs, EstimatorOutput, DescentMeasurements, ImageMeasurement,
                                    CalibrationProducts, Camera, Cahvor])
def test_every_field_of_the_contract_records_is_listed(contract_section, record):
    missing = [f.name for f in dataclasses.fields(record) if f.name not in named(contract_section)]
    assert missing == [], f"docs/estimators.md does not list {record.__name__} fields {missing}"


@pytest.mark.parametrize("table", [Detector, Timing, Radiometry, Electronics])
def test_every_camera_table_field_is_listed(contract_section, table):
    missing = [name for name in table.model_fields if name not in named(contract_section)]
    assert missing == [], f"docs/estimators.md does not list camera {table.__name__} fields {missing}"


def test_json_keys_placeholders_and_output_keys_are_listed(contract_section):
    words = named(contract_section)
    json_keys = (*measurements_json._REQUIRED, *measurements_json._OPTIONAL, "sun_direction_world", "images")
    assert [key for key in json_keys if key not in words] == []
    assert [key for key in (*REQUIRED_KEYS, *FEATURE_METRICS, "features", "status") if key not in words] == []
    placeholders = re.findall(r"\{([a-z_0-9]+)\}", contract_section)
    assert [name for name in NAMES if name not in placeholders] == []


def test_the_result_columns_the_doc_names_exist(contract_section):
    output = contract_section[contract_section.index("### Output"):contract_section.index("### Read-only")]
    stored = [row.rsplit("|", 2)[-2] for row in output.splitlines() if row.startswith("| `")]
    columns = {column.name for column in RESULT_COLUMNS}
    named_columns = [name for cell in stored for name in re.findall(r"`([a-z_]+)`", cell)]
    assert len(named_columns) >= 8 and [name for name in named_columns if name not in columns] == []


def test_the_inline_python_plug_in_is_the_example_file(contract_section):
    block = re.search(r"The python one, whole:\n```python\n(.*?)```", contract_section, re.S).group(1)
    source = Path(minimal_python.__file__).read_text()
    assert block == source[source.index("import math\n"):]
