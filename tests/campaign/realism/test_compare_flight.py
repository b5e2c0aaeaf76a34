"""campaign compare-flight on a "flight" image of known pose: rendered at the reference preset by a
camera whose ADC gain and dark current differ from the site camera's, with its own noise seed."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from campaign.realism.compare_flight import FlightImage, compare, load_flight, pose_profile
from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.descent_image import render_descent_image
from simulator.scene_config import preset_config
from sitedata.sites import load_class_terrain, load_site

ROOT = Path(__file__).resolve().parents[3]
SITE = ROOT / "sitedata" / "gusev.toml"
FLIGHT_GAIN_E_PER_DN = 160.0        # site camera: 150 e-/DN
ATTITUDE = quat_from_axis_angle([1.0, 0.3, 0.0], np.radians(8.0))


def flight_camera(camera):
    return replace(camera, electronics=camera.electronics.model_copy(update=dict(
        adc_gain_e_per_dn=FLIGHT_GAIN_E_PER_DN, dark_current_ref_e_per_s=2200.0)))


def flight_toml(directory: Path, name: str, images: list[dict], extra: str = "") -> Path:
    text = f'site = "{SITE}"\nclass = "gdcp"\ncolumn = 296\noutput_dir = "{directory / name}"\n{extra}'
    for image in images:
        text += "[[images]]\n" + "".join(f"{key} = {json.dumps(value)}\n" for key, value in image.items())
    path = directory / f"{name}.toml"
    path.write_text(text)
    return path


def render_flight(position, velocity, time_s, preset, seed, path: Path) -> dict:
    site = load_site(SITE)
    terrain = load_class_terrain(site.classes[1].terrain)
    image = FlightImage(path, None, time_s, np.asarray(position, float), ATTITUDE, np.asarray(velocity, float),
                        np.zeros(3), None)
    config = preset_config(preset).with_fields(sun_distance_au=site.heliocentric_distance_au)
    rendered = render_descent_image(terrain, pose_profile(image), flight_camera(load_camera(site.camera_path)),
                                    time_s, site.sun_direction_world, config, np.random.default_rng(seed))
    assert cv2.imwrite(str(path), rendered.dn.astype(np.uint16))
    return {"file": path.name, "time_s": time_s, "position_m": [float(v) for v in position],
            "attitude_quat": [float(v) for v in ATTITUDE], "velocity_mps": [float(v) for v in velocity]}


def run_cli(*arguments) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "campaign.cli", "compare-flight", *map(str, arguments)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    directory = tmp_path_factory.mktemp("flight")
    # a still pose: the reference render (3 x 3 samples, every CCD period rendered) costs ~5 s instead of ~10 s
    image = render_flight([100.0, 2000.0, 2000.0], [0.0, 0.0, 0.0], 0.0, "reference", 987, directory / "flight.png")
    return directory, image


@pytest.mark.slow
def test_right_pose_correlates_and_a_pose_20_m_off_does_not(flight):
    directory, image = flight
    right = run_cli(flight_toml(directory, "right", [image]))
    assert right.returncode == 0, right.stderr
    off_pose = {**image, "position_m": [image["position_m"][0] + 20.0, *image["position_m"][1:]]}
    off = run_cli(flight_toml(directory, "off", [off_pose]))
    assert off.returncode == 0, off.stderr
    good = json.loads((directory / "right" / "comparison.json").read_text())["images"][0]
    bad = json.loads((directory / "off" / "comparison.json").read_text())["images"][0]
    assert "r = " in right.stdout and "slope = " in right.stdout
    # right pose: the images agree up to the gain ratio (DN scale 150/160), as the paper's m = 0.85
    assert good["column_r"] > 0.99 and good["image_r"] > 0.995 and good["texture_r"] > 0.95
    assert good["image_slope"] == pytest.approx(150.0 / FLIGHT_GAIN_E_PER_DN, rel=0.015)
    # 20 m (12 pixels) off: the texture no longer lines up
    assert bad["texture_r"] < 0.8 and bad["texture_r"] < good["texture_r"] - 0.3
    assert bad["column_r"] < good["column_r"]
    # the figures and tables exist and are what they say
    out = directory / "right"
    side = cv2.imread(str(out / "image_0_side_by_side.png"))
    assert side.shape == (1024, 2 * 1024 + 16, 3)
    assert (side[:, 296] == (0, 255, 0)).all()                              # the profile column, in green
    for name in ("image_0_column.png", "image_0_scatter.png"):
        assert cv2.imread(str(out / name)) is not None
    assert cv2.imread(str(out / "simulated_image_0.png"), cv2.IMREAD_UNCHANGED).shape == (256, 1024)
    pixels = pd.read_csv(out / "pixels.csv")
    assert pixels.loc[0, "column_r"] == pytest.approx(good["column_r"])
    templates = pd.read_csv(out / "features.csv")
    assert len(templates) >= 2 and (templates["source"] == "templates").all()
    ratio = templates["flight_brightness_dn"] / templates["simulated_brightness_dn"]
    assert ratio.to_numpy() == pytest.approx(150.0 / FLIGHT_GAIN_E_PER_DN, rel=0.03)
    assert (templates["flight_simulated_correlation"] > 0.95).all()


def test_two_images_give_the_estimators_table_3_metrics_for_both(tmp_path):
    images = [render_flight([100.0, 2000.0, 2000.0 - 72.0 * t], [4.0, -2.0, -72.0], t, "default", 5 + k,
                            tmp_path / f"flight{k}.png") for k, t in enumerate((0.0, 3.75))]
    spec = load_flight(flight_toml(tmp_path, "pair", images))
    summary = compare(spec)
    features = pd.read_csv(tmp_path / "pair" / "features.csv")
    assert set(features["source"]) == {"templates", "estimator_flight", "estimator_simulated"}
    assert summary["estimator"]["flight"]["valid"] and summary["estimator"]["simulated"]["valid"]
    flight_metrics = summary["templates"]["estimator_flight"]
    simulated_metrics = summary["templates"]["estimator_simulated"]
    # the flattened DN scale with the gain; contrast over brightness and correlation do not
    assert (flight_metrics["brightness_dn"] / simulated_metrics["brightness_dn"]
            == pytest.approx(150.0 / FLIGHT_GAIN_E_PER_DN, rel=0.03))
    assert (flight_metrics["contrast_over_brightness"]
            == pytest.approx(simulated_metrics["contrast_over_brightness"], rel=0.1))
    assert flight_metrics["correlation"] > 0.8 and simulated_metrics["correlation"] > 0.8


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    from campaign.cli import main

    image = {"file": "missing.png", "time_s": 0.0, "position_m": [0.0, 0.0, 2000.0], "attitude_quat": [1, 0, 0, 0]}
    np.save(tmp_path / "ok.npy", np.full((256, 1024), 900, np.uint16))
    good = {**image, "file": "ok.npy"}
    cases = {
        "class": ([good], "", "class = 'nope' is not allowed; allowed: gcp, gdcp, gkep"),
        "below": ([{**good, "position_m": [0.0, 0.0, -5.0]}], "", "images[0].position_m up = -5 m"),
        "unknown": ([{**good, "altitude_m": 3.0}], "", "images[0].altitude_m is not a known field"),
        "order": ([good, {**good, "time_s": -1.0}], "", "images time_s = [0.0, -1.0] must increase"),
        "scene": ([good], "[scene.atmosphere]\norbital_optical_depth = -1\n", "scene.atmosphere.orbital_optical_depth"),
        "shape": ([{**good, "file": "flight.npy"}], "", "images[0].file = 'flight.npy'"),
    }
    np.save(tmp_path / "flight.npy", np.zeros((300, 300), np.uint16))   # not binned, not a full frame
    for name, (images, extra, message) in cases.items():
        path = flight_toml(tmp_path, name, images, extra)
        if name == "class":
            path.write_text(path.read_text().replace('class = "gdcp"', 'class = "nope"'))
        assert main(["compare-flight", str(path)]) == 2, name
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and message.replace("'", '"') in err.replace("'", '"') \
            and str(path) in err, (name, err)
        assert not (tmp_path / name).exists()                               # nothing written
    # the real command line: a missing image file, and a column outside the image
    result = run_cli(flight_toml(tmp_path, "missing", [image]))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "images[0].file" in result.stderr and "missing.png: file not found" in result.stderr
    assert not (tmp_path / "missing").exists()
    result = run_cli(flight_toml(tmp_path, "column", [good]), "--column", 5000)
    assert result.returncode == 2 and "--column = 5000 is out of range; allowed: 0 .. 1023" in result.stderr
