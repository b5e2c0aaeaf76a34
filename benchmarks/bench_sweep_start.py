"""How soon a large sweep starts computing: ``sweep/2000_points_first_batch``.

A sweep of 2000 grid points (one Gusev case each) runs as ``campaign sweep`` in its own process (its own
embedded LocalCluster of one worker), from launch until its first case file exists, then gets SIGINT as a
user's Ctrl-C. Point stores are prepared as the sweep reaches them, so the first batch of points should be
submitted within seconds: target <= 10 s from launch to the progress line of the first batch
(``sweep: points p000-p003 ...``). Also reported: the first progress line and the first case file (s).
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.targets import target_columns

REPO = Path(__file__).resolve().parents[1]
GUSEV = REPO / "sitedata" / "gusev.toml"
ONE_CASE = "[sweep.cases]\ngcp = 1\ngdcp = 0\ngkep = 0\n"
FIRST_BATCH_TARGET_S = 10.0
WIDE_AXES = {"scene.camera_effects.dark_current_scale": [1.0 + i for i in range(40)],
             "sensors.attitude_random_sigma_deg": [0.01 + 0.01 * i for i in range(50)]}


def sweep_file(path: Path, axes: dict) -> Path:
    """A sweep of the Gusev site, one gcp case per point, over ``axes`` (field -> values)."""
    lines = [f'"{field}" = [{", ".join(repr(v) for v in values)}]' for field, values in axes.items()]
    path.write_text(f'[sweep]\nbase = "{GUSEV}"\n{ONE_CASE}[axes]\n' + "\n".join(lines) + "\n")
    return path


def start_and_interrupt(sweep: Path, out: Path, limit_s: float = 180.0) -> tuple[list, float | None, int, int]:
    """Run `campaign sweep` until its first case file exists, then SIGINT it. Returns the stderr lines with
    their times (s since launch), the time of the first case file, the point stores then, and the exit status."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-c", "import sys; from campaign.cli import main; sys.exit(main())",
                                "sweep", str(sweep), "--output", str(out), "--workers", "1"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
                               start_new_session=True)
    lines: list[tuple[float, str]] = []
    stderr = process.stderr
    assert stderr is not None                   # stderr=PIPE

    def read() -> None:
        for line in stderr:
            lines.append((time.perf_counter() - start, line.rstrip()))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    first_case, stores = None, 0
    while time.perf_counter() - start < limit_s and process.poll() is None:
        if any(out.glob("points/*/cases/??/batch-*.parquet")):
            first_case = time.perf_counter() - start
            stores = sum(1 for _ in out.glob("points/*/manifest.json"))
            break
        time.sleep(0.1)
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGINT)
    try:
        code = process.wait(60)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        code = process.wait()
    reader.join(10)
    return lines, first_case, stores, code


def first_batch_s(lines: list) -> float:
    """Seconds from launch to the progress line of the first batch (NaN when there is none)."""
    times = [at for at, line in lines if re.match(r"sweep: points p000-p\d+ \(\d+ of \d+\): 0 cases done", line)]
    return times[0] if times else float("nan")


def run() -> list[dict]:
    root = Path(tempfile.mkdtemp(prefix="bench-sweep-start-"))
    lines, first_case, stores, _ = start_and_interrupt(sweep_file(root / "wide.toml", WIDE_AXES), root / "out")
    return [{"name": "sweep/2000_points_first_batch", "points": 2000,
             "first_line_s": lines[0][0] if lines else float("nan"),
             "first_case_s": first_case if first_case is not None else float("nan"), "stores_at_first_case": stores,
             **target_columns(first_batch_s(lines), FIRST_BATCH_TARGET_S, "s")}]
