"""Bad campaign TOML: one clear line naming file and field, exit code 2, nothing written."""
import subprocess
import sys
from pathlib import Path

import pytest

from campaign.cli import main as campaign_main
from fuzz_inputs import run_main

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"


def _bad_copy(tmp_path: Path, extra: str = "", replace: tuple[str, str] | None = None, text: str | None = None) -> Path:
    source = GUSEV.read_text() if text is None else text
    if replace:
        assert replace[0] in source
        source = source.replace(replace[0], replace[1], 1)
    path = tmp_path / "sitedata" / "bad.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    for sub in ("cameras", "trajectories"):
        link = path.parent / sub
        if not link.exists():
            link.symlink_to(REPO / "sitedata" / sub)
    path.write_text(source + extra)
    return path


@pytest.mark.parametrize("case, expected", [
    ({"text": "[site\nname = 1"}, "invalid TOML"),
    ({"extra": "\n[campaign]\nseed = 1\nsede = 2\n"}, "campaign.sede"),
    ({"extra": "\n[campaign]\nseed = \"one\"\n"}, "campaign.seed"),
    ({"extra": "\n[execution]\nretries = 99\n"}, "execution.retries"),
    ({"extra": "\n[campaign]\nfalse_valid_mps = 0\n"}, "campaign.false_valid_mps"),
    ({"extra": "\n[estimator]\ntemplate_size_px = -3\n"}, "template_size_px"),
    ({"extra": "\n[colour]\nx = 1\n"}, "colour"),
    ({"replace": ("ellipse_fraction = 0.59", "ellipse_fraction = 1.59")}, "ellipse_fraction"),
    ({"replace": ('camera = "cameras/mer_a.toml"', 'camera = "cameras/nope.toml"')}, "nope.toml"),
])
def test_bad_campaign_toml_is_one_line_exit_2_nothing_written(tmp_path, case, expected):
    path = _bad_copy(tmp_path, **case)
    out = tmp_path / "out"
    result = run_main(campaign_main, ["submit", path, "--output", out], tmp_path)   # (a real process: below)
    assert result.code == 2, result.err
    lines = result.err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], lines
    assert not out.exists()


@pytest.mark.slow
def test_missing_file_and_usage_errors_exit_2(tmp_path):
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "submit", str(tmp_path / "none.toml")],
                            capture_output=True, text=True)
    assert result.returncode == 2 and "file not found" in result.stderr
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "submit"], capture_output=True, text=True)
    assert result.returncode == 2
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "status", str(tmp_path)], capture_output=True, text=True)
    assert result.returncode == 2 and "not a campaign directory" in result.stderr


def test_false_valid_threshold_is_read_but_not_hashed(tmp_path):
    from campaign.configuration.campaign_file import load_campaign_config

    default = load_campaign_config(_bad_copy(tmp_path, extra="\n[campaign]\nseed = 1\n"))
    stricter = load_campaign_config(_bad_copy(tmp_path, extra="\n[campaign]\nseed = 1\nfalse_valid_mps = 2.5\n"))
    assert default.false_valid_mps == 5.0 and stricter.false_valid_mps == 2.5
    assert default.config_hash == stricter.config_hash       # a reporting threshold: same results


def test_default_counts_are_the_papers():
    from campaign.configuration.campaign_file import load_campaign_config

    gusev = load_campaign_config(GUSEV)
    assert gusev.cases_per_class == {"gcp": 186, "gdcp": 112, "gkep": 78}
    meridiani = load_campaign_config(REPO / "sitedata" / "meridiani.toml")
    assert meridiani.cases_per_class == {"hbsp": 44, "hdcp": 179, "heb": 31}
    assert gusev.config_hash != meridiani.config_hash


def test_hash_is_of_content_not_of_paths_defaults_or_counts(tmp_path):
    """The same campaign given by an absolute path, from another directory (its input files copied), with
    the default seed written out, or scaled (CLI or TOML) has one hash; a changed input byte does not."""
    import os
    import shutil

    from campaign.configuration.campaign_file import load_campaign_config

    base = load_campaign_config(GUSEV).config_hash
    elsewhere = tmp_path / "copy"
    shutil.copytree(REPO / "sitedata" / "cameras", elsewhere / "cameras")
    shutil.copytree(REPO / "sitedata" / "trajectories", elsewhere / "trajectories")
    copied = elsewhere / "gusev.toml"
    copied.write_text(GUSEV.read_text() + "\n[campaign]\nseed = 1\ncases_scale = 0.25\n")
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        assert load_campaign_config(copied.resolve()).config_hash == base
        assert load_campaign_config(Path("copy/gusev.toml")).config_hash == base
        assert load_campaign_config(GUSEV.resolve(), cases_scale=0.1).config_hash == base
    finally:
        os.chdir(cwd)
    other_seed = copied.read_text().replace("seed = 1\n", "seed = 2\n")
    copied.write_text(other_seed)
    assert load_campaign_config(copied).config_hash != base
    copied.write_text(GUSEV.read_text())
    camera = elsewhere / "cameras" / "mer_a.toml"
    camera.write_text(camera.read_text() + "\n")          # same values, other bytes: another input file
    assert load_campaign_config(copied).config_hash != base


def test_a_sun_distance_left_out_and_one_written_out_are_different_campaigns(tmp_path):
    """Left out, the scene takes the site's heliocentric distance (Gusev 1.478 AU); written out at the
    scene default (1.524 AU) it renders other radiances, so the hash and the manifest's scene differ."""
    from campaign.configuration.campaign_file import load_campaign_config
    from simulator.scene_config import SceneConfig

    default_au = SceneConfig.model_fields["sun_distance_au"].default
    left_out = load_campaign_config(_bad_copy(tmp_path, extra="\n[campaign]\nseed = 1\n"))
    written = load_campaign_config(_bad_copy(tmp_path, extra=f"\n[campaign]\nseed = 1\n[scene]\nsun_distance_au = {default_au}\n"))
    site_au = left_out.site.heliocentric_distance_au
    assert site_au != default_au
    assert left_out.scene.sun_distance_au == site_au and written.scene.sun_distance_au == default_au
    assert left_out.resolved["scene"]["sun_distance_au"] == site_au
    assert written.resolved["scene"]["sun_distance_au"] == default_au
    assert left_out.config_hash != written.config_hash
    same = load_campaign_config(_bad_copy(tmp_path, extra=f"\n[campaign]\nseed = 1\n[scene]\nsun_distance_au = {site_au}\n"))
    assert same.config_hash == left_out.config_hash           # writing the used value out changes nothing
