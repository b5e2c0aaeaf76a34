"""No command writes a file the user did not ask for: `python -m campaign.realism.measure_terrains` prints
its table and writes a CSV only with ``--csv FILE`` (a subprocess in an empty working directory, with the
terrain cache elsewhere)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[3]


def _tile(directory: Path) -> str:
    """A 400 x 400 PNG of DN 140-160 with its side-car (5 m/px, I/F = 0.001 DN): measured without a site's
    synthetic strips, so the run takes a second."""
    directory.mkdir()
    dn = np.random.default_rng(3).integers(140, 161, (400, 400), dtype=np.uint8)
    Image.fromarray(dn).save(directory / "tile.png")
    (directory / "tile.toml").write_text("metres_per_pixel = 5.0\ndn_to_if_scale = 0.001\n")
    return f"{directory / 'tile.png'}:{directory / 'tile.toml'}"


def _run(*args: str, cwd: Path, cache: Path) -> subprocess.CompletedProcess:
    env = {"PYTHONPATH": str(REPO), "PATH": os.environ.get("PATH", "/usr/bin:/bin"), "MOC2DIMES_CACHE": str(cache),
           "HOME": str(cache), "MPLCONFIGDIR": str(cache / "mpl")}
    return subprocess.run([sys.executable, "-m", "campaign.realism.measure_terrains", *args], cwd=cwd,
                          capture_output=True, text=True, env=env, timeout=300)


def test_terrain_stats_prints_and_leaves_an_empty_working_directory_empty(tmp_path):
    source = _tile(tmp_path / "inputs")
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    result = _run(source, cwd=cwd, cache=tmp_path / "cache")
    assert result.returncode == 0, result.stderr
    assert "tile.png + tile.toml" in result.stdout and "contrast 1 km" in result.stdout
    assert "wrote" not in result.stdout
    assert sorted(os.listdir(cwd)) == []


def test_terrain_stats_writes_the_csv_asked_for_and_nothing_else(tmp_path):
    source = _tile(tmp_path / "inputs")
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    result = _run(source, "--csv", "table.csv", cwd=cwd, cache=tmp_path / "cache")
    assert result.returncode == 0, result.stderr
    assert sorted(os.listdir(cwd)) == ["table.csv"]
    lines = (cwd / "table.csv").read_text().splitlines()
    assert len(lines) == 2 and lines[1].startswith("tile.png + tile.toml")
    bad = _run(source, "--csv", str(cwd / "no_such_dir" / "t.csv"), cwd=cwd, cache=tmp_path / "cache")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--csv" in bad.stderr, bad.stderr
    assert "Traceback" not in bad.stderr
