"""A campaign file built on a base file (``base = "gusev"`` or a path): key-by-key merging, paths resolved
against the file that wrote them, and one-line errors naming the file at fault (exit 2)."""
import hashlib
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from campaign.configuration.base_files import shipped_sites
from campaign.configuration.campaign_file import load_campaign_config
from config_tables.errors import ConfigError

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_shipped_site_by_name_is_the_site_file_itself(tmp_path):
    """`base = "gusev"` from any directory: the same campaign (same configuration hash, same input files) as
    sitedata/gusev.toml itself, whose camera and trajectory set resolve against sitedata/, not the new file."""
    mine = _write(tmp_path / "elsewhere" / "mine.toml", 'base = "gusev"\n')
    config, shipped = load_campaign_config(mine), load_campaign_config(GUSEV)
    assert config.config_hash == shipped.config_hash
    assert config.site.camera_path.samefile(REPO / "sitedata" / "cameras" / "mer_a.toml")
    assert config.site.trajectory_path.samefile(REPO / "sitedata" / "trajectories" / "gusev.parquet")
    assert {"gusev", "meridiani"} <= set(shipped_sites())


def test_relative_paths_resolve_against_the_file_that_wrote_them(tmp_path):
    """A site file in sites/ with its own cameras/ and trajectories/, built on from campaigns/: the site's
    relative paths are the site file's, the campaign's own `path` is the campaign file's."""
    site_dir = tmp_path / "sites"
    (site_dir / "cam").mkdir(parents=True)
    (site_dir / "traj").mkdir()
    shutil.copy(REPO / "sitedata" / "cameras" / "mer_a.toml", site_dir / "cam" / "a.toml")
    shutil.copy(REPO / "sitedata" / "trajectories" / "gusev.parquet", site_dir / "traj" / "g.parquet")
    text = GUSEV.read_text().replace('"cameras/mer_a.toml"', '"cam/a.toml"').replace(
        '"trajectories/gusev.parquet"', '"traj/g.parquet"')
    _write(site_dir / "site.toml", text)
    mine = _write(tmp_path / "campaigns" / "deep" / "mine.toml", 'base = "../../sites/site.toml"\n')
    config = load_campaign_config(mine)
    assert config.site.camera_path.samefile(site_dir / "cam" / "a.toml")
    assert config.site.trajectory_path.samefile(site_dir / "traj" / "g.parquet")
    # the same bytes as the shipped site's files: the same campaign
    assert _sha256(config.site.camera_path) == _sha256(REPO / "sitedata" / "cameras" / "mer_a.toml")
    assert config.config_hash == load_campaign_config(GUSEV).config_hash


def test_tables_merge_key_by_key_and_arrays_are_replaced(tmp_path):
    """Three files: each table merges key by key through the chain; [[site.classes]] is replaced whole."""
    _write(tmp_path / "middle.toml", 'base = "gusev"\n[campaign]\nseed = 7\n'
           '[sensors]\nradar_altitude_sigma_percent = 0.5\n')
    mine = _write(tmp_path / "mine.toml", '''base = "middle.toml"
[sensors]
attitude_random_sigma_deg = 0.2
[site.sun]
elevation_deg = 40.0
[[site.classes]]
name = "plains"
ellipse_fraction = 1.0
cases = 9
terrain = { kind = "synthetic", preset = "gcp", seed = 5 }
''')
    config = load_campaign_config(mine)
    assert config.seed == 7                                              # from the middle file
    assert config.sensors.radar_altitude_sigma_percent == 0.5            # the middle file's key stays
    assert config.sensors.attitude_random_sigma_deg == 0.2               # the top file's key is added
    assert [entry.name for entry in config.site.classes] == ["plains"]   # an array is replaced whole
    assert config.cases_per_class == {"plains": 9}
    assert config.site.sun.elevation_deg == 40.0                         # [site.sun] merged key by key:
    assert config.site.sun.azimuth_deg == 268.0 and config.site.name == "Gusev"    # the rest stays gusev's


def test_merged_case_counts(tmp_path):
    """[campaign.cases] of the base and of the file merge key by key (the classes stay the site's)."""
    _write(tmp_path / "middle.toml", 'base = "gusev"\n[campaign.cases]\ngcp = 5\n')
    mine = _write(tmp_path / "mine.toml", 'base = "middle.toml"\n[campaign.cases]\ngdcp = 3\n')
    assert load_campaign_config(mine).cases_per_class == {"gcp": 5, "gdcp": 3, "gkep": 78}


@pytest.mark.parametrize("files, top, expected", [
    ({"mine.toml": 'base = "nope.toml"\n'}, "mine.toml",
     "mine.toml: base = 'nope.toml': no such file"),
    ({"mine.toml": 'base = "gusevv"\n'}, "mine.toml",
     "mine.toml: base = 'gusevv' is not a shipped site; allowed: a shipped site (gusev, meridiani"),
    ({"mine.toml": 'base = 3\n'}, "mine.toml", "mine.toml: base = 3 is not a file name; allowed:"),
    ({"a.toml": 'base = "sub/b.toml"\n', "sub/b.toml": 'base = "../a.toml"\n'}, "a.toml",
     "b.toml: base = '../a.toml' makes a cycle ("),
    ({"a.toml": 'base = "a.toml"\n'}, "a.toml", "a.toml: base = 'a.toml' makes a cycle ("),
    ({"mine.toml": "[campaign]\nseed = 1\n"}, "mine.toml", 'or base = "gusev" to build on a shipped site'),
])
def test_base_errors_are_one_line_naming_the_file(tmp_path, files, top, expected):
    for name, text in files.items():
        _write(tmp_path / name, text)
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(tmp_path / top)
    assert expected in str(caught.value) and "\n" not in str(caught.value), str(caught.value)


def test_a_field_the_base_wrote_is_blamed_on_the_base(tmp_path):
    """The error names the file that wrote the bad value, reached through the campaign file."""
    site = _write(tmp_path / "sites" / "site.toml",
                  GUSEV.read_text().replace("seed = 4102", "seed = -4"))
    for sub in ("cameras", "trajectories"):
        (site.parent / sub).symlink_to(REPO / "sitedata" / sub)
    mine = _write(tmp_path / "mine.toml", 'base = "sites/site.toml"\n[campaign]\nseed = 2\n')
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(mine)
    assert str(caught.value).startswith(f"{site} (base of {mine}): site.classes[1].terrain.seed = -4 is out of range")
    bad_top = _write(tmp_path / "top.toml", 'base = "sites/site.toml"\n[campaign]\nsede = 2\n')
    site.write_text(GUSEV.read_text())
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(bad_top)
    assert str(caught.value).startswith(f"{bad_top}: campaign.sede is not a known field")


def test_command_line_exit_2_for_a_missing_base_and_a_cycle(tmp_path):
    _write(tmp_path / "missing.toml", 'base = "../nowhere/site.toml"\n')
    _write(tmp_path / "a.toml", 'base = "b.toml"\n')
    _write(tmp_path / "b.toml", 'base = "a.toml"\n')
    for name, expected in (("missing.toml", "base = '../nowhere/site.toml': no such file"), ("a.toml", "makes a cycle")):
        done = subprocess.run([sys.executable, "-m", "campaign.cli", "plan", str(tmp_path / name)], cwd=tmp_path,
                              capture_output=True, text=True, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
        assert done.returncode == 2 and expected in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_a_copied_site_file_says_how_to_build_on_it_instead(tmp_path):
    """The copy's camera path is relative to the copy, so it breaks; the line says so and names `base`."""
    copy = tmp_path / "copied.toml"
    shutil.copy(GUSEV, copy)
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(copy)
    text = str(caught.value)
    assert text.startswith(f"{copy}: site.camera = 'cameras/mer_a.toml': no such file {tmp_path / 'cameras' / 'mer_a.toml'}")
    assert 'write base = "gusev" (a shipped site)' in text and "\n" not in text
