"""Trajectory files: the documented schema for sets of descent profiles, and its readers and writers.

Schema (one row per time sample; Parquet ``.parquet`` or CSV ``.csv`` with a header row)
-----------------------------------------------------------------------------------------
Frames and conventions of :mod:`flight_interface.frames`: world x east, y north, z up, ground z = 0;
attitude = lander body-to-world unit quaternion ``(w, x, y, z)``, Hamilton, body z up the lander axis.

===================  =====================================================================
column               meaning (unit in the name)
===================  =====================================================================
profile_id           integer id of the profile; a profile's rows are contiguous
t_s                  time (s), strictly increasing within a profile
x_m, y_m, z_m        lander body origin in the world frame (m); z is the altitude
vx_mps vy_mps vz_mps lander velocity, world frame (m/s)
qw qx qy qz          attitude, body-to-world unit quaternion (|q| within 1e-6 of 1; kept as stored)
wx_radps wy_radps    angular rate in the *body* frame (rad/s)
wz_radps
wind_east_mps        steady-state wind (truth, no gusts), world frame (m/s)
wind_north_mps
wind_up_mps
heat_shield_x_m      optional (all three or none): heat-shield centre, world frame (m)
heat_shield_y_m
heat_shield_z_m
image1_t_s ...       start of exposure of image k (s, same clock as t_s), k = 1..K consecutive (K = 3,
imageK_t_s           the DIMES images, unless a reader asks otherwise); constant within a profile,
                     strictly increasing, inside the profile's span
===================  =====================================================================

Any numeric column type is accepted (read as float64). :func:`write_profiles` with
``compact=True`` (used for the stored sets) keeps ``t_s``, ``x_m``, ``y_m``, ``z_m`` and the image
times in float64 and stores the other columns as float32 (relative precision 6e-8: 0.1 mm at 2 km,
quaternion components to 3e-8): about half the file size.

The image times are per-profile metadata stored as constant columns, so the one table works in
both formats (Parquet's dictionary/RLE encoding makes the repetition free). Other columns are
refused (a typo would otherwise silently drop data). The lander must be above the ground (``z_m > 0``)
while it images: at every row from the last one at or before image 1 to the first one at or after
image K, and at each image time. Every reader error is one line naming the file, the row (data rows
counted from 1, header excluded) and column, and what is allowed.

POST-style whitespace tables are read by :mod:`sitedata.edl.post_table`, which maps them onto this schema.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from config_tables.errors import ConfigError
from simulator.scene.descent_profile import DescentProfile

if TYPE_CHECKING:
    import pandas as pd

# pandas and pyarrow are imported by the functions that read and write tables: a site or parameter file that
# names a trajectory file (and `campaign schema`) does not load them.

QUATERNION_NORM_TOLERANCE = 1e-6
#: Images per profile of a DIMES trajectory (three descent images).
DIMES_IMAGE_COUNT = 3
VECTOR_COLUMNS = {
    "position_m": ("x_m", "y_m", "z_m"),
    "velocity_mps": ("vx_mps", "vy_mps", "vz_mps"),
    "attitude_quat": ("qw", "qx", "qy", "qz"),
    "angular_rate_radps": ("wx_radps", "wy_radps", "wz_radps"),
    "wind_mps": ("wind_east_mps", "wind_north_mps", "wind_up_mps"),
}
HEAT_SHIELD_COLUMNS = ("heat_shield_x_m", "heat_shield_y_m", "heat_shield_z_m")
REQUIRED_COLUMNS = ("profile_id", "t_s") + tuple(c for cols in VECTOR_COLUMNS.values() for c in cols)


class TrajectoryFileError(ConfigError):
    """A trajectory file is unreadable or breaks the schema (one-line message)."""


def _plain(value):
    """A numpy scalar as the Python value (for readable error messages)."""
    return value.item() if hasattr(value, "item") else value


def image_column(k: int) -> str:
    """Name of the column holding image ``k``'s time (k counted from 1)."""
    return f"image{k}_t_s"


# ---------------------------------------------------------------------------------------------- write
def profiles_to_frame(profiles: Sequence[DescentProfile], profile_ids: Sequence[int] | None = None) -> pd.DataFrame:
    """The schema table of ``profiles`` (ids default to 0..n-1)."""
    import pandas as pd

    if not profiles:
        raise ValueError("profiles_to_frame: no profiles")
    ids = list(range(len(profiles))) if profile_ids is None else [int(i) for i in profile_ids]
    if len(ids) != len(profiles) or len(set(ids)) != len(ids):
        raise ValueError("profiles_to_frame: profile_ids must be unique, one per profile")
    image_count = len(profiles[0].image_times_s)
    heat = profiles[0].heat_shield_position_m is not None
    for profile in profiles:
        if len(profile.image_times_s) != image_count or (profile.heat_shield_position_m is not None) != heat:
            raise ValueError(f"profiles_to_frame: profile {profile.name} differs from the first in image count "
                             "or heat-shield presence; a file holds profiles of one shape")
    columns: dict[str, np.ndarray] = {
        "profile_id": np.concatenate([np.full(len(p.time_s), i, dtype=np.int64) for p, i in zip(profiles, ids)]),
        "t_s": np.concatenate([p.time_s for p in profiles]).astype(float),
    }
    for field, names in VECTOR_COLUMNS.items():
        stacked = np.concatenate([np.asarray(getattr(p, field), dtype=float) for p in profiles])
        for axis, name in enumerate(names):
            columns[name] = np.ascontiguousarray(stacked[:, axis])
    if heat:
        stacked = np.concatenate([p.heat_shield_position_m for p in profiles])
        for axis, name in enumerate(HEAT_SHIELD_COLUMNS):
            columns[name] = np.ascontiguousarray(stacked[:, axis])
    for k in range(image_count):
        columns[image_column(k + 1)] = np.concatenate([np.full(len(p.time_s), float(p.image_times_s[k]))
                                                       for p in profiles])
    return pd.DataFrame(columns)


FULL_PRECISION_COLUMNS = ("profile_id", "t_s", "x_m", "y_m", "z_m")


def compact_frame(frame: pd.DataFrame) -> pd.DataFrame:
    """The table with every column but ``FULL_PRECISION_COLUMNS`` and image times cast to float32."""
    return frame.astype({name: np.float32 for name in frame.columns
                         if name not in FULL_PRECISION_COLUMNS and not name.startswith("image")})


def write_profiles(path: str | Path, profiles: Sequence[DescentProfile],
                   profile_ids: Sequence[int] | None = None, compact: bool = False) -> Path:
    """Write profiles to ``path`` (``.parquet``: zstd, byte-stream-split floats; ``.csv``: shortest
    round-trip decimal text). ``compact``: see :func:`compact_frame`. Same profiles -> same bytes
    (for a given pyarrow / pandas version)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    frame = profiles_to_frame(profiles, profile_ids)
    if compact:
        frame = compact_frame(frame)
    if path.suffix == ".parquet":
        table = pa.Table.from_pandas(frame, preserve_index=False).replace_schema_metadata(None)
        floats = [name for name in frame.columns if name != "profile_id" and not name.startswith("image")]
        pq.write_table(table, path, compression="zstd", compression_level=9, use_dictionary=False,
                       use_byte_stream_split=floats, write_statistics=False)
    elif path.suffix == ".csv":
        frame.to_csv(path, index=False, lineterminator="\n")
    else:
        raise ValueError(f"{path}: unknown trajectory file type {path.suffix!r}; allowed: .parquet, .csv")
    return path


# ----------------------------------------------------------------------------------------------- read
def read_profiles(path: str | Path, image_count: int | None = DIMES_IMAGE_COUNT) -> list[DescentProfile]:
    """Read and validate a trajectory file; profiles named ``<file stem>-<profile_id:04d>``, in file order.
    ``image_count``: the number of image time columns required (None: any K >= 1)."""
    import pandas as pd
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise TrajectoryFileError(f"{path}: file not found")
    try:
        if path.suffix == ".parquet":
            frame = pq.read_table(path).to_pandas()
        elif path.suffix == ".csv":
            # pandas >= 3 parses CSV floats round-trip exactly by default (and deprecates the option)
            options = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
            frame = pd.read_csv(path, **options)
        else:
            raise TrajectoryFileError(f"{path}: unknown trajectory file type {path.suffix!r}; allowed: .parquet, .csv")
    except TrajectoryFileError:
        raise
    except Exception as exc:  # pyarrow / pandas parse errors: one line naming the file
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise TrajectoryFileError(f"{path}: cannot be read as {path.suffix[1:]}: {message}") from None
    return frame_to_profiles(frame, str(path), name_prefix=path.stem, image_count=image_count)


def _image_columns(frame: pd.DataFrame, source: str, image_count: int | None) -> list[str]:
    names = [c for c in frame.columns if c.startswith("image") and c.endswith("_t_s")]
    expected = [image_column(k + 1) for k in range(len(names))]
    if not names or sorted(names) != sorted(expected):
        raise TrajectoryFileError(f"{source}: image time columns {sorted(names) or 'none'} are not "
                                  f"image1_t_s..imageK_t_s; allowed: image1_t_s, image2_t_s, ... (K >= 1, consecutive)")
    if image_count is not None and len(names) != image_count:
        raise TrajectoryFileError(f"{source}: image time columns {', '.join(expected)} give {len(names)} images; "
                                  f"allowed: {', '.join(image_column(k + 1) for k in range(image_count))} "
                                  f"({image_count} images)")
    return expected


def _check_above_ground(profile: DescentProfile, start: int, source: str) -> None:
    """The lander above the ground (z > 0) while imaging (rows bracketing the images, and at the images)."""
    time, altitude = profile.time_s, profile.position_m[:, 2]
    first = max(int(np.searchsorted(time, profile.image_times_s[0], side="right")) - 1, 0)
    last = min(int(np.searchsorted(time, profile.image_times_s[-1], side="left")), len(time) - 1)
    low = np.nonzero(altitude[first:last + 1] <= 0.0)[0]
    if len(low):
        row = first + int(low[0])
        raise TrajectoryFileError(f"{source}: row {start + row + 1} column 'z_m' = {float(altitude[row])!r} is at or "
                                  "below the ground while imaging; allowed: > 0 (ground is z = 0)")
    for k, image_time in enumerate(profile.image_times_s):
        height = float(profile.pose(float(image_time)).position_m[2])
        if not height > 0.0:
            raise TrajectoryFileError(f"{source}: row {start + 1} column {image_column(k + 1)!r}: the lander is at "
                                      f"z = {height:.3f} m at image {k + 1}; allowed: > 0 (above the ground)")


def frame_to_profiles(frame: pd.DataFrame, source: str, name_prefix: str = "profile",
                      image_count: int | None = DIMES_IMAGE_COUNT) -> list[DescentProfile]:
    """Validate a schema table and split it into profiles (errors name ``source``, row and column);
    ``image_count`` image time columns are required (None: any K >= 1)."""
    import pandas as pd

    missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
    if missing:
        raise TrajectoryFileError(f"{source}: column {missing[0]!r} is missing"
                                  f"{f' (and {len(missing) - 1} more)' if len(missing) > 1 else ''}; "
                                  f"required columns: {', '.join(REQUIRED_COLUMNS)}, image1_t_s..")
    images = _image_columns(frame, source, image_count)
    heat = [c for c in HEAT_SHIELD_COLUMNS if c in frame.columns]
    if heat and len(heat) != 3:
        absent = [c for c in HEAT_SHIELD_COLUMNS if c not in heat][0]
        raise TrajectoryFileError(f"{source}: column {absent!r} is missing; heat-shield columns come all three or none")
    known = set(REQUIRED_COLUMNS) | set(images) | set(HEAT_SHIELD_COLUMNS)
    unknown = [c for c in frame.columns if c not in known]
    if unknown:
        raise TrajectoryFileError(f"{source}: unknown column {unknown[0]!r}; allowed: {', '.join(REQUIRED_COLUMNS)}, "
                                  f"{', '.join(HEAT_SHIELD_COLUMNS)}, image1_t_s..imageK_t_s")
    if len(frame) < 2:
        raise TrajectoryFileError(f"{source}: {len(frame)} data rows; allowed: at least 2 per profile")
    values: dict[str, np.ndarray] = {}
    for name in list(REQUIRED_COLUMNS) + heat + images:
        column = frame[name]
        numeric = pd.to_numeric(column, errors="coerce").to_numpy(dtype=np.float64)
        bad = np.nonzero(~np.isfinite(numeric))[0]
        if len(bad):
            row = int(bad[0])
            raise TrajectoryFileError(f"{source}: row {row + 1} column {name!r} = {_plain(column.iloc[row])!r} is not a finite "
                                      "number; allowed: finite numbers")
        values[name] = numeric
    ids = values["profile_id"]
    fractional = np.nonzero(ids != np.round(ids))[0]
    if len(fractional):
        raise TrajectoryFileError(f"{source}: row {fractional[0] + 1} column 'profile_id' = {float(ids[fractional[0]])!r} "
                                  "is not an integer; allowed: integers")
    starts = np.concatenate([[0], np.nonzero(np.diff(ids))[0] + 1])
    ends = np.concatenate([starts[1:], [len(ids)]])
    block_ids = ids[starts]
    if len(np.unique(block_ids)) != len(block_ids):
        seen: dict[float, int] = {}
        for start, pid in zip(starts, block_ids):
            if pid in seen:
                raise TrajectoryFileError(f"{source}: row {start + 1} column 'profile_id' = {int(pid)} starts a second "
                                          f"block (first at row {seen[pid] + 1}); allowed: each profile's rows contiguous")
            seen[pid] = start
    time = values["t_s"]
    same_profile = np.diff(ids) == 0
    backwards = np.nonzero(same_profile & (np.diff(time) <= 0))[0]
    if len(backwards):
        row = int(backwards[0]) + 1
        raise TrajectoryFileError(f"{source}: row {row + 1} column 't_s' = {float(time[row])!r} does not follow "
                                  f"{float(time[row - 1])!r} (profile_id {int(ids[row])}); allowed: strictly increasing "
                                  "t_s within each profile")
    quat = np.stack([values[c] for c in VECTOR_COLUMNS["attitude_quat"]], axis=1)
    norm = np.sqrt(np.sum(quat * quat, axis=1))
    off = np.nonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)[0]
    if len(off):
        row = int(off[0])
        raise TrajectoryFileError(f"{source}: row {row + 1} columns qw,qx,qy,qz have norm {norm[row]:.9g}; allowed: "
                                  f"unit quaternions, |norm - 1| <= {QUATERNION_NORM_TOLERANCE:g}")
    profiles = []
    for start, end in zip(starts, ends):
        pid = int(ids[start])
        if end - start < 2:
            raise TrajectoryFileError(f"{source}: profile_id {pid} has {end - start} row (row {start + 1}); "
                                      "allowed: at least 2 rows per profile")
        image_times = np.array([values[c][start] for c in images])
        for c in images:
            changed = np.nonzero(values[c][start:end] != values[c][start])[0]
            if len(changed):
                raise TrajectoryFileError(f"{source}: row {start + changed[0] + 1} column {c!r} = {float(values[c][start + changed[0]])!r} "
                                          f"differs from the profile's first row ({float(values[c][start])!r}); allowed: one value per profile")
        if np.any(np.diff(image_times) <= 0) or image_times[0] < time[start] or image_times[-1] > time[end - 1]:
            raise TrajectoryFileError(f"{source}: row {start + 1} image times {image_times.tolist()} (profile_id {pid}); "
                                      f"allowed: strictly increasing, inside [{float(time[start])!r}, {float(time[end - 1])!r}] s")
        block = slice(start, end)

        def stack(names: Sequence[str]) -> np.ndarray:
            return np.stack([values[n][block] for n in names], axis=1)  # noqa: B023 - called in this iteration

        profile = DescentProfile(
            time_s=time[block].copy(), position_m=stack(VECTOR_COLUMNS["position_m"]),
            velocity_mps=stack(VECTOR_COLUMNS["velocity_mps"]),
            attitude_quat=quat[block], angular_rate_radps=stack(VECTOR_COLUMNS["angular_rate_radps"]),
            wind_mps=stack(VECTOR_COLUMNS["wind_mps"]), heat_shield_position_m=stack(HEAT_SHIELD_COLUMNS) if heat else None,
            image_times_s=image_times, name=f"{name_prefix}-{pid:04d}")
        _check_above_ground(profile, start, source)
        profiles.append(profile)
    return profiles
