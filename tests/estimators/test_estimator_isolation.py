"""Isolation in a real campaign (one dask worker process, so every case shares the worker's cached flat
field and camera): python plug-ins listed before the reference that write into the images, the flat field,
a measurement and the camera, call ``sys.exit(3)``, raise ``KeyboardInterrupt`` or answer 1e30 m/s each get failed
rows with their reason; the run finishes with every case, and the reference's rows are bit for bit those
of a campaign without the plug-ins (same seed)."""
from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
import pytest

from service_campaigns import REPO, campaign_file, run_campaign

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"
CASES = {"gcp": 1, "gdcp": 1, "gkep": 0}
BAD = {   # name -> (callable in tests/plugins/python_estimators.py, reason, text in the error)
    "halves_image": ("halves_image", "estimator_failed", "crashed: ValueError: output array is read-only"),
    "scales_flat": ("scales_flat", "estimator_failed", "crashed: ValueError: output array is read-only"),
    "changes_imu": ("changes_imu", "estimator_failed", "crashed: ValueError: assignment destination is read-only"),
    "changes_camera": ("changes_camera", "estimator_failed",
                       "crashed: ValueError: assignment destination is read-only"),
    "exits": ("exits", "estimator_failed", "crashed: SystemExit(3)"),
    "interrupts": ("interrupts", "estimator_failed", "crashed: KeyboardInterrupt()"),
    "too_fast": ("too_fast", "implausible", "implausible: horizontal speed 1e+30 m/s of a valid answer is not below"),
}


def _submit(config: Path, out: Path):
    env = {"PYTHONPATH": os.pathsep.join(filter(None, [str(PLUGINS), str(REPO), os.environ.get("PYTHONPATH")]))}
    return run_campaign("submit", config, "--output", out, "--workers", 1, "--no-progress", env=env)


def test_bad_plugins_fail_their_own_rows_and_leave_the_reference_rows_bit_identical(tmp_path):
    alone = _submit(campaign_file(tmp_path / "alone", CASES), tmp_path / "alone" / "out")
    assert alone.returncode == 0, alone.stdout + alone.stderr
    entries = "".join(f'\n[[estimators]]\nname = "{name}"\nkind = "python"\n'
                      f'callable = "python_estimators:{target}"\n' for name, (target, _, _) in BAD.items())
    entries += '\n[[estimators]]\nname = "dimes"\nkind = "reference"\n'
    config = campaign_file(tmp_path / "bad", CASES, extra=entries)
    bad = _submit(config, tmp_path / "bad" / "out")
    assert bad.returncode in (0, 1) and "Traceback" not in bad.stderr and "killed" not in bad.stderr.lower(), (
        bad.stdout + bad.stderr)
    results = pd.read_parquet(tmp_path / "bad" / "out" / "results.parquet")
    assert results.groupby("case_id")["estimator"].apply(list).tolist() == [[*BAD, "dimes"]] * 2
    for name, (_, reason, message) in BAD.items():
        rows = results[results["estimator"] == name]
        assert set(rows["status"]) == {"failed"} and set(rows["reason"]) == {reason}, rows[["status", "reason"]]
        assert rows["error"].str.contains(message, regex=False).all(), rows["error"].tolist()
        assert not rows["valid"].any()
    reference = pd.read_parquet(tmp_path / "alone" / "out" / "results.parquet")
    assert set(reference["status"]) == {"ok"}
    kept = results[results["estimator"] == "dimes"].reset_index(drop=True)
    pd.testing.assert_frame_equal(kept[reference.columns], reference.reset_index(drop=True), check_exact=True)
