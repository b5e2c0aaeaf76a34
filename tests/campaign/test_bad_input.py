"""Bad input that used to give a traceback or silence: now one line naming file and field, exit 2, nothing
written (issue 16, "Bad input" bullet). Real files, the real CLIs (in-process through ``main(argv)`` and as
subprocesses)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from campaign.cli import main as campaign_main
from config_tables.errors import ConfigError
from flight_interface.camera import load_camera
from fuzz_inputs import run_main
from sitedata.edl.post_table import read_post_table
from sitedata.edl.trajectory_io import TrajectoryFileError, read_profiles

REPO = Path(__file__).resolve().parents[2]
SITEDATA = REPO / "sitedata"
GUSEV = SITEDATA / "gusev.toml"


def tree(root: Path) -> dict:
    """Every path under ``root`` with its size and modification time (what "nothing written" compares)."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else None
            for p in sorted(root.rglob("*"))} if root.exists() else {}


def campaign(capsys, *argv) -> tuple[int, str, str]:
    code = campaign_main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# ------------------------------------------------------------------------------------------ TOML files
def _unreadable(tmp_path: Path) -> Path:
    loop = tmp_path / "loop.toml"
    loop.symlink_to(loop)                       # ELOOP: unreadable even for root (chmod 000 is not)
    return loop


def _latin1(tmp_path: Path) -> Path:
    path = tmp_path / "latin1.toml"
    path.write_bytes("[site]\nname = \"G\xfcsev\"\n".encode("latin-1"))
    return path


def _folder(tmp_path: Path) -> Path:
    path = tmp_path / "folder.toml"
    path.mkdir()
    return path


@pytest.mark.parametrize("make, expected", [
    (_latin1, "is not UTF-8 text"), (_folder, "is a directory"), (_unreadable, "cannot be read"),
    (lambda d: d / "absent.toml", "file not found"),
])
def test_unusable_campaign_file_is_one_line_exit_2_nothing_written(tmp_path, make, expected):
    path = make(tmp_path)
    out = tmp_path / "out"
    before = tree(tmp_path)
    result = run_main(campaign_main, ["submit", path, "--output", out], tmp_path)   # real processes: below
    assert result.code == 2
    line = one_line(result.err)
    assert str(path) in line and expected in line
    assert tree(tmp_path) == before


@pytest.fixture()
def existing_store(tmp_path) -> Path:
    """A directory that looks like a campaign store (any write to it would show in its tree)."""
    store = tmp_path / "store"
    (store / "cases").mkdir(parents=True)
    (store / "manifest.json").write_text('{"config_hash": "0"}')
    return store


@pytest.mark.parametrize("flags, expected", [
    (["--cases-scale", "nan"], "--cases-scale = nan is not finite; allowed: > 0 and <= 100"),
    (["--cases-scale", "inf"], "--cases-scale = inf is not finite"),
    (["--cases-scale", "0"], "--cases-scale = 0 is out of range; allowed: > 0 and <= 100"),
    (["--cases-scale", "-1"], "--cases-scale = -1 is out of range"),
    (["--cases-scale", "1e9"], "--cases-scale = 1e+09 is out of range"),
    (["--workers", "-3"], "--workers = -3 is out of range; allowed: >= 0 and <= 1024"),
    (["--scheduler", "localhost:8786"], "--scheduler = 'localhost:8786' is not a scheduler address"),
])
def test_bad_flags_are_refused_before_the_store_is_touched(existing_store, capsys, flags, expected):
    before = tree(existing_store)
    code, out, err = campaign(capsys, "submit", GUSEV, "--output", existing_store, "--no-progress", *flags)
    assert code == 2 and out == ""
    assert expected in one_line(err) and "command line" in err
    assert tree(existing_store) == before


def test_bad_flag_through_a_real_process(existing_store):
    before = tree(existing_store)
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "submit", str(GUSEV), "--output", str(existing_store),
                             "--cases-scale", "nan"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode == 2 and "--cases-scale = nan is not finite" in one_line(result.stderr)
    assert tree(existing_store) == before


# ---------------------------------------------------------------------------------------------- camera
def test_misspelt_camera_key_is_refused_not_zero_distortion(tmp_path, mer_a_path, capsys):
    text = mer_a_path.read_text()
    assert "radial_distortion = [0.0, -0.01, 0.0]" in text
    bad = tmp_path / "camera.toml"
    bad.write_text(text.replace("radial_distortion", "radial_distorsion"))
    with pytest.raises(ConfigError, match=r"camera.toml: geometry.radial_distorsion is not a known field; allowed: "
                                          r"focal_length_m, principal_point_px, radial_distortion, cahvor"):
        load_camera(bad)
    code, out, err = campaign(capsys, "camera", bad)
    assert code == 2 and out == "" and "geometry.radial_distorsion" in one_line(err)
    # unknown tables and keys anywhere in the file, too
    bad.write_text(text + "\n[lens]\nf_number = 12.0\n")
    with pytest.raises(ConfigError, match=r"lens is not a known field"):
        load_camera(bad)
    bad.write_text(text.replace("[electronics]", "[electronics]\nread_noise = 5.0"))
    with pytest.raises(ConfigError, match=r"electronics.read_noise is not a known field"):
        load_camera(bad)


# ---------------------------------------------------------------------------------------- trajectories
def _set_frame(profiles: int = 2) -> pd.DataFrame:
    frame = pq.read_table(SITEDATA / "trajectories" / "gusev.parquet").to_pandas()
    return frame[frame.profile_id < profiles].reset_index(drop=True)


def test_two_image_times_are_refused_at_load(tmp_path):
    path = tmp_path / "two.csv"
    _set_frame().drop(columns=["image3_t_s"]).to_csv(path, index=False)
    with pytest.raises(TrajectoryFileError, match=r"two.csv: image time columns image1_t_s, image2_t_s give 2 images; "
                                                  r"allowed: image1_t_s, image2_t_s, image3_t_s \(3 images\)"):
        read_profiles(path)
    assert len(read_profiles(path, image_count=None)[0].image_times_s) == 2       # the schema itself allows K >= 1


def test_lander_below_ground_while_imaging_is_refused_at_load(tmp_path):
    frame = _set_frame()
    first = frame[frame.profile_id == 1]
    inside = first[(first.t_s > first.image1_t_s) & (first.t_s < first.image3_t_s)].index[5]
    frame.loc[inside, "z_m"] = -2.0
    path = tmp_path / "deep.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(TrajectoryFileError, match=rf"deep.csv: row {inside + 1} column 'z_m' = -2.0 is at or below the "
                                                  r"ground while imaging; allowed: > 0"):
        read_profiles(path)
    # below ground only after the last image (e.g. touchdown rows) is allowed
    frame = _set_frame()
    last = frame[frame.profile_id == 0].index[-1]
    frame.loc[last, "z_m"] = -1.0
    frame.to_csv(path, index=False)
    assert len(read_profiles(path)) == 2


def _site_with_trajectory(tmp_path: Path, trajectory: Path) -> Path:
    text = GUSEV.read_text().replace('"cameras/mer_a.toml"', f'"{SITEDATA / "cameras" / "mer_a.toml"}"')
    path = tmp_path / "site.toml"
    path.write_text(text.replace('"trajectories/gusev.parquet"', f'"{trajectory}"'))
    return path


@pytest.mark.parametrize("edit, expected", [
    (lambda f: f.drop(columns=["image3_t_s"]), "give 2 images"),
    (lambda f: f.assign(z_m=f.z_m - 1800.0), "is at or below the ground while imaging"),
])
def test_campaign_with_a_bad_trajectory_set_exits_2_before_any_case(tmp_path, capsys, edit, expected):
    trajectory = tmp_path / "set.csv"
    edit(_set_frame()).to_csv(trajectory, index=False)
    site = _site_with_trajectory(tmp_path, trajectory)
    before = tree(tmp_path)
    code, out, err = campaign(capsys, "submit", site, "--output", tmp_path / "out", "--no-progress")
    assert code == 2 and out == ""
    line = one_line(err)
    assert str(trajectory) in line and expected in line
    assert tree(tmp_path) == before


POST = """TIME ALT
0.0 2100.0
1.0 2028.0
2.0 1956.0
9.0 1452.0
"""


def test_post_mapping_with_two_images_is_refused(tmp_path):
    table = tmp_path / "run.post"
    table.write_text(POST)
    columns = {name: {"value": 0.0} for name in ("x_m", "y_m", "vx_mps", "vy_mps", "qx", "qy", "qz", "wx_radps",
                                                   "wy_radps", "wz_radps", "wind_east_mps", "wind_north_mps",
                                                   "wind_up_mps")}
    columns.update(t_s="TIME", z_m="ALT", vz_mps={"value": -72.0}, qw={"value": 1.0})
    mapping = {"columns": columns, "images": {"altitudes_m": [2000.0, 1725.0]}}
    with pytest.raises(ConfigError, match=r"<mapping>: images.altitudes_m gives 2 image times; allowed: 3"):
        read_post_table(table, mapping)
    mapping["images"]["last_after_previous_s"] = 3.75
    profile = read_post_table(table, mapping)
    np.testing.assert_allclose(profile.image_times_s, [100 / 72, 375 / 72, 375 / 72 + 3.75], atol=1e-9)
    mapping["columns"]["z_m"] = {"column": "ALT", "offset": -1500.0}
    mapping["images"] = {"times_s": [1.0, 2.0, 8.5]}
    with pytest.raises(TrajectoryFileError, match=r"is at or below the ground while imaging"):
        read_post_table(table, mapping)


def test_no_traceback_when_run_from_an_unwritable_place(tmp_path):
    """Errors are reported before the working directory is used: a bad file given from a read-only
    directory still gives the one line (the default output directory is never created)."""
    readonly = tmp_path / "ro"
    readonly.mkdir()
    os.chmod(readonly, 0o555)
    try:
        result = subprocess.run([sys.executable, "-m", "campaign.cli", "plan", str(GUSEV), "--cases-scale", "-1"],
                                capture_output=True, text=True, cwd=readonly, timeout=120,
                                env={**os.environ, "PYTHONPATH": str(REPO)})
    finally:
        os.chmod(readonly, 0o755)
    assert result.returncode == 2 and "--cases-scale = -1 is out of range" in one_line(result.stderr)
    assert list(readonly.iterdir()) == []
