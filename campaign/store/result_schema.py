"""The declared Arrow schema of a campaign's result rows: every column's name, type, unit and meaning.

One row per (case, estimator). A worker writes a case's rows in one case file with every column of
:data:`CASE_FILE_SCHEMA` (:func:`campaign.store.case_files.write_case_rows`); the store reads a case file
only when its schema is exactly that one (:func:`schema_problem`), and compaction writes
``results.parquet`` with :data:`RESULTS_SCHEMA` (the run-dependent columns, worker name, attempts and
stage timings, go to ``timings.parquet`` instead). The sensor-error columns ``sensor_*`` come from the
sensor model's declared errors (:func:`simulator.sensors.error_fields`) for the
:data:`IMAGE_COUNT` images of a case, so the schema is the same for every case of every campaign.

:func:`markdown_table` renders the columns for the documentation.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

from simulator.sensors import error_fields

IMAGE_COUNT = 3
"""Descent images per case (the three DIMES images)."""

RESULT_SCHEMA_VERSION = 1
"""Version of the declared case-file schema, recorded in every case file's identity metadata
(:mod:`campaign.store.case_files`): raise it whenever a column is added, removed, renamed, retyped or
changes meaning, so files of the old schema are rejected and recomputed instead of mixed in."""

SENSOR_PREFIX = "sensor_"
UNIT_SUFFIXES = (("_radps", "rad/s"), ("_rad", "rad"), ("_mps", "m/s"), ("_m", "m"))


class ResultSchemaError(ValueError):
    """A row or table does not fit the declared result schema; the message says which column and why."""


@dataclass(frozen=True)
class ResultColumn:
    """One declared column of the result rows.

    Attributes
    ----------
    name : str
        Column name.
    arrow_type : pyarrow.DataType
        Its Arrow type (every column is nullable: a case that failed has nulls).
    unit : str
        Physical unit ("" for none; list columns: the unit of their elements).
    meaning : str
        What the value is.
    run_dependent : bool
        The value varies from run to run (worker, attempts, timings): kept in ``timings.parquet``, not in
        ``results.parquet``.
    """

    name: str
    arrow_type: pa.DataType
    unit: str
    meaning: str
    run_dependent: bool = False


def _unit_of(name: str) -> str:
    """The SI unit a sensor-error name ends with."""
    return next(unit for suffix, unit in UNIT_SUFFIXES if name.endswith(suffix))


def declared_columns(image_count: int = IMAGE_COUNT) -> tuple[ResultColumn, ...]:
    """Every column of a case file, in the order it is written (and of ``results.parquet``, minus the
    run-dependent columns), for cases of ``image_count`` images."""
    f64, i64, text, flag = pa.float64(), pa.int64(), pa.string(), pa.bool_()
    column = ResultColumn
    return (
        # the plan row (campaign.plan.placement)
        column("case_id", i64, "", "case id: class_index * 1 000 000 + index within class"),
        column("class_name", text, "", "appearance class of the site"),
        column("terrain_name", text, "", "terrain the case is imaged on"),
        column("profile_index", i64, "", "index of the descent trajectory in the trajectory set"),
        column("profile_name", text, "", "name of the descent trajectory"),
        column("heading_rad", f64, "rad", "rotation of the trajectory about the vertical"),
        column("offset_east_m", f64, "m", "east offset of the trajectory on the terrain"),
        column("offset_north_m", f64, "m", "north offset of the trajectory on the terrain"),
        column("footprint_inside", flag, "", "all image footprints lie inside the terrain (planner's check)"),
        column("campaign_seed", i64, "", "the campaign's seed (a case draws from SeedSequence([seed, case_id]))"),
        # how the case ran
        column("attempts", i64, "", "attempts used (retries + 1 at most)", run_dependent=True),
        column("worker", text, "", "host:pid of the worker process", run_dependent=True),
        column("t_case_ms", f64, "ms", "wall time of the whole case, retries included", run_dependent=True),
        # one estimator's answer
        column("estimator", text, "", "estimator name ([[estimators]] name)"),
        column("status", text, "", "'ok', or 'failed' (the case's simulation or the estimator failed)"),
        column("error", text, "", "the failure ('' when ok)"),
        column("estimate_velocity_east_mps", f64, "m/s", "estimated horizontal velocity, east (null unless valid)"),
        column("estimate_velocity_north_mps", f64, "m/s", "estimated horizontal velocity, north (null unless valid)"),
        column("valid", flag, "", "the estimate is flagged valid (and the images see only terrain)"),
        column("reason", text, "", "the estimator's reason, or outside_terrain, estimator_failed, implausible, case_failed, no_op"),
        column("velocity_error_mps", f64, "m/s", "horizontal error of a valid estimate against the truth"),
        column("velocity_uncertainty_mps", f64, "m/s", "the estimator's own stated uncertainty (null unless valid and stated)"),
        column("feature_brightness", pa.list_(f64), "DN", "mean brightness of each tracked feature"),
        column("feature_contrast", pa.list_(f64), "DN", "contrast of each tracked feature"),
        column("feature_correlation", pa.list_(f64), "", "correlation score of each tracked feature"),
        column("feature_status", pa.list_(text), "", "status of each tracked feature"),
        # the case's truth
        column("truth_velocity_east_mps", f64, "m/s", "true velocity at the last image, east"),
        column("truth_velocity_north_mps", f64, "m/s", "true velocity at the last image, north"),
        column("wind_east_mps", f64, "m/s", "wind at the last image, east"),
        column("wind_north_mps", f64, "m/s", "wind at the last image, north"),
        column("altitude_image1_m", f64, "m", "lander altitude at image 1"),
        column("altitude_image3_m", f64, "m", "lander altitude at the last image"),
        column("attitude_floor_mps", f64, "m/s", "velocity error the attitude bias alone causes "
                                                 "(campaign.case.error_budget)"),
        column("heat_shield_in_view", pa.list_(flag), "", "the heat shield is visible, per image"),
        column("outside_terrain_fraction", pa.list_(f64), "", "fraction of pixels on ground outside the "
                                                              "terrain, per image"),
        *(column(f"{SENSOR_PREFIX}{name}", f64, _unit_of(name), f"sensor error: {meaning}")
          for name, meaning in error_fields(image_count)),
        # stage timings
        column("t_scene_ms", f64, "ms", "scene rendering time, all images", run_dependent=True),
        column("t_camera_ms", f64, "ms", "camera (detector) simulation time, all images", run_dependent=True),
        column("t_sensors_ms", f64, "ms", "sensor draw time", run_dependent=True),
        column("t_estimator_ms", f64, "ms", "this estimator's wall time", run_dependent=True),
    )


RESULT_COLUMNS = declared_columns()
CASE_FILE_SCHEMA = pa.schema([pa.field(c.name, c.arrow_type) for c in RESULT_COLUMNS])
"""Schema of a case file (every column, as the worker writes it)."""
RESULTS_SCHEMA = pa.schema([pa.field(c.name, c.arrow_type) for c in RESULT_COLUMNS if not c.run_dependent])
"""Schema of ``results.parquet`` (the columns that are the same in every run of a campaign)."""
TIMING_COLUMNS = tuple(c.name for c in RESULT_COLUMNS if c.run_dependent)
TIMINGS_SCHEMA = pa.schema([CASE_FILE_SCHEMA.field("case_id"), CASE_FILE_SCHEMA.field("estimator"),
                            *(CASE_FILE_SCHEMA.field(name) for name in TIMING_COLUMNS)])
"""Schema of ``timings.parquet`` (the keys of a row and its run-dependent columns)."""


def schema_problem(found: pa.Schema, expected: pa.Schema = CASE_FILE_SCHEMA) -> str | None:
    """Why a table's schema does not fit ``expected`` (the first missing, unexpected, mistyped or misplaced
    column, in one line), or None when it fits exactly."""
    if found.equals(expected, check_metadata=False):     # the common case, checked at once (status reads every file)
        return None
    names = set(found.names)
    for name in expected.names:
        if name not in names:
            return f"does not fit the result schema: column {name!r} is missing"
    for name in found.names:
        if name not in expected.names:
            return f"does not fit the result schema: unexpected column {name!r}"
    if len(found.names) != len(set(found.names)):
        duplicate = next(name for name in found.names if found.names.count(name) > 1)
        return f"does not fit the result schema: column {duplicate!r} appears twice"
    for field in expected:
        actual = found.field(field.name).type
        if actual != field.type:
            return f"does not fit the result schema: column {field.name!r} is {actual}, declared {field.type}"
    if found.names != expected.names:
        moved = next(a for a, b in zip(found.names, expected.names) if a != b)
        return f"does not fit the result schema: column {moved!r} is out of the declared order"
    return None


def rows_table(rows: Sequence[Mapping[str, Any]], schema: pa.Schema = CASE_FILE_SCHEMA) -> pa.Table:
    """The rows (mappings of column name to value) as an Arrow table of ``schema``.

    Raises
    ------
    ResultSchemaError
        A row lacks a declared column or has an undeclared one, or a value does not convert to its
        column's declared type (the message names the row and the column).
    """
    declared = set(schema.names)
    for index, row in enumerate(rows):
        missing = [name for name in schema.names if name not in row]
        if missing:
            raise ResultSchemaError(f"row {index}: column {missing[0]!r} is missing")
        unexpected = [name for name in row if name not in declared]
        if unexpected:
            raise ResultSchemaError(f"row {index}: unexpected column {unexpected[0]!r}")
    arrays = []
    for field in schema:
        values = [row[field.name] for row in rows]
        try:
            arrays.append(pa.array(values, type=field.type))
        except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, ValueError, OverflowError) as exc:
            raise ResultSchemaError(f"column {field.name!r} does not convert to {field.type}: "
                                    f"{str(exc).splitlines()[0]}") from None
    return pa.Table.from_arrays(arrays, schema=schema)


def markdown_table(columns: Sequence[ResultColumn] = RESULT_COLUMNS) -> str:
    """The columns as a GitHub Markdown table (column, Arrow type, unit, meaning, file)."""
    lines = ["| Column | Arrow type | Unit | Meaning | In |", "|---|---|---|---|---|"]
    for c in columns:
        where = ("timings.parquet" if c.run_dependent
                 else "both (row key)" if c.name in TIMINGS_SCHEMA.names else "results.parquet")
        lines.append(f"| `{c.name}` | `{c.arrow_type}` | {c.unit} | {c.meaning} | {where} |")
    return "\n".join(lines)
