"""The full Gusev campaign end to end (376 cases) on the embedded LocalCluster: wall time (budget 60 s),
including cluster start, and ms per case from the stored stage timings."""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[1]


def run() -> list[dict]:
    out = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    try:
        start = time.perf_counter()
        result = subprocess.run([sys.executable, "-m", "campaign.cli", "submit", str(REPO / "sitedata" / "gusev.toml"),
                                 "--output", str(out), "--no-progress"], capture_output=True, text=True, cwd=REPO)
        wall_s = time.perf_counter() - start
        if result.returncode != 0:
            return [{"name": "campaign/gusev_full", "error": result.stderr.strip().splitlines()[-1:]}]
        print(result.stdout)
        results = pd.read_parquet(out / "results.parquet")
        timings = pd.read_parquet(out / "timings.parquet")
        return [{
            "name": "campaign/gusev_full", "cases": len(results), "wall_s": wall_s, "budget_s": 60.0,
            "valid_pct": 100.0 * results["valid"].mean(),
            "ms_per_case_median": float(timings["t_case_ms"].median()),
            "scene_ms_median": float(timings["t_scene_ms"].median()),
            "camera_ms_median": float(timings["t_camera_ms"].median()),
            "estimator_ms_median": float(timings["t_estimator_ms"].median()),
        }]
    finally:
        shutil.rmtree(out, ignore_errors=True)
