"""POST-style whitespace tables mapped onto the trajectory schema of :mod:`sitedata.edl.trajectory_io`.

A POST (Program to Optimize Simulated Trajectories) or similar tool prints a table: optional comment
lines (starting with ``#`` or ``!``), one header line naming the columns, then rows of numbers
separated by whitespace (Fortran ``1.0D+03`` exponents accepted). A *mapping* (dict or
:class:`PostMapping`, or a TOML file) says which source column feeds each schema column and how to
convert it to SI (declared once by :class:`PostMapping`; ``campaign schema post_mapping``)::

    [columns]                               # schema column = source
    t_s = "TIME"                            # copied as is (already SI)
    z_m = { column = "ALT", unit = "ft", offset = -120.0 }   # si = value * unit_scale + offset
    vx_mps = { column = "VE", scale = 0.3048 }               # or an explicit scale
    wind_up_mps = { value = 0.0 }           # a constant
    heat_shield_x_m = "HSX"                 # optional: all three heat-shield columns or none
    [attitude]                              # optional, instead of qw, qx, qy, qz in [columns]
    euler_zyx = { yaw = "PSI", pitch = "THT", roll = "PHI", unit = "deg" }
    [images]
    altitudes_m = [2000.0, 1725.0]          # first downward crossings of z_m ...
    last_after_previous_s = 3.75            # ... and one more image this long after the last (optional)
    # or: times_s = [12.1, 15.9, 19.65]

Euler angles give the body-to-world attitude ``Rz(yaw) Ry(pitch) Rx(roll)`` in the schema's frames
(world x east, y north, z up; body z up the lander axis); convert other conventions in the source.
Units: m, km, ft, kft (length); s, ms (time); m/s, km/s, ft/s (speed); rad, deg (angle); rad/s, deg/s
(rate); 1 (quaternion components). A unit must suit the schema column's kind (its name's suffix).
The images must be the three of DIMES (``times_s`` of 3, or 2 ``altitudes_m`` + ``last_after_previous_s``,
or 3 ``altitudes_m``).
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeAlias

import numpy as np
from pydantic import Discriminator, Field, Tag, create_model, model_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, FloatList, parse
from config_tables.toml_file import load_toml
from flight_interface.frames import quat_from_axis_angle, quat_multiply
from simulator.scene.descent_profile import DescentProfile
from sitedata.edl.trajectory_io import (
    DIMES_IMAGE_COUNT,
    HEAT_SHIELD_COLUMNS,
    REQUIRED_COLUMNS,
    TrajectoryFileError,
    frame_to_profiles,
    image_column,
)

if TYPE_CHECKING:
    import pandas as pd

UNITS = {  # unit: (kind, scale to SI)
    "m": ("length", 1.0), "km": ("length", 1e3), "ft": ("length", 0.3048), "kft": ("length", 304.8),
    "s": ("time", 1.0), "ms": ("time", 1e-3),
    "m/s": ("speed", 1.0), "km/s": ("speed", 1e3), "ft/s": ("speed", 0.3048),
    "rad": ("angle", 1.0), "deg": ("angle", np.pi / 180.0),
    "rad/s": ("rate", 1.0), "deg/s": ("rate", np.pi / 180.0), "1": ("none", 1.0),
}
_ATTITUDE = ("qw", "qx", "qy", "qz")
if TYPE_CHECKING:
    #: A key of UNITS (checked at run time).
    Unit: TypeAlias = str
else:
    Unit = Literal[tuple(UNITS)]


def _kind(schema_column: str) -> str:
    for suffix, kind in (("_radps", "rate"), ("_mps", "speed"), ("_t_s", "time"), ("_s", "time"), ("_m", "length")):
        if schema_column.endswith(suffix):
            return kind
    return "none"


class ColumnSource(ConfigModel):
    """A source column: ``si = value * (unit scale | scale) + offset``."""

    column: str
    """Name of the source column (header)."""
    unit: Unit | None = None
    """Unit of the source column; must suit the schema column's kind."""
    scale: float | None = None
    """Explicit factor to SI (instead of unit)."""
    offset: float = 0.0
    """Added after scaling (SI)."""

    @model_validator(mode="after")
    def _one_factor(self):
        if self.unit is not None and self.scale is not None:
            raise FieldProblem("unit", "and scale both given; allowed: one of them")
        return self

    @property
    def factor(self) -> float:
        return UNITS[self.unit][1] if self.unit is not None else (1.0 if self.scale is None else self.scale)


class ConstantSource(ConfigModel):
    """A constant (SI)."""

    value: float


def _source_kind(value: Any) -> str:
    if isinstance(value, str):
        return "name"
    return "constant" if isinstance(value, dict) and "value" in value else "column"


#: "SOURCE", {column, unit | scale, offset} or {value}
Source = Annotated[Annotated[str, Tag("name")] | Annotated[ColumnSource, Tag("column")]
                   | Annotated[ConstantSource, Tag("constant")], Discriminator(_source_kind)]


class _Columns(ConfigModel):
    """``[columns]``: schema column = source, for every column of the trajectory schema
    (:mod:`sitedata.edl.trajectory_io`; qw..qz unless [attitude] euler_zyx is given; the heat-shield columns
    are optional, all three or none)."""

    @model_validator(mode="after")
    def _units_suit_columns(self):
        for name in type(self).model_fields:
            source = getattr(self, name)
            if isinstance(source, ColumnSource) and source.unit is not None:
                kind = _kind(name)
                allowed = [u for u, (k, _) in UNITS.items() if k == kind] or ["1"]
                if source.unit not in allowed:
                    raise FieldProblem(f"{name}.unit", f"= {source.unit!r} is not allowed; allowed: {', '.join(allowed)}")
        return self


if TYPE_CHECKING:
    # Built at run time with one optional Source field per schema column; statically a _Columns whose
    # fields are read by name (getattr).
    ColumnsTable: TypeAlias = _Columns
else:
    ColumnsTable = create_model(
        "ColumnsTable", __base__=_Columns, __doc__=_Columns.__doc__,
        **{name: (Source | None, None)
           for name in [c for c in REQUIRED_COLUMNS if c != "profile_id"] + list(HEAT_SHIELD_COLUMNS)})


class EulerAngles(ConfigModel):
    """``euler_zyx``: body-to-world attitude Rz(yaw) Ry(pitch) Rx(roll) from three source columns."""

    yaw: str
    pitch: str
    roll: str
    unit: Literal["rad", "deg"] = "rad"


class AttitudeTable(ConfigModel):
    """``[attitude]``: instead of qw, qx, qy, qz in [columns]."""

    euler_zyx: EulerAngles | None = None


class PostImages(ConfigModel):
    """``[images]``: the three image times, given or from first downward altitude crossings."""

    times_s: FloatList | None = None
    """Start of exposure of each image (s)."""
    altitudes_m: FloatList | None = None
    """First downward crossings of z_m (m)."""
    last_after_previous_s: float | None = Field(None, gt=0.0)
    """One more image this long after the last crossing (s)."""

    @model_validator(mode="after")
    def _three_images(self):
        if (self.times_s is None) == (self.altitudes_m is None):
            raise FieldProblem("times_s", "and altitudes_m: give exactly one of them")
        given = "times_s" if self.times_s is not None else "altitudes_m"
        count = len(getattr(self, given)) + (self.last_after_previous_s is not None and given == "altitudes_m")
        if count != DIMES_IMAGE_COUNT:
            raise FieldProblem(given, f"gives {count} image times; allowed: {DIMES_IMAGE_COUNT} (the DIMES images)")
        return self


class PostMapping(ConfigModel):
    """A POST-table mapping (TOML file or dict)."""

    columns: ColumnsTable
    attitude: AttitudeTable = AttitudeTable()
    images: PostImages


def parse_whitespace_table(path: str | Path) -> pd.DataFrame:
    """Header + whitespace-separated numbers -> DataFrame of float64 (errors name file and line)."""
    import pandas as pd

    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryFileError(f"{path}: cannot be read as a text table: {exc}") from None
    header, rows = None, []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text[0] in "#!":
            continue
        tokens = text.split()
        if header is None:
            header = tokens
            if len(set(header)) != len(header):
                raise TrajectoryFileError(f"{path}: line {number}: header repeats a column name; allowed: unique names")
            continue
        if len(tokens) != len(header):
            raise TrajectoryFileError(f"{path}: line {number}: {len(tokens)} values but the header has {len(header)} "
                                      "columns; allowed: one value per header column")
        try:
            rows.append([float(t.replace("D", "E").replace("d", "e")) for t in tokens])
        except ValueError:
            bad = next(i for i, t in enumerate(tokens) if not _is_number(t))
            raise TrajectoryFileError(f"{path}: line {number} column {header[bad]!r}: {tokens[bad]!r} is not a number; "
                                      "allowed: decimal numbers") from None
    if header is None or len(rows) < 2:
        raise TrajectoryFileError(f"{path}: {0 if header is None else len(rows)} data rows; allowed: a header line and "
                                  "at least 2 rows")
    return pd.DataFrame(np.array(rows), columns=header)


def _is_number(token: str) -> bool:
    try:
        float(token.replace("D", "E").replace("d", "e"))
        return True
    except ValueError:
        return False


def _source_values(table: pd.DataFrame, source: Any, field: str, where: str, path: Path) -> np.ndarray:
    """Values of one mapped column in SI (``field``: its dotted name in the mapping, for errors)."""
    if isinstance(source, ConstantSource):
        return np.full(len(table), source.value)
    source = ColumnSource(column=source) if isinstance(source, str) else source
    if source.column not in table.columns:
        raise TrajectoryFileError(f"{where}: {field}.column = {source.column!r} is not a column of {path}; allowed: "
                                  f"{', '.join(table.columns)}")
    return table[source.column].to_numpy(dtype=float) * source.factor + source.offset


def _crossing(time: np.ndarray, altitude: np.ndarray, level: float) -> float | None:
    index = np.nonzero((altitude[:-1] >= level) & (altitude[1:] < level))[0]
    if not len(index):
        return None
    j = index[0]
    return float(time[j] + (altitude[j] - level) / (altitude[j] - altitude[j + 1]) * (time[j + 1] - time[j]))


def read_post_table(path: str | Path, mapping: PostMapping | dict | str | Path, profile_id: int = 0) -> DescentProfile:
    """Read a POST-style table as one :class:`DescentProfile` through ``mapping`` (see module doc).

    ``mapping`` is a :class:`PostMapping`, a dict, or the path of a TOML file holding ``[columns]``,
    ``[attitude]`` and ``[images]``. Errors name the table file (line) or the mapping field, and what is allowed.
    """
    import pandas as pd

    path = Path(path)
    where = "<mapping>"
    if isinstance(mapping, (str, Path)):
        where = str(mapping)
        mapping = parse(PostMapping, load_toml(mapping), where)
    elif isinstance(mapping, dict):
        mapping = parse(PostMapping, mapping, where)
    table = parse_whitespace_table(path)
    columns = mapping.columns
    euler = mapping.attitude.euler_zyx
    needed = [c for c in REQUIRED_COLUMNS if c != "profile_id" and not (euler is not None and c in _ATTITUDE)]
    missing = [c for c in needed if getattr(columns, c) is None]
    if missing:
        raise TrajectoryFileError(f"{where}: columns.{missing[0]} is missing; every schema column needs a source: "
                                  f"{', '.join(needed)}"
                                  + (" (or [attitude] euler_zyx for the quaternion)" if missing[0] in _ATTITUDE else ""))
    heat = [c for c in HEAT_SHIELD_COLUMNS if getattr(columns, c) is not None]
    if heat and len(heat) != 3:
        absent = [c for c in HEAT_SHIELD_COLUMNS if c not in heat][0]
        raise TrajectoryFileError(f"{where}: columns.{absent} is missing; heat-shield columns come all three or none")
    frame = {"profile_id": np.full(len(table), profile_id, dtype=np.int64)}
    for name in needed + heat:
        frame[name] = _source_values(table, getattr(columns, name), f"columns.{name}", where, path)
    if euler is not None:
        yaw, pitch, roll = (_source_values(table, ColumnSource(column=getattr(euler, k), unit=euler.unit),
                                           f"attitude.euler_zyx.{k}", where, path) for k in ("yaw", "pitch", "roll"))
        quat = quat_multiply(quat_multiply(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), yaw),
                                           quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), pitch)),
                             quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), roll))
        for axis, name in enumerate(_ATTITUDE):
            frame[name] = quat[:, axis]
    images = mapping.images
    if images.altitudes_m is None:      # PostImages gives exactly one of times_s and altitudes_m
        times = np.array(images.times_s)
    else:
        crossings = []
        for level in images.altitudes_m:
            crossing = _crossing(frame["t_s"], frame["z_m"], level)
            if crossing is None:
                raise TrajectoryFileError(f"{where}: images.altitudes_m = {level:g} m is never crossed downward by z_m "
                                          f"in {path} (z_m spans {frame['z_m'].min():.1f}..{frame['z_m'].max():.1f} m)")
            crossings.append(crossing)
        if images.last_after_previous_s is not None:
            crossings.append(crossings[-1] + images.last_after_previous_s)
        times = np.array(crossings)
    for k, value in enumerate(times):
        frame[image_column(k + 1)] = np.full(len(table), float(value))
    return frame_to_profiles(pd.DataFrame(frame), str(path), name_prefix=path.stem)[0]
