"""POST-style whitespace tables mapped onto the trajectory schema of :mod:`sitedata.trajectory_io`.

A POST (Program to Optimize Simulated Trajectories) or similar tool prints a table: optional comment
lines (starting with ``#`` or ``!``), one header line naming the columns, then rows of numbers
separated by whitespace (Fortran ``1.0D+03`` exponents accepted). A *mapping* (dict or
:class:`~flight_interface.tomlfields.Table`, e.g. a TOML file) says which source column feeds each schema
column and how to convert it to SI::

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
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from simulator.scene.descent_profile import DescentProfile
from flight_interface.frames import quat_from_axis_angle, quat_multiply
from flight_interface.tomlfields import Table, load_toml

from .trajectory_io import HEAT_SHIELD_COLUMNS, REQUIRED_COLUMNS, TrajectoryFileError, frame_to_profiles, image_column

UNITS = {  # unit: (kind, scale to SI)
    "m": ("length", 1.0), "km": ("length", 1e3), "ft": ("length", 0.3048), "kft": ("length", 304.8),
    "s": ("time", 1.0), "ms": ("time", 1e-3),
    "m/s": ("speed", 1.0), "km/s": ("speed", 1e3), "ft/s": ("speed", 0.3048),
    "rad": ("angle", 1.0), "deg": ("angle", np.pi / 180.0),
    "rad/s": ("rate", 1.0), "deg/s": ("rate", np.pi / 180.0), "1": ("none", 1.0),
}
_ATTITUDE = ("qw", "qx", "qy", "qz")


def _kind(schema_column: str) -> str:
    for suffix, kind in (("_radps", "rate"), ("_mps", "speed"), ("_t_s", "time"), ("_s", "time"), ("_m", "length")):
        if schema_column.endswith(suffix):
            return kind
    return "none"


def parse_whitespace_table(path: str | Path) -> pd.DataFrame:
    """Header + whitespace-separated numbers -> DataFrame of float64 (errors name file and line)."""
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


def _source_values(table: pd.DataFrame, spec: Table, key: str, kind: str, source: str) -> np.ndarray:
    """Values of one mapped column in SI."""
    spec.ignore(key)
    entry = spec.data[key]
    if isinstance(entry, str):
        entry_table = Table({"column": entry}, spec.source, f"{spec.path}.{key}" if spec.path else key)
    elif isinstance(entry, dict):
        entry_table = spec.table(key)
    else:
        raise spec.fail(key, f"= {entry!r} is not a mapping; allowed: \"SOURCE\", {{column, unit | scale, offset}} "
                        "or {value}")
    if entry_table.has("value"):
        value = entry_table.number("value")
        entry_table.reject_unknown()
        return np.full(len(table), value)
    column = entry_table.string("column")
    if column not in table.columns:
        raise entry_table.fail("column", f"= {column!r} is not a column of {source}; allowed: {', '.join(table.columns)}")
    if entry_table.has("unit") and entry_table.has("scale"):
        raise entry_table.fail("unit", "and scale both given; allowed: one of them")
    scale = 1.0
    if entry_table.has("unit"):
        unit = entry_table.string("unit", choices=[u for u, (k, _) in UNITS.items() if k == kind] or ["1"])
        scale = UNITS[unit][1]
    elif entry_table.has("scale"):
        scale = entry_table.number("scale")
    offset = entry_table.number("offset", default=0.0)
    entry_table.reject_unknown()
    return table[column].to_numpy(dtype=float) * scale + offset


def _crossing(time: np.ndarray, altitude: np.ndarray, level: float) -> float | None:
    index = np.nonzero((altitude[:-1] >= level) & (altitude[1:] < level))[0]
    if not len(index):
        return None
    j = index[0]
    return float(time[j] + (altitude[j] - level) / (altitude[j] - altitude[j + 1]) * (time[j + 1] - time[j]))


def read_post_table(path: str | Path, mapping: Table | dict | str | Path, profile_id: int = 0) -> DescentProfile:
    """Read a POST-style table as one :class:`DescentProfile` through ``mapping`` (see module doc).

    ``mapping`` is a Table, a dict, or the path of a TOML file holding ``[columns]``, ``[attitude]``
    and ``[images]``. Errors name the table file (line) or the mapping field, and what is allowed.
    """
    path = Path(path)
    if isinstance(mapping, (str, Path)):
        mapping = Table(load_toml(mapping), str(mapping))
    elif isinstance(mapping, dict):
        mapping = Table(mapping, "<mapping>")
    table = parse_whitespace_table(path)
    columns = mapping.table("columns")
    attitude = mapping.table("attitude", required=False)
    euler = attitude.has("euler_zyx")
    needed = [c for c in REQUIRED_COLUMNS if c != "profile_id" and not (euler and c in _ATTITUDE)]
    missing = [c for c in needed if not columns.has(c)]
    if missing:
        raise columns.fail(missing[0], f"is missing; every schema column needs a source: {', '.join(needed)}"
                           + (" (or [attitude] euler_zyx for the quaternion)" if missing[0] in _ATTITUDE else ""))
    heat = [c for c in HEAT_SHIELD_COLUMNS if columns.has(c)]
    if heat and len(heat) != 3:
        raise columns.fail([c for c in HEAT_SHIELD_COLUMNS if c not in heat][0], "is missing; heat-shield columns come "
                           "all three or none")
    frame = {"profile_id": np.full(len(table), profile_id, dtype=np.int64)}
    for name in needed + heat:
        frame[name] = _source_values(table, columns, name, _kind(name), str(path))
    if euler:
        angles = attitude.table("euler_zyx")
        unit = angles.string("unit", default="rad", choices=("rad", "deg"))
        yaw, pitch, roll = (_source_values(table, Table({"a": {"column": angles.string(k), "unit": unit}}, angles.source,
                                                        angles.path), "a", "angle", str(path)) for k in ("yaw", "pitch", "roll"))
        angles.reject_unknown()
        quat = quat_multiply(quat_multiply(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), yaw),
                                           quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), pitch)),
                             quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), roll))
        for axis, name in enumerate(_ATTITUDE):
            frame[name] = quat[:, axis]
    images = mapping.table("images")
    if images.has("times_s") == images.has("altitudes_m"):
        raise images.fail("times_s", "and altitudes_m: give exactly one of them")
    if images.has("times_s"):
        values = images.data["times_s"]
        if not isinstance(values, list) or not values:
            raise images.fail("times_s", f"must be a non-empty list of numbers; got {values!r}")
        times = images.vector("times_s", len(values))
    else:
        levels = images.data["altitudes_m"]
        if not isinstance(levels, list) or not levels:
            raise images.fail("altitudes_m", f"must be a non-empty list of numbers; got {levels!r}")
        crossings = []
        for level in images.vector("altitudes_m", len(levels)):
            crossing = _crossing(frame["t_s"], frame["z_m"], level)
            if crossing is None:
                raise images.fail("altitudes_m", f"= {level:g} m is never crossed downward by z_m in {path} "
                                  f"(z_m spans {frame['z_m'].min():.1f}..{frame['z_m'].max():.1f} m)")
            crossings.append(crossing)
        if images.has("last_after_previous_s"):
            crossings.append(crossings[-1] + images.number("last_after_previous_s", minimum=0.0, exclusive_minimum=True))
        times = np.array(crossings)
    mapping.reject_unknown()
    for k, value in enumerate(times):
        frame[image_column(k + 1)] = np.full(len(table), float(value))
    return frame_to_profiles(pd.DataFrame(frame), str(path), name_prefix=path.stem)[0]
