"""`campaign export DIR CASE_ID OUT` + `python -m dimes_velocity` replay a campaign case bit for bit."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from campaign.cli import main
from service_campaigns import REPO, campaign_file, file_tree, run_campaign, stderr_line

pytestmark = [pytest.mark.cluster, pytest.mark.slow]


def test_export_replays_the_reference_answer_bit_for_bit(tmp_path):
    store = tmp_path / "store"
    submitted = run_campaign("submit", campaign_file(tmp_path, {"gcp": 2, "gdcp": 1, "gkep": 0}), "--output", store,
                             "--workers", "1", "--no-progress")
    assert submitted.returncode == 0, submitted.stderr
    results = pd.read_parquet(store / "results.parquet")
    reference = results[results["estimator"] == "dimes"].set_index("case_id")
    case_ids = [int(case_id) for case_id in reference.index]
    assert len(case_ids) == 3

    for case_id in case_ids:                            # in this process: the exports share its inputs
        assert main(["export", str(store), str(case_id), str(tmp_path / f"case-{case_id}")]) == 0
    replays = {}
    for case_id in case_ids:
        out = tmp_path / f"case-{case_id}"
        assert {path.name for path in out.iterdir()} == {"image_1.png", "image_2.png", "image_3.png",
                                                         "measurements.json", "flat_field.npy", "truth.json",
                                                         "estimator.toml"}
        command = [sys.executable, "-m", "dimes_velocity", *(str(out / f"image_{k}.png") for k in (1, 2, 3)),
                   str(out / "measurements.json"), "--camera", str(REPO / "sitedata" / "cameras" / "mer_a.toml"),
                   "--flat-field", str(out / "flat_field.npy")]
        replays[case_id] = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    for case_id, process in replays.items():
        stdout, stderr = process.communicate(timeout=120)
        assert process.returncode == 0, stderr
        answer, stored = json.loads(stdout), reference.loc[case_id]
        assert answer["valid"] == bool(stored["valid"]) and answer["reason"] == stored["reason"]
        if stored["valid"]:                             # the store keeps a velocity of valid answers only
            assert answer["velocity_east_mps"] == stored["estimate_velocity_east_mps"]
            assert answer["velocity_north_mps"] == stored["estimate_velocity_north_mps"]
        truth = json.loads((tmp_path / f"case-{case_id}" / "truth.json").read_text())
        assert truth["config_hash_matches_store"] and truth["case_id"] == case_id
        assert truth["truth_velocity_east_mps"] == stored["truth_velocity_east_mps"]
        assert truth["truth_velocity_north_mps"] == stored["truth_velocity_north_mps"]
        assert truth["altitude_image3_m"] == stored["altitude_image3_m"]
        assert truth["sensor_errors"]["attitude_bias_east_rad"] == stored["sensor_attitude_bias_east_rad"]
        assert np.isfinite(truth["wind_east_mps"])

    before = file_tree(tmp_path)
    unknown = run_campaign("export", store, "424242", tmp_path / "nowhere")
    assert unknown.returncode == 2 and "case 424242 is not in the plan" in stderr_line(unknown)
    assert file_tree(tmp_path) == before                # nothing written
