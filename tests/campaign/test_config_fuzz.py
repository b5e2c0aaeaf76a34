"""Fuzz suite: every bad input to every configuration file and command-line flag gives ONE line on stderr,
exit status 2, nothing on stdout and nothing written (issue 16, "Done when").

* Files (campaign, camera, sweep, trajectory-set and terrain side-car TOMLs) are generated from the JSON
  Schema of each kind walked over a complete valid example (tests/fuzz_inputs.py): unknown keys, dropped
  keys, tables replaced by scalars, wrong TOML types, values beyond the bounds, non-finite numbers,
  strings outside an enum; plus broken encodings and syntax (hypothesis picks the positions). Trajectory
  data files get schema violations (two images, below ground, NaN, text, missing/unknown columns...).
  Each file goes through every command that reads it.
* Flags of ``campaign submit/plan/status/table/report/sweep/camera/schema``, ``python -m dimes_velocity``,
  ``python -m sitedata.edl.trajectory_sets`` and ``python -m file_formats.planetary.inspect_files`` are drawn by hypothesis
  (derandomized: the same inputs every run).

Most runs are in-process through each CLI's ``main(argv)``; a sample goes through real subprocesses. The
number of bad inputs tried is printed in the test summary (``fuzz:`` line).
"""
from __future__ import annotations

import copy
import json
import math
import subprocess
import sys
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from campaign.cli import main as campaign_main
from campaign.configuration.campaign_file import load_campaign_config
from campaign.configuration.estimators import EstimatorTable
from campaign.configuration.execution import ExecutionConfig
from campaign.configuration.schemas import SCHEMA_TABLES, table_schema
from campaign.configuration.sweep_file import load_sweep
from campaign.realism.compare_flight import load_flight
from campaign.realism.measure_terrains import main as terrain_stats_main
from config_tables.errors import ConfigError
from dimes_velocity.__main__ import main as dimes_main
from file_formats.planetary.inspect_files import main as readers_main
from flight_interface.camera import load_camera
from fuzz_inputs import refusal_problems, run_main, schema_mutations, snapshot, toml_text, with_value
from simulator.scene_config import SceneConfig
from simulator.sensors import SensorConfig
from sitedata.edl.parameters import load_edl_parameters
from sitedata.edl.trajectory_io import read_profiles
from sitedata.edl.trajectory_sets import main as trajectories_main

REPO = Path(__file__).resolve().parents[2]
SITEDATA = REPO / "sitedata"
TRIED: Counter = Counter()
FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A complete, valid set of input files in a scratch directory (the fuzz mutates copies of them)."""
    root = tmp_path_factory.mktemp("fuzz")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MOC2DIMES_CACHE", str(root / "cache"))
        frame = pq.read_table(SITEDATA / "trajectories" / "gusev.parquet").to_pandas()
        frame[frame.profile_id < 2].to_csv(root / "set.csv", index=False)
        pixels = (np.random.default_rng(0).random((64, 64)) * 200).astype(np.uint8)
        Image.fromarray(pixels).save(root / "img.png")
        (root / "img.toml").write_text("metres_per_pixel = 3.0\nincidence_deg = 30.0\nemission_deg = 0.0\n"
                                       "phase_deg = 30.0\ndn_to_if_scale = 0.001\ndn_to_if_offset = 0.0\n"
                                       "band_index = 0\n[crop]\nfirst_row = 0\nfirst_col = 0\nrows = 64\ncols = 64\n")
        (root / "camera.toml").write_text((SITEDATA / "cameras" / "mer_a.toml").read_text())
        campaign = tomllib.loads((SITEDATA / "gusev.toml").read_text())
        campaign["site"].update(camera=str(root / "camera.toml"), trajectory_set=str(root / "set.csv"))
        campaign["site"]["classes"][1]["terrain"]["overrides"] = {"haze_optical_depth": 0.3,
                                                                  "track_width_m": [10.0, 30.0], "rows": 256}
        campaign["site"]["classes"].append({"name": "strip", "ellipse_fraction": 0.0, "cases": 1, "terrain": {
            "kind": "file", "path": "img.png", "sidecar": "img.toml"}})
        campaign.update(campaign={"seed": 3, "output_dir": "runs/fuzz", "cases": {"gcp": 2}, "cases_scale": 0.5},
                        execution=ExecutionConfig(workers=1).model_dump(mode="json"),
                        sensors=SensorConfig().model_dump(mode="json"),
                        estimator=EstimatorTable(flat_field="none").model_dump(mode="json"),
                        estimators=[{"name": "dimes", "kind": "reference", "parameters": {"min_correlation": 0.75}},
                                    {"name": "pc", "kind": "python", "callable": "estimators.phase_correlation:estimate",
                                     "isolate": True, "timeout_s": 30.0, "parameters": {"min_response": 0.05}}],
                        scene=SceneConfig().model_dump(mode="json"))
        (root / "campaign.toml").write_text(toml_text(campaign))
        strip = copy.deepcopy(campaign)
        strip["site"]["classes"] = [dict(campaign["site"]["classes"][-1], ellipse_fraction=1.0)]
        strip["campaign"]["cases"] = {}
        (root / "strip.toml").write_text(toml_text(strip))
        sweep = {"sweep": {"base": str(root / "campaign.toml"), "output_dir": "runs/sweep", "mode": "grid",
                           "cases_scale": 0.5, "cases": {"gkep": 0}},
                 "axes": {"scene.camera_effects.dark_current_scale": [1.0, 2.0], "sensors.perfect": [True, False]},
                 "tolerances": {"pct_valid_drop_points": 5.0, "error_increase_mps": 0.5}}
        (root / "sweep.toml").write_text(toml_text(sweep))
        edl = tomllib.loads((SITEDATA / "trajectories" / "edl_gusev.toml").read_text())
        edl["set"]["output"] = str(root / "generated.parquet")
        (root / "edl.toml").write_text(toml_text(edl))
        measurements = {"sun_direction_world": [0.0, 0.5, 0.8], "images": [
            {"time_s": float(t), "attitude_quat": [1.0, 0.0, 0.0, 0.0], "radar_altitude_m": 2000.0 - 72 * t,
             "imu_velocity_mps": [0.0, 0.0, -72.0]} for t in (0.0, 3.8, 7.6)]}
        (root / "meas.json").write_text(json.dumps(measurements))
        for k in range(3):
            np.save(root / f"im{k}.npy", np.full((256, 1024), 500, dtype=np.uint16))
        flight = {"site": "campaign.toml", "class": "gdcp", "seed": 2, "column": 300, "output_dir": "runs/flight",
                  "scene": {"fidelity": "fast", "atmosphere": {"orbital_optical_depth": 0.3}},
                  "estimator": {"min_correlation": 0.8},
                  "images": [{"file": "im0.npy", "time_s": 0.0, "position_m": [0.0, 0.0, 2000.0],
                              "attitude_quat": [1.0, 0.0, 0.0, 0.0], "velocity_mps": [0.0, 0.0, -72.0],
                              "angular_rate_radps": [0.0, 0.01, 0.0], "heat_shield_position_m": [0.0, 0.0, 1850.0]},
                             {"file": "im1.npy", "time_s": 3.8, "position_m": [0.0, 0.0, 1726.4],
                              "attitude_quat": [1.0, 0.0, 0.0, 0.0]}]}
        (root / "flight.toml").write_text(toml_text(flight))
        # every example is valid as written: what the fuzz changes is what makes an input bad
        load_campaign_config(root / "campaign.toml")
        load_campaign_config(root / "strip.toml")
        load_sweep(root / "sweep.toml")
        load_edl_parameters(root / "edl.toml")
        load_camera(root / "camera.toml")
        load_flight(root / "flight.toml")
        assert len(read_profiles(root / "set.csv")) == 2
        yield root


def refused(work: Path, main, argv: list, kind: str, what: str) -> None:
    before = snapshot(work)
    outcome = run_main(main, argv, work)
    problems = refusal_problems(outcome, before, snapshot(work))
    TRIED[kind] += 1
    assert not problems, f"{kind}: {what}: {problems}"


def _mutated(work: Path, name: str, text: str | bytes, suffix: str = ".toml") -> Path:
    path = work / "mutated" / f"{name}{suffix}"
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def _guard(loader, path: Path, what: str) -> None:
    """The schema says the input is bad: the library loader must refuse it (else the schema and the
    loader disagree, and running the command on it would do real work)."""
    try:
        loader(path)
    except ConfigError:
        return
    pytest.fail(f"{path.name}: accepted although the schema forbids it: {what}")


def _file_commands(kind: str, path: Path) -> list[tuple]:
    """(main, argv) of every command that reads a file of ``kind``."""
    images = ["im0.npy", "im1.npy", "im2.npy", "meas.json"]
    if kind == "terrain_sidecar":               # also as the side-car of a campaign's file terrain
        work = next(parent for parent in path.parents if (parent / "strip.toml").is_file())
        campaign = tomllib.loads((work / "strip.toml").read_text())
        campaign["site"]["classes"][0]["terrain"]["sidecar"] = str(path)
        strip = work / "mutated" / f"strip-{path.stem}.toml"
        strip.write_text(toml_text(campaign))
        return [(readers_main, ["img.png", "--sidecar", path]), (campaign_main, ["plan", strip, "--out", "maps"]),
                (campaign_main, ["submit", strip, "--output", "out", "--no-progress"]),
                (terrain_stats_main, [f"img.png:{path}", "--csv", "stats.csv"])]
    return {
        "campaign_file": [(campaign_main, ["submit", path, "--output", "out", "--no-progress"]),
                          (campaign_main, ["plan", path, "--out", "maps"])],
        "camera": [(campaign_main, ["camera", path]), (dimes_main, [*images, "--camera", path])],
        "sweep": [(campaign_main, ["sweep", path, "--output", "out", "--no-progress"])],
        "trajectory_set": [(trajectories_main, ["verify", path]), (trajectories_main, ["stats", path])],
        "flight": [(campaign_main, ["compare-flight", path, "--out", "out"])],
    }[kind]


EXAMPLES = {"campaign_file": "campaign.toml", "camera": "camera.toml", "sweep": "sweep.toml",
            "trajectory_set": "edl.toml", "terrain_sidecar": "img.toml", "flight": "flight.toml"}
LOADERS = {"campaign_file": load_campaign_config, "camera": load_camera, "sweep": load_sweep,
           "trajectory_set": load_edl_parameters, "terrain_sidecar": None, "flight": load_flight}


@pytest.mark.parametrize("kind", list(EXAMPLES))
def test_every_schema_violation_of_every_file_is_refused(work, kind):
    """Slow by design for the campaign file (over 60 s in a loaded suite run): every schema violation of the
    file, some two thousand, each loaded and refused; their number is the coverage under test."""
    data = tomllib.loads((work / EXAMPLES[kind]).read_text())
    variants = schema_mutations(table_schema(kind), data, skip=(("axes",), ("estimators", 0, "parameters"),
                                                                ("estimators", 1, "parameters")))
    if kind == "sweep":      # [axes] is a free table of dotted fields: its violations, explicitly
        axis = "scene.camera_effects.dark_current_scale"
        for what, axes in [("unknown field", {"scene.camera_effects.dark_current_scal": [1.0]}),
                           ("not sweepable", {"site.sun.elevation_deg": [40.0]}), ("not a list", {axis: 2.0}),
                           ("empty list", {axis: []}), ("mixed types", {axis: [1.0, "x"]}),
                           ("out of range", {axis: [1.0, -3.0]}), ("wrong type", {"sensors.perfect": [1, 0]}),
                           ("repeated grid value", {axis: [1.0, 1.0]}), ("non-finite", {axis: [1.0, math.nan]}),
                           ("empty table", {"scene": {}}), ("no axes", {})]:
            variants.append((f"axes: {what}", {**data, "axes": axes}))
    if kind == "campaign_file":
        variants += [("campaign.cases: not a class", with_value(data, ("campaign", "cases", "gxx"), 3)),
                     ("site.classes: fractions do not sum to 1", with_value(data, ("site", "classes", 0, "ellipse_fraction"), 0.2)),
                     ("site.classes: duplicate name", with_value(data, ("site", "classes", 1, "name"), "gcp")),
                     ("terrain overrides out of range",
                      with_value(data, ("site", "classes", 1, "terrain", "overrides", "haze_optical_depth"), 9.0)),
                     ("site.camera: no such file", with_value(data, ("site", "camera"), "nowhere/camera.toml")),
                     ("estimators: a name used twice", with_value(data, ("estimators", 1, "name"), "dimes")),
                     ("estimators: reference parameter out of range",
                      with_value(data, ("estimators", 0, "parameters", "min_correlation"), 3.0)),
                     ("estimators: reference parameter unknown", with_value(data, ("estimators", 0, "parameters", "x"), 1)),
                     ("estimators: callable not importable", with_value(data, ("estimators", 1, "callable"), "no.such:f")),
                     ("estimators: command placeholder unknown",
                      with_value(data, ("estimators", 1), {"name": "c", "kind": "command", "argv": ["{python}", "{imgs}"]})),
                     ("estimators: program missing",
                      with_value(data, ("estimators", 1), {"name": "c", "kind": "command", "argv": ["/no/such/program"]}))]
    if kind == "flight":
        variants += [("class not in the site", {**data, "class": "gxx"}),
                     ("images out of order", with_value(data, ("images", 1, "time_s"), -1.0)),
                     ("image below ground", with_value(data, ("images", 0, "position_m"), [0.0, 0.0, -5.0])),
                     ("image file missing", with_value(data, ("images", 0, "file"), "absent.npy")),
                     ("image of the wrong shape", with_value(data, ("images", 0, "file"), "img.png")),
                     ("column outside the image", {**data, "column": 5000})]
    assert len(variants) >= 30
    for _index, (what, bad) in enumerate(variants):
        path = _mutated(work, kind, toml_text(bad))
        if LOADERS[kind] is not None:
            _guard(LOADERS[kind], path, what)
        for main, argv in _file_commands(kind, path):
            refused(work, main, argv, f"{kind} file", what)


@FUZZ
@given(kind=st.sampled_from(list(EXAMPLES)), position=st.floats(0.0, 1.0),
       damage=st.sampled_from(["latin-1 byte", "syntax", "nul", "truncated table header"]))
def test_broken_encoding_and_syntax_are_refused(work, kind, position, damage):
    text = (work / EXAMPLES[kind]).read_bytes()
    lines = text.split(b"\n")
    at = min(int(position * len(lines)), len(lines) - 1)
    insert = {"latin-1 byte": b"# caf\xe9", "syntax": b"= = =", "nul": b"x = \"\x00\"",
              "truncated table header": b"[unclosed"}[damage]
    path = _mutated(work, f"{kind}-damaged", b"\n".join(lines[:at] + [insert] + lines[at:]))
    for main, argv in _file_commands(kind, path):
        refused(work, main, argv, f"{kind} file", f"{damage} at line {at}")


@pytest.mark.parametrize("kind", list(EXAMPLES))
def test_unusable_paths_are_refused(work, kind):
    folder = work / "mutated" / f"{kind}-folder.toml"
    folder.mkdir(parents=True, exist_ok=True)
    loop = work / "mutated" / f"{kind}-loop.toml"
    if not loop.is_symlink():
        loop.symlink_to(loop)
    for path in (folder, loop, work / "mutated" / "absent.toml", work / "img.png"):
        for main, argv in _file_commands(kind, path):
            refused(work, main, argv, f"{kind} file", f"unusable path {path.name}")


TRAJECTORY_DAMAGE = {
    "two images": lambda f: f.drop(columns=["image3_t_s"]),
    "four images": lambda f: f.assign(image4_t_s=f.image3_t_s + 1.0),
    "below ground while imaging": lambda f: f.assign(z_m=f.z_m - 1500.0),
    "NaN altitude": lambda f: f.assign(z_m=f.z_m.where(f.index != 7, np.nan)),
    "text in a number column": lambda f: f.assign(vx_mps=f.vx_mps.astype(object).where(f.index != 3, "fast")),
    "missing column": lambda f: f.drop(columns=["qx"]),
    "unknown column": lambda f: f.assign(speed_mps=1.0),
    "time going back": lambda f: f.assign(t_s=f.t_s.where(f.index != 4, 0.0)),
    "non-unit quaternion": lambda f: f.assign(qw=f.qw * 1.5),
    "image time changes in a profile": lambda f: f.assign(image2_t_s=f.image2_t_s.where(f.index != 9, 0.1)),
    "image outside the profile": lambda f: f.assign(image3_t_s=1e4),
    "fractional profile id": lambda f: f.assign(profile_id=f.profile_id + 0.5),
    "one row": lambda f: f.head(1),
    "empty": lambda f: f.head(0),
    "profiles interleaved": lambda f: f.assign(profile_id=np.arange(len(f)) % 2),
    "heat shield column alone": lambda f: f.drop(columns=["heat_shield_y_m", "heat_shield_z_m"]),
}


@pytest.mark.parametrize("damage", list(TRAJECTORY_DAMAGE))
def test_bad_trajectory_files_are_refused_at_load(work, damage):
    frame = pd.read_csv(work / "set.csv")
    path = work / "mutated" / f"trajectory-{damage.replace(' ', '_')}.csv"
    path.parent.mkdir(exist_ok=True)
    TRAJECTORY_DAMAGE[damage](frame).to_csv(path, index=False)
    campaign = tomllib.loads((work / "campaign.toml").read_text())
    campaign["site"]["trajectory_set"] = str(path)
    site = _mutated(work, f"campaign-trajectory-{damage.replace(' ', '_')}", toml_text(campaign))
    for main, argv in [(trajectories_main, ["stats", path]),
                       (campaign_main, ["submit", site, "--output", "out", "--no-progress"]),
                       (campaign_main, ["plan", site, "--out", "maps"])]:
        refused(work, main, argv, "trajectory file", damage)


# ------------------------------------------------------------------------------------------------ flags
BAD_SCALE = st.one_of(st.floats(allow_nan=True, allow_infinity=True).filter(lambda x: not 0.0 < x <= 100.0).map(repr),
                      st.sampled_from(["", "one", "1,5", "0x10", "--", "1e"]))
BAD_WORKERS = st.one_of(st.integers().filter(lambda n: not 0 <= n <= 1024).map(str),
                        st.sampled_from(["two", "1.5", "", "1e3"]))
BAD_SCHEDULER = st.text(min_size=1, max_size=30).filter(lambda s: not s.startswith(("tcp://", "tls://", "inproc://")))
KNOWN_FLAGS = ("--output", "--scheduler", "--workers", "--cases-scale", "--fresh", "--wait", "--no-progress", "--out",
               "--baseline", "--help", "--camera", "--config", "--big-endian", "--summary", "--sidecar")
UNKNOWN_FLAG = st.from_regex(r"\A--[a-z][a-z-]{2,12}\Z").filter(     # nor an abbreviation of a known flag
    lambda flag: not any(known.startswith(flag) for known in KNOWN_FLAGS))


@FUZZ
@given(command=st.sampled_from(["submit", "plan", "sweep"]), flag=st.sampled_from(
    ["--cases-scale", "--workers", "--scheduler", "unknown", "--output-is-a-file", "missing-value"]), data=st.data())
def test_bad_campaign_flags(work, command, flag, data):
    file = work / ("sweep.toml" if command == "sweep" else "campaign.toml")
    argv = [command, file] + (["--no-progress"] if command != "plan" else [])
    if flag == "--cases-scale":
        if command == "sweep":
            flag = "--workers"
        else:
            argv += ["--cases-scale", data.draw(BAD_SCALE)]
    if flag == "--workers":
        if command == "plan":
            argv += ["--workers", "2"]                   # plan has no --workers: a usage error too
        else:
            argv += ["--workers", data.draw(BAD_WORKERS)]
    elif flag == "--scheduler":
        argv += ["--scheduler" if command != "plan" else "--bogus", data.draw(BAD_SCHEDULER)]
    elif flag == "unknown":
        argv += [data.draw(UNKNOWN_FLAG)]
    elif flag == "--output-is-a-file":
        argv += ["--out" if command == "plan" else "--output", "set.csv"]
    elif flag == "missing-value":
        argv += [data.draw(st.sampled_from(["--output", "--cases-scale", "--workers", "--scheduler", "--out",
                                            "--baseline"]))]
    refused(work, campaign_main, argv, "campaign flags", " ".join(map(str, argv)))


@FUZZ
@given(command=st.sampled_from(["status", "table", "report", "verify", "camera", "schema"]),
       target=st.sampled_from(["absent", "a file", "an empty directory", "a directory of other files", "no argument",
                               "two arguments", "unknown flag", "text"]), text=st.text(max_size=20).filter(lambda t: "\x00" not in t))
def test_bad_store_camera_and_schema_arguments(work, command, target, text):
    (work / "empty").mkdir(exist_ok=True)
    argv = [command] + {"absent": ["absent-dir"], "a file": ["meas.json"], "an empty directory": ["empty"],
                        "a directory of other files": ["mutated" if command != "camera" else "empty"],
                        "no argument": [], "two arguments": ["empty", "empty"], "unknown flag": ["empty", "--colour"],
                        "text": [text]}[target]
    if command == "schema" and target in ("absent", "a file", "an empty directory", "a directory of other files"):
        argv = [command, argv[1] + "x"]
    if command == "schema" and (target in ("no argument",) or (target == "text" and text in SCHEMA_TABLES)):
        return                                          # valid: prints every schema
    if target == "text" and command != "schema" and (work / text).is_file() and command == "camera":
        return
    refused(work, campaign_main, argv, "campaign flags", " ".join(map(str, argv)))


@FUZZ
@given(case=st.sampled_from(["compare-flight column", "compare-flight out is a file", "compare-flight no file",
                             "terrain_stats absent source", "terrain_stats unknown preset", "terrain_stats bad site",
                             "terrain_stats unknown flag", "terrain_stats no source"]),
       number=st.integers().filter(lambda n: not 0 <= n < 1024), text=st.from_regex(r"\A[a-z]{1,12}\Z"))
def test_bad_compare_flight_and_terrain_stats_command_lines(work, case, number, text):
    main, argv = {
        "compare-flight column": (campaign_main, ["compare-flight", "flight.toml", "--column", str(number)]),
        "compare-flight out is a file": (campaign_main, ["compare-flight", "flight.toml", "--out", "set.csv"]),
        "compare-flight no file": (campaign_main, ["compare-flight"]),
        "terrain_stats absent source": (terrain_stats_main, [f"{text}.img", "--csv", "stats.csv"]),
        "terrain_stats unknown preset": (terrain_stats_main, [text + "x", "--csv", "stats.csv"]),
        "terrain_stats bad site": (terrain_stats_main, ["img.png", "--site", "camera.toml", "--csv", "stats.csv"]),
        "terrain_stats unknown flag": (terrain_stats_main, ["img.png", "--" + text]),
        "terrain_stats no source": (terrain_stats_main, []),
    }[case]
    if case == "terrain_stats unknown flag" and any(flag.startswith("--" + text) for flag in
                                                   ("--csv", "--site", "--no-cache", "--help")):
        return
    refused(work, main, argv, "campaign flags" if main is campaign_main else "terrain stats flags", case)


@FUZZ
@given(case=st.sampled_from(["two files", "missing camera flag", "absent image", "image is a directory",
                             "wrong image shape", "garbage image", "measurements not JSON", "measurements latin-1",
                             "measurements unknown key", "measurements wrong count", "config unknown key",
                             "config without [estimator]", "config out of range", "unknown flag", "camera absent",
                             "bits not allowed", "flat field absent", "channel not allowed"]),
       number=st.floats(allow_nan=True, allow_infinity=True))
def test_bad_estimator_command_lines(work, case, number):
    images = ["im0.npy", "im1.npy", "im2.npy"]
    bad = work / "mutated"
    bad.mkdir(exist_ok=True)
    argv = [*images, "meas.json", "--camera", "camera.toml"]
    if case == "two files":
        argv = ["im0.npy", "meas.json", "--camera", "camera.toml"]
    elif case == "missing camera flag":
        argv = [*images, "meas.json"]
    elif case == "absent image":
        argv[1] = "absent.npy"
    elif case == "image is a directory":
        argv[1] = "mutated"
    elif case == "wrong image shape":
        np.save(bad / "small.npy", np.zeros((16, 16), np.uint16))
        argv[1] = bad / "small.npy"
    elif case == "garbage image":
        (bad / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
        argv[1] = bad / "garbage.png"
    elif case.startswith("measurements"):
        data = json.loads((work / "meas.json").read_text())
        text = {"measurements not JSON": "{images: [",
                "measurements latin-1": json.dumps(data).replace("images", "im\xe4ges"),
                "measurements unknown key": json.dumps({**data, "sun": [0, 0, 1]}),
                "measurements wrong count": json.dumps({**data, "images": data["images"][:2]})}[case]
        (bad / "meas.json").write_bytes(text.encode("latin-1"))
        argv[3] = bad / "meas.json"
    elif case.startswith("config"):
        text = {"config unknown key": "[estimator]\nmin_corelation = 0.5\n", "config without [estimator]": "[scene]\n",
                "config out of range": f"[estimator]\nmin_correlation = {_toml_float(number, 1.0)}\n"}[case]
        (bad / "estimator.toml").write_text(text)
        argv += ["--config", bad / "estimator.toml"]
    elif case == "unknown flag":
        argv += ["--fast"]
    elif case == "camera absent":
        argv[-1] = "absent.toml"
    elif case == "bits not allowed":
        argv += ["--bits", str(int(number) if math.isfinite(number) and abs(number) < 1e9 and int(number) not in
                               (8, 12, 16) else 7)]
    elif case == "flat field absent":
        argv += ["--flat-field", "absent.npy"]
    elif case == "channel not allowed":
        argv += ["--channel", "x"]
    refused(work, dimes_main, argv, "estimator flags", case)


def _toml_float(value: float, limit: float) -> str:
    """A TOML number outside [-limit, limit] (or not finite)."""
    if math.isfinite(value) and abs(value) <= limit:
        value = limit + 1.0 + abs(value)
    return {math.inf: "inf", -math.inf: "-inf"}.get(value, "nan" if math.isnan(value) else repr(value))


@FUZZ
@given(argv=st.one_of(
    st.tuples(st.text(max_size=12).filter(lambda c: c not in ("generate", "verify", "stats")), st.just("gusev")),
    st.tuples(st.sampled_from(["generate", "verify", "stats"]),
              st.from_regex(r"\A[a-z]{1,10}\Z").filter(lambda s: s not in ("gusev", "meridiani"))),
    st.tuples(st.just("stats"), st.sampled_from(["absent.csv", "absent.parquet", "meas.json.csv", "img.png"]))))
def test_bad_trajectory_command_lines(work, argv):
    if argv[1] == "meas.json.csv" and not (work / "meas.json.csv").exists():
        (work / "meas.json.csv").write_text((work / "meas.json").read_text())
    if argv[1] == "img.png":
        argv = ("stats", "img.parquet")
        if not (work / "img.parquet").exists():
            (work / "img.parquet").write_bytes((work / "img.png").read_bytes())
    refused(work, trajectories_main, list(argv), "trajectory flags", " ".join(argv))


@FUZZ
@given(content=st.binary(min_size=0, max_size=400), suffix=st.sampled_from([".img", ".png", ".tif", ".cub", ".lbl",
                                                                           ".raw", ".IMG", ".qub"]))
def test_garbage_orbital_images_are_refused(work, content, suffix):
    path = work / "mutated" / f"garbage{suffix}"
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(content)
    refused(work, readers_main, [path], "reader inputs", f"{len(content)} bytes as {suffix}")


def test_reader_arguments(work):
    (work / "empty").mkdir(exist_ok=True)
    for argv in (["absent.img"], ["empty"], [], ["img.png", "--sidecar"], ["img.png", "--sidecar", "absent.toml"],
                 ["img.png", "--colour"]):
        refused(work, readers_main, argv, "reader inputs", " ".join(argv))


# ------------------------------------------------------------------------------------------- subprocesses
SUBPROCESS_SAMPLE = [
    ("campaign.cli", ["submit", "campaign.toml", "--cases-scale", "nan"]),
    ("campaign.cli", ["submit", "campaign.toml", "--workers", "-3"]),
    ("campaign.cli", ["sweep", "sweep.toml", "--scheduler", "localhost"]),
    ("campaign.cli", ["camera", "img.toml"]),
    ("campaign.cli", ["status", "absent-dir"]),
    ("campaign.cli", ["schema", "cameras"]),
    ("dimes_velocity", ["im0.npy", "im1.npy", "im2.npy", "meas.json", "--camera", "img.toml"]),
    ("sitedata.edl.trajectory_sets", ["stats", "meas.json.csv"]),
    ("file_formats.planetary.inspect_files", ["img.png", "--sidecar", "camera.toml"]),
]


@pytest.mark.parametrize("module, argv", SUBPROCESS_SAMPLE, ids=[" ".join([m, *a]) for m, a in SUBPROCESS_SAMPLE])
def test_sample_through_real_processes(work, module, argv):
    if not (work / "meas.json.csv").exists():
        (work / "meas.json.csv").write_text((work / "meas.json").read_text())
    before = snapshot(work)
    result = subprocess.run([sys.executable, "-m", module, *argv], capture_output=True, text=True, cwd=work,
                            timeout=300)
    from fuzz_inputs import Outcome
    problems = refusal_problems(Outcome(result.returncode, result.stdout, result.stderr), before, snapshot(work))
    TRIED["subprocess"] += 1
    assert not problems, problems


def test_zz_fuzz_size_is_reported():
    """Runs last in this module: the suite tried what it claims (the total is printed in the summary)."""
    if len(TRIED) < 12:
        pytest.skip("only part of the fuzz suite ran")
    assert sum(TRIED.values()) >= 2000, TRIED
