"""`campaign export DIR CASE_ID OUT` + `python -m dimes_velocity` replay a campaign case bit for bit.

The campaigns run on the test process's warm cluster (``warm_scheduler``, tests/conftest.py): the replay is
tested, not the cluster's start-up."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from campaign.cli import main
from service_campaigns import REPO, campaign_file, file_tree, run_campaign, stderr_line

pytestmark = [pytest.mark.cluster, pytest.mark.slow]


def test_export_replays_the_reference_answer_bit_for_bit(tmp_path, warm_scheduler):
    store = tmp_path / "store"
    submitted = run_campaign("submit", campaign_file(tmp_path, {"gcp": 2, "gdcp": 1, "gkep": 0}), "--output", store,
                             "--scheduler", warm_scheduler, "--no-progress")
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
                                                         "estimator.toml", "estimators"}
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


PLUGINS = REPO / "tests" / "plugins"
BIAS_MPS = [0.75, -0.5]


def _three_kinds(directory):
    """A Gusev campaign of the reference estimator, a python plug-in and a command plug-in (tests/plugins), each
    with parameters of its own; the command reads npy images and a tiff flat field."""
    estimators = (f'''
[[estimators]]
name = "dimes_tight"
kind = "reference"
parameters = {{ features_per_pair = 6 }}

[[estimators]]
name = "imu_py"
kind = "python"
path = "{PLUGINS}"
callable = "python_estimators:imu_minus_bias"
parameters = {{ bias = {BIAS_MPS} }}

[[estimators]]
name = "imu_cmd"
kind = "command"
argv = ["{{python}}", "{PLUGINS / "command_estimator.py"}", "ok", "{{measurements}}", "{{flat_field}}", "{{parameters}}",
        "{{output}}", "{{images}}"]
image_format = "npy"
flat_field_format = "tiff"
parameters = {{ bias = {BIAS_MPS} }}
''')
    return campaign_file(directory, {"gcp": 1, "gdcp": 1, "gkep": 0}, "workers = 1", extra=estimators)


def _answer(entry: dict, replayed: subprocess.CompletedProcess) -> dict:
    assert replayed.returncode == 0, (entry["replay"], replayed.stderr)
    return json.loads(replayed.stdout) if entry["answer"] == "stdout" else json.loads(Path(entry["answer"]).read_text())


def test_export_replays_every_estimator_kind_bit_for_bit(tmp_path, warm_scheduler):
    store = tmp_path / "store"
    submitted = run_campaign("submit", _three_kinds(tmp_path), "--output", store, "--scheduler", warm_scheduler,
                             "--no-progress")
    assert submitted.returncode == 0, submitted.stderr
    results = pd.read_parquet(store / "results.parquet")
    assert set(results["estimator"]) == {"dimes_tight", "imu_py", "imu_cmd"}
    assert (results["status"] == "ok").all()
    for case_id in sorted(set(results["case_id"].astype(int))):
        out = tmp_path / f"case {case_id}"                      # a space: every path of a replay is quoted
        exported = run_campaign("export", store, str(case_id), out)
        assert exported.returncode == 0, exported.stderr
        truth = json.loads((out / "truth.json").read_text())
        entries = {entry["name"]: entry for entry in truth["estimators"]}
        assert {name: entry["kind"] for name, entry in entries.items()} == \
            {"dimes_tight": "reference", "imu_py": "python", "imu_cmd": "command"}
        printed = [line for line in exported.stdout.splitlines() if line.startswith("replay ")]
        assert len(printed) == 3 and all(line.endswith(entries[line.split()[1]]["replay"]) for line in printed)
        # each estimator's own parameters, as the campaign resolved them
        assert entries["dimes_tight"]["parameters"]["features_per_pair"] == 6
        assert entries["imu_py"]["parameters"] == entries["imu_cmd"]["parameters"] == {"bias": BIAS_MPS}
        assert json.loads((out / "estimators" / "imu_py" / "parameters.json").read_text()) == {"bias": BIAS_MPS}
        assert "features_per_pair = 6" in (out / "estimators" / "dimes_tight" / "estimator.toml").read_text()
        assert sorted(path.suffix for path in (out / "estimators" / "imu_cmd").glob("image*")) == [".npy"] * 3
        assert (out / "estimators" / "imu_cmd" / "flat_field.tif").is_file()
        stored_rows = results[results["case_id"].astype(int) == case_id].set_index("estimator")
        for name, entry in entries.items():
            # run as printed, by a shell, from another directory
            replayed = subprocess.run(entry["replay"], shell=True, capture_output=True, text=True, timeout=300,
                                      cwd=tmp_path)
            answer, stored = _answer(entry, replayed), stored_rows.loc[name]
            assert answer["valid"] == bool(stored["valid"]) and answer["reason"] == stored["reason"], name
            if stored["valid"]:                     # the store keeps the velocity of valid answers only
                assert answer["velocity_east_mps"] == stored["estimate_velocity_east_mps"], name
                assert answer["velocity_north_mps"] == stored["estimate_velocity_north_mps"], name
            features = answer.get("features", [])
            assert [feature["brightness_dn"] for feature in features] == list(stored["feature_brightness"]), name
            assert [feature["contrast_dn"] for feature in features] == list(stored["feature_contrast"]), name
            assert entry["stored"]["valid"] == bool(stored["valid"])
        # the plug-ins' answers are the IMU velocity less the bias: the replays read this case's measurements
        measurements = json.loads((out / "measurements.json").read_text())
        imu = measurements["images"][-1]["imu_velocity_mps"]
        assert stored_rows.loc["imu_py", "estimate_velocity_east_mps"] == imu[0] - BIAS_MPS[0]
        assert stored_rows.loc["imu_cmd", "estimate_velocity_north_mps"] == imu[1] - BIAS_MPS[1]
