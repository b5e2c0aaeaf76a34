"""Trajectory files: schema round trips, one-line errors, POST tables, and the stored sets' statistics."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from config_tables.errors import ConfigError
from flight_interface.frames import quat_from_axis_angle, rotate
from simulator.scene.descent_profile import DescentProfile
from sitedata.edl.post_table import read_post_table
from sitedata.edl.trajectory_io import TrajectoryFileError, profiles_to_frame, read_profiles, write_profiles
from sitedata.edl.trajectory_sets import check_set, compare_sites, main, set_statistics

SETS = Path(__file__).resolve().parents[3] / "sitedata" / "trajectories"
FIELDS = ("time_s", "position_m", "velocity_mps", "attitude_quat", "angular_rate_radps", "wind_mps",
          "heat_shield_position_m", "image_times_s")


def _profile(seed: int, samples: int = 40, heat_shield: bool = True) -> DescentProfile:
    rng = np.random.default_rng(seed)
    time = np.cumsum(rng.uniform(0.01, 0.2, samples))
    velocity = np.column_stack([rng.normal(5, 1, samples), rng.normal(-3, 1, samples), rng.normal(-72, 1, samples)])
    position = np.column_stack([rng.normal(size=(samples, 2)), 2000.0 - 72.0 * (time - time[0])])
    attitude = quat_from_axis_angle(rng.normal(size=(samples, 3)), rng.uniform(0, 0.5, samples))
    return DescentProfile(time, position, velocity, attitude, rng.normal(0, 0.3, (samples, 3)),
                          rng.normal(0, 5, (samples, 3)), position - [50, 10, 160] if heat_shield else None,
                          np.array([time[1], time[samples // 2], time[-2]]), name=f"p{seed}")


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_round_trip_is_exact(tmp_path, suffix):
    profiles = [_profile(1), _profile(2, samples=7)]
    path = write_profiles(tmp_path / f"set{suffix}", profiles, profile_ids=[10, 4])
    back = read_profiles(path)
    assert [p.name for p in back] == ["set-0010", "set-0004"]
    for a, b in zip(profiles, back):
        for field in FIELDS:
            assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_compact_files_keep_float32_precision_and_no_heat_shield_round_trips(tmp_path):
    profiles = [_profile(3, heat_shield=False)]
    back = read_profiles(write_profiles(tmp_path / "c.parquet", profiles, compact=True))[0]
    assert back.heat_shield_position_m is None
    assert np.array_equal(back.position_m, profiles[0].position_m)  # full precision columns
    np.testing.assert_allclose(back.velocity_mps, profiles[0].velocity_mps, rtol=6e-8)
    np.testing.assert_allclose(back.attitude_quat, profiles[0].attitude_quat, atol=6e-8)


def _write_frame(tmp_path, frame: pd.DataFrame, name="bad.csv") -> Path:
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("edit, message", [
    (lambda f: f.drop(columns=["qw"]), r"bad.csv: column 'qw' is missing; required columns: profile_id, t_s"),
    (lambda f: f.assign(t_s=f.t_s.where(f.index != 5, f.t_s[3])), r"bad.csv: row 6 column 't_s' = .* does not follow .*"
     r"allowed: strictly increasing"),
    (lambda f: f.assign(vx_mps=f.vx_mps.where(f.index != 8, np.nan)), r"bad.csv: row 9 column 'vx_mps' = .* is not a "
     r"finite number; allowed: finite numbers"),
    (lambda f: f.assign(qw=f.qw.where(f.index != 2, f.qw * 1.01)), r"bad.csv: row 3 columns qw,qx,qy,qz have norm "
     r"1\.0\d+; allowed: unit quaternions, \|norm - 1\| <= 1e-06"),
    (lambda f: f.assign(extra_m=1.0), r"bad.csv: unknown column 'extra_m'; allowed:"),
    (lambda f: f.drop(columns=["heat_shield_y_m"]), r"column 'heat_shield_y_m' is missing; heat-shield columns come all"),
    (lambda f: f.assign(image2_t_s=f.image2_t_s.where(f.index != 4, 0.77)), r"row 5 column 'image2_t_s' = 0.77 differs"),
    (lambda f: f.assign(image3_t_s=1e3), r"image times .* allowed: strictly increasing, inside"),
    (lambda f: f.drop(columns=["image2_t_s"]), r"image time columns .* are not image1_t_s..imageK_t_s"),
    (lambda f: f.assign(profile_id=np.where(f.index < 45, 0, np.where(f.index < 60, 1, 0))),
     r"row 61 column 'profile_id' = 0 starts a second block \(first at row 1\)"),
    (lambda f: f.assign(y_m=f.y_m.astype(object).where(f.index != 1, "north")), r"row 2 column 'y_m' = 'north' is not a finite"),
])
def test_schema_errors_are_one_line_and_name_row_and_column(tmp_path, edit, message):
    frame = profiles_to_frame([_profile(1), _profile(2)])
    path = _write_frame(tmp_path, edit(frame))
    with pytest.raises(TrajectoryFileError, match=message) as caught:
        read_profiles(path)
    assert "\n" not in str(caught.value)


def test_unreadable_files_get_a_clear_error(tmp_path):
    good = write_profiles(tmp_path / "good.parquet", [_profile(1)])
    truncated = tmp_path / "truncated.parquet"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(TrajectoryFileError, match=r"truncated.parquet: cannot be read as parquet"):
        read_profiles(truncated)
    with pytest.raises(TrajectoryFileError, match=r"missing.csv: file not found"):
        read_profiles(tmp_path / "missing.csv")
    with pytest.raises(TrajectoryFileError, match=r"allowed: .parquet, .csv"):
        read_profiles(good.rename(tmp_path / "good.txt"))
    assert issubclass(TrajectoryFileError, ConfigError)


POST_TABLE = """# POST run, English units
! east/north/alt in ft, velocities in ft/s, angles in deg
TIME  EAST   NORTH  ALT      VE    VN   VD     PSI  THT  PHI  P   Q  R  WE  WN
0.0   0.0    0.0    6700.0   32.8  0.0  236.22 90.0 0.0  0.0  0.0 0  0  9   1
1.0D0 32.8   0.0    6463.78  32.8  0.0  236.22 90.0 0.0  0.0  0.0 0  0  9   1
2.0   65.6   0.0    6227.56  32.8  0.0  236.22 90.0 0.0  0.0  0.0 0  0  9   1
3.0   98.4   0.0    5991.34  32.8  0.0  236.22 90.0 0.0  0.0  0.0 0  0  9   1
"""


def _mapping():
    return {"columns": {
        "t_s": "TIME", "x_m": {"column": "EAST", "unit": "ft"}, "y_m": {"column": "NORTH", "unit": "ft"},
        "z_m": {"column": "ALT", "unit": "ft", "offset": -10.0}, "vx_mps": {"column": "VE", "unit": "ft/s"},
        "vy_mps": {"column": "VN", "unit": "ft/s"}, "vz_mps": {"column": "VD", "scale": -0.3048},
        "wx_radps": {"column": "P", "unit": "deg/s"}, "wy_radps": "Q", "wz_radps": "R",
        "wind_east_mps": "WE", "wind_north_mps": "WN", "wind_up_mps": {"value": 0.0}},
        "attitude": {"euler_zyx": {"yaw": "PSI", "pitch": "THT", "roll": "PHI", "unit": "deg"}},
        "images": {"altitudes_m": [2000.0, 1900.0], "last_after_previous_s": 0.5}}


def test_post_table_maps_units_euler_angles_and_image_altitudes(tmp_path):
    path = tmp_path / "run.post"
    path.write_text(POST_TABLE)
    profile = read_post_table(path, _mapping())
    np.testing.assert_allclose(profile.position_m[1], [32.8 * 0.3048, 0.0, 6463.78 * 0.3048 - 10.0])
    np.testing.assert_allclose(profile.velocity_mps[0], [32.8 * 0.3048, 0.0, -72.0], atol=1e-3)
    # altitude falls linearly at 72.0 m/s from 6700 ft - 10 m: crossing times in closed form
    z0, rate = 6700 * 0.3048 - 10.0, 236.22 * 0.3048
    np.testing.assert_allclose(profile.image_times_s, [(z0 - 2000) / rate, (z0 - 1900) / rate, (z0 - 1900) / rate + 0.5],
                               atol=1e-9)
    # yaw 90 deg turns body x to north
    np.testing.assert_allclose(rotate(profile.attitude_quat[0], [1.0, 0, 0]), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(profile.wind_mps[0], [9.0, 1.0, 0.0])


@pytest.mark.parametrize("change, message", [
    (lambda m: m["columns"].pop("vy_mps"), r"<mapping>: columns.vy_mps is missing"),
    (lambda m: m["columns"].update(x_m={"column": "EAST", "unit": "ft/s"}), r"columns.x_m.unit = 'ft/s' is not allowed; allowed: m, km, ft, kft"),
    (lambda m: m["columns"].update(x_m="EASTING"), r"columns.x_m.column = 'EASTING' is not a column of .*run.post"),
    (lambda m: m["images"].update(altitudes_m=[2000.0, 900.0]), r"images.altitudes_m = 900 m is never crossed"),
    (lambda m: m["columns"].update(typo_m="EAST"), r"<mapping>: columns.typo_m is not a known field; allowed: t_s, x_m"),
])
def test_post_mapping_errors_name_the_field(tmp_path, change, message):
    path = tmp_path / "run.post"
    path.write_text(POST_TABLE)
    mapping = _mapping()
    change(mapping)
    with pytest.raises(ConfigError, match=message):
        read_post_table(path, mapping)


@pytest.mark.parametrize("text, message", [
    (POST_TABLE.replace("32.8  0.0  236.22 90.0 0.0  0.0  0.0 0  0  9   1\n2.0", "32.8  0.0  236.22 90.0\n2.0"),
     r"run.post: line 5: 8 values but the header has 15 columns"),
    (POST_TABLE.replace("98.4", "9B.4"), r"run.post: line 7 column 'EAST': '9B.4' is not a number"),
])
def test_post_table_errors_name_the_line(tmp_path, text, message):
    path = tmp_path / "run.post"
    path.write_text(text)
    with pytest.raises(TrajectoryFileError, match=message):
        read_post_table(path, _mapping())


@pytest.fixture(scope="module")
def stored_statistics():
    return {site: set_statistics(SETS / f"{site}.parquet") for site in ("gusev", "meridiani")}


def test_stored_sets_meet_the_paper_ranges(stored_statistics):
    for site, minimum in (("gusev", 376), ("meridiani", 254)):
        stats = stored_statistics[site]
        assert len(stats) >= minimum  # enough distinct trajectories for the paper's campaign
        failed = [row for row in check_set(stats) if not row[-1]]
        assert not failed, (site, failed)
        assert stats["off_nadir_max_deg"].max() > 15.0  # the envelope is exercised, not trivially met
    assert all(row[-1] for row in compare_sites(stored_statistics["gusev"], stored_statistics["meridiani"]))
    assert (SETS / "gusev.parquet").stat().st_size < 5.5e6


def test_check_set_flags_a_set_outside_the_ranges(stored_statistics):
    stats = stored_statistics["meridiani"].copy()
    stats.loc[0, "roll_max_deg"] = 50.0
    failed = [row[0] for row in check_set(stats) if not row[-1]]
    assert failed == ["roll max (deg)"]


def test_stats_command_prints_and_passes(capsys):
    assert main(["stats"]) == 0
    out = capsys.readouterr().out
    assert "off-nadir max (deg)" in out and "all checks passed" in out
