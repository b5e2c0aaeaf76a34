"""The declared result schema (campaign.store.result_schema): the worker writes it, the store reads only
case files that fit it (a file with an unexpected column or a mistyped one is bad, named with the column,
and moved to rejected/), compaction writes it, and the documentation table is rendered from it.

A real campaign store made by the ``campaign`` CLI (a subprocess), real Parquet files.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from store_files import case_files as _case_files
from store_files import place, results_part

from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import table_bytes, write_case_rows
from campaign.store.result_schema import (
    CASE_FILE_SCHEMA,
    RESULT_COLUMNS,
    RESULTS_SCHEMA,
    SENSOR_PREFIX,
    ResultSchemaError,
    markdown_table,
    rows_table,
    schema_problem,
)
from simulator.sensors import error_fields

REPO = Path(__file__).resolve().parents[3]
SITE = REPO / "sitedata" / "gusev.toml"


def _campaign(*args) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "campaign.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=REPO, env=env)


@pytest.fixture(scope="module")
def reference(tmp_path_factory, warm_scheduler) -> Path:
    """A finished store of three cases (gcp, gdcp, gkep: one each), computed on the test process's warm cluster
    (``warm_scheduler``, tests/conftest.py: the files' schema is tested, not the cluster's start-up)."""
    out = tmp_path_factory.mktemp("schema") / "reference"
    result = _campaign("submit", SITE, "--output", out, "--cases-scale", "0.005", "--scheduler", warm_scheduler,
                       "--no-progress")
    assert result.returncode == 0, result.stdout + result.stderr
    return out


def _write_recorded(store: Path, case_id: int, table: pa.Table) -> Path:
    """``table`` as the case file of ``case_id`` with a correct size and sha256 record in its name (so only
    its schema can be wrong), replacing the worker's file."""
    return place(store, case_id, table_bytes(table))


@pytest.mark.cluster
@pytest.mark.slow
def test_worker_files_and_compacted_results_have_the_declared_schema(reference):
    for path in _case_files(reference).values():
        assert pq.read_schema(path).remove_metadata() == CASE_FILE_SCHEMA
    assert pq.read_schema(results_part(reference)).remove_metadata() == RESULTS_SCHEMA
    sensor_columns = [name for name in CASE_FILE_SCHEMA.names if name.startswith(SENSOR_PREFIX)]
    assert sensor_columns == [SENSOR_PREFIX + name for name, _ in error_fields(3)]


@pytest.mark.cluster
@pytest.mark.slow
def test_store_rejects_case_files_with_an_unexpected_or_mistyped_column(reference, tmp_path):
    store = tmp_path / "store"
    shutil.copytree(reference, store)
    files = _case_files(store)
    first, second, third = sorted(files)
    table = pq.read_table(files[first])
    extra = _write_recorded(store, first, table.append_column("note", pa.array(["hand-made"] * table.num_rows)))
    table = pq.read_table(files[second])
    index = table.schema.get_field_index("velocity_error_mps")
    mistyped = _write_recorded(store, second, table.set_column(
        index, pa.field("velocity_error_mps", pa.string()), table.column(index).cast(pa.string())))

    status = _campaign("status", store)
    assert status.returncode == 0, status.stderr
    assert f"{store}: 3 planned, 1 done, 0 failed, 2 missing" in status.stdout, status.stdout
    assert "2 bad case files not counted" in status.stdout, status.stdout
    verify = _campaign("verify", store)
    assert verify.returncode == 1
    lines = verify.stdout.splitlines()
    assert f"{extra}: does not fit the result schema: unexpected column 'note'" in lines, verify.stdout
    assert (f"{mistyped}: does not fit the result schema: column 'velocity_error_mps' is string, declared double"
            in lines), verify.stdout

    campaign_store = CampaignStore(store)
    assert campaign_store.read_case_table().column("case_id").to_pylist() == [third]   # only the fitting file
    assert campaign_store.reject_bad_files() == 2
    log = (store / "rejected" / "rejected.log").read_text()
    assert "unexpected column 'note'" in log and "column 'velocity_error_mps' is string" in log
    assert not extra.exists() and (store / "rejected" / extra.name).exists()


def test_the_writer_refuses_rows_that_do_not_fit(tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    row = dict.fromkeys(CASE_FILE_SCHEMA.names)
    with pytest.raises(ResultSchemaError, match="unexpected column 'payload'"):
        write_case_rows(cases, 1, [{**row, "case_id": 1, "payload": "x"}], ok=True)
    with pytest.raises(ResultSchemaError, match="column 'valid' is missing"):
        write_case_rows(cases, 1, [{name: value for name, value in row.items() if name != "valid"}], ok=True)
    with pytest.raises(ResultSchemaError, match="column 'heading_rad' does not convert to double"):
        write_case_rows(cases, 1, [{**row, "heading_rad": "north"}], ok=True)
    assert list(cases.iterdir()) == [], "nothing is written for rows that do not fit"
    table = rows_table([{**row, "case_id": 1, "feature_brightness": []}])
    assert table.schema == CASE_FILE_SCHEMA and table.column("feature_brightness").type == pa.list_(pa.float64())


def test_schema_problem_names_the_column():
    assert schema_problem(CASE_FILE_SCHEMA) is None
    assert schema_problem(CASE_FILE_SCHEMA.remove(0)) == "does not fit the result schema: column 'case_id' is missing"
    swapped = pa.schema([CASE_FILE_SCHEMA.field(1), CASE_FILE_SCHEMA.field(0), *list(CASE_FILE_SCHEMA)[2:]])
    assert "column 'class_name' is out of the declared order" in schema_problem(swapped)


def test_markdown_table_documents_every_column_with_type_and_unit():
    lines = markdown_table().splitlines()
    assert len(lines) == 2 + len(RESULT_COLUMNS)
    assert "| `velocity_error_mps` | `double` | m/s |" in markdown_table()
    assert "| `sensor_angular_rate_noise_image3_z_radps` | `double` | rad/s |" in markdown_table()
    assert all(column.meaning for column in RESULT_COLUMNS)


def test_the_documented_columns_are_the_declared_schema():
    """docs/campaigns.md shows the table generated from the schema, so the docs cannot drift from it."""
    text = (Path(__file__).resolve().parents[3] / "docs" / "campaigns.md").read_text()
    documented = text.split("<!-- result-schema:start -->\n")[1].split("\n<!-- result-schema:end -->")[0]
    assert documented == markdown_table()
    assert "`case_id` | `int64` |  | " in documented and "both (row key)" in documented
