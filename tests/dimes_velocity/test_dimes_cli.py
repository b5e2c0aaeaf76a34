"""`python -m dimes_velocity`: three image files + measurements JSON -> result JSON; bad input -> exit 2."""
from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from dimes_velocity.__main__ import main
from file_formats.descent_images import ImageDeclaration, InputFileError, load_image
from file_formats.measurements_json import measurements_from_dict, measurements_to_dict

VELOCITY = (12.0, -7.0, -72.0)
BIAS = (6.0, -3.0)


@pytest.fixture(scope="module")
def case_files(mer_a, tmp_path_factory):
    """Images as PNG, .npy and raw; measurements with a known IMU bias."""
    directory = tmp_path_factory.mktemp("dimes_cli")
    descent = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(21)), np.random.default_rng(22),
                                        velocity_mps=VELOCITY)
    paths = [directory / "image1.png", directory / "image2.npy", directory / "image3.raw"]
    cv2.imwrite(str(paths[0]), descent.images[0])
    np.save(paths[1], descent.images[1])
    descent.images[2].astype("<u2").tofile(paths[2])
    data = measurements_to_dict(descent.truth)
    for image in data["images"]:
        image["imu_velocity_mps"][0] += BIAS[0]
        image["imu_velocity_mps"][1] += BIAS[1]
    measurements = directory / "measurements.json"
    measurements.write_text(json.dumps(data))
    return paths, measurements, data, descent


def run_cli(args, capsys):
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_prints_the_velocity_as_json(case_files, mer_a_path, capsys):
    paths, measurements, _, _ = case_files
    code, out, err = run_cli([*paths, measurements, "--camera", mer_a_path], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["valid"] and result["reason"] == "ok"
    assert np.hypot(result["velocity_east_mps"] - VELOCITY[0], result["velocity_north_mps"] - VELOCITY[1]) < 0.5
    assert np.hypot(result["imu_bias_east_mps"] - BIAS[0], result["imu_bias_north_mps"] - BIAS[1]) < 0.5
    assert {"brightness_dn", "contrast_dn", "correlation"} <= set(result["features"][0])
    assert set(result["timings"]) >= {"preprocess_ms", "rectify_ms", "select_ms", "match_ms", "total_ms"}


def test_cli_reads_estimator_parameters_from_toml(case_files, mer_a_path, tmp_path, capsys):
    paths, measurements, _, _ = case_files
    config = tmp_path / "site.toml"
    config.write_text("[estimator]\nfeatures_per_pair = 2\nmin_correlation = 0.8\n")
    code, out, err = run_cli([*paths, measurements, "--camera", mer_a_path, "--config", config], capsys)
    assert code == 0, err
    assert max(f["index"] for f in json.loads(out)["features"]) == 1
    config.write_text("[estimator]\nfeatures_per_pair = 0\n")
    code, out, err = run_cli([*paths, measurements, "--camera", mer_a_path, "--config", config], capsys)
    assert code == 2 and f"{config}: estimator.features_per_pair = 0 is out of range" in err


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["images"][1].pop("radar_altitude_m"), r"images[1].radar_altitude_m is missing"),
    (lambda d: d["images"][0].__setitem__("attitude_quat", [1, 0, 0]), r"images[0].attitude_quat must be a list of 4 numbers"),
    (lambda d: d["images"][2].__setitem__("time_s", 0.0), r"images[2].time_s"),
    (lambda d: d["images"][0].__setitem__("radar_altitude", 5.0), r"images[0].radar_altitude is not an image field"),
    (lambda d: d.__setitem__("sun_direction_world", [0, 0, 0]), r"sun_direction_world must be a non-zero vector"),
])
def test_bad_measurements_exit_2_naming_file_and_field(case_files, mer_a_path, tmp_path, capsys, edit, message):
    paths, _, data, _ = case_files
    broken = json.loads(json.dumps(data))
    edit(broken)
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(broken))
    code, out, err = run_cli([*paths, path, "--camera", mer_a_path], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and str(path) in err and message in err


def test_bad_image_exits_2_naming_the_file(case_files, mer_a_path, tmp_path, capsys):
    paths, measurements, _, descent = case_files
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, descent.images[0][:, :512])
    code, _, err = run_cli([paths[0], wrong, paths[2], measurements, "--camera", mer_a_path], capsys)
    assert code == 2 and str(wrong) in err and "image shape 256 x 512; accepted: 256 x 1024" in err
    short = tmp_path / "short.raw"
    short.write_bytes(b"\0" * 1000)
    code, _, err = run_cli([paths[0], paths[1], short, measurements, "--camera", mer_a_path], capsys)
    assert code == 2 and str(short) in err and "1000 bytes match no accepted shape" in err
    code, _, err = run_cli([paths[0], paths[1], tmp_path / "missing.png", measurements, "--camera", mer_a_path], capsys)
    assert code == 2 and "missing.png: file not found" in err


def test_raw_big_endian_and_png_round_trip(case_files, mer_a, tmp_path):
    _, _, _, descent = case_files
    path = tmp_path / "big.img"
    descent.images[0].astype(">u2").tofile(path)
    assert np.array_equal(load_image(path, mer_a, ImageDeclaration(big_endian=True)), descent.images[0])
    with pytest.raises(InputFileError, match="RGB image"):
        colour = tmp_path / "colour.png"
        cv2.imwrite(str(colour), np.zeros((256, 1024, 3), np.uint16))
        load_image(colour, mer_a)


def one_line_error(code, out, err):
    return code == 2 and out == "" and err.count("\n") == 1 and err.startswith("python -m dimes_velocity: error: ")


def test_done_criteria_refusals_exit_2_with_one_line(case_files, mer_a_path, tmp_path, capsys):
    """RGBA PNG without --channel, 8-bit PNG without --bits, a 300 x 300 image: exit 2, one line each."""
    paths, measurements, _, descent = case_files
    rgba = tmp_path / "rgba.png"
    cv2.imwrite(str(rgba), np.dstack([descent.images[0]] * 4))
    eight = tmp_path / "eight.png"
    cv2.imwrite(str(eight), (descent.images[0] // 16).astype(np.uint8))
    square = tmp_path / "square.png"
    cv2.imwrite(str(square), cv2.resize(descent.images[0], (300, 300), interpolation=cv2.INTER_AREA))
    for path, text in ((rgba, "RGBA image (256 x 1024 x 4); choose one channel with --channel r|g|b, or --luminance"),
                       (eight, "8-bit image without a declared bit depth; add --bits 8"),
                       (square, "image shape 300 x 300; accepted: 256 x 1024 (rows binned on chip) or 1024 x 1024")):
        code, out, err = run_cli([path, paths[1], paths[2], measurements, "--camera", mer_a_path], capsys)
        assert one_line_error(code, out, err), err
        assert f"{path}: {text}" in err
    with pytest.raises(SystemExit) as usage:
        main([str(a) for a in (rgba, paths[1], paths[2], measurements, "--camera", mer_a_path, "--channel", "r",
                               "--luminance")])
    err = capsys.readouterr().err
    assert usage.value.code == 2 and err.count("\n") == 1 and "--luminance: not allowed with argument --channel" in err
    code, out, err = run_cli([rgba, paths[1], paths[2], measurements, "--camera", mer_a_path, "--channel", "g"], capsys)
    assert code == 0, err
    assert json.loads(out)["inputs"][0]["dn_rule"] == "DN = value (16-bit container of camera DN)"


def full_frame(binned: np.ndarray, offset: int = 20) -> np.ndarray:
    """A 1024 x 1024 frame whose 4-row sums above the ADC offset are exactly the binned image."""
    base, remainder = np.divmod(binned.astype(np.int64) - offset, 4)
    frame = np.repeat(base, 4, axis=0)
    for i in range(4):
        frame[i::4] += remainder > i
    return (frame + offset).astype(np.uint16)


def test_8_bit_full_frame_stretch_is_refused_with_its_reason(case_files, mer_a_path, tmp_path, capsys):
    """A full frame stretched to 8 bits (0..255) read with --bits 8 would be saturated above value 76:
    exit 2, one line giving the reason and the --dn-scale that states the range; with it, the CLI runs."""
    paths, measurements, _, descent = case_files
    frames = []
    for k, image in enumerate(descent.images):
        frame = full_frame(image).astype(np.float64)
        frames.append(tmp_path / f"stretch{k}.png")
        cv2.imwrite(str(frames[-1]), np.round(frame * 255.0 / 1220.0).clip(0, 255).astype(np.uint8))
    code, out, err = run_cli([*frames, measurements, "--camera", mer_a_path, "--bits", "8"], capsys)
    assert one_line_error(code, out, err), err
    assert f"{frames[0]}: full frame at --bits 8" in err and "one full-frame pixel saturates at 1220 DN" in err
    code, out, err = run_cli([*frames, measurements, "--camera", mer_a_path, "--dn-scale", str(1220 / 255),
                              "--summary"], capsys)
    assert code == 0, err
    assert set(json.loads(out)) == {"velocity_east_mps", "velocity_north_mps", "valid", "reason",
                                    "velocity_uncertainty_mps", "imu_bias_east_mps", "imu_bias_north_mps"}


def test_full_frame_16_bit_triple_runs_and_prints_json(case_files, mer_a_path, tmp_path, capsys):
    paths, measurements, _, descent = case_files
    frames = []
    for k, image in enumerate(descent.images):
        frames.append(tmp_path / f"frame{k}.png")
        cv2.imwrite(str(frames[-1]), full_frame(image))
    code, out, err = run_cli([*frames, measurements, "--camera", mer_a_path], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["valid"], result["reason"]
    assert np.hypot(result["velocity_east_mps"] - VELOCITY[0], result["velocity_north_mps"] - VELOCITY[1]) < 0.5
    assert all(item["binned_from_full_frame"] and item["stored_shape"] == [1024, 1024] for item in result["inputs"])


def test_measurements_json_round_trip(case_files):
    _, _, data, _ = case_files
    again = measurements_to_dict(measurements_from_dict(data))
    assert again == data


def test_module_entry_point_runs(case_files, mer_a_path):
    paths, measurements, _, _ = case_files
    completed = subprocess.run([sys.executable, "-m", "dimes_velocity", *map(str, paths), str(measurements),
                                "--camera", str(mer_a_path), "--summary"], capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr
    summary = json.loads(completed.stdout)      # --summary: the summary only, no inputs list, pairs or features
    assert set(summary) == {"velocity_east_mps", "velocity_north_mps", "valid", "reason", "velocity_uncertainty_mps",
                            "imu_bias_east_mps", "imu_bias_north_mps"}


BLOCK_SIMULATOR = """
import json, sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('simulator', 'campaign'):
            raise ImportError('blocked ' + name)
sys.meta_path.insert(0, Block())
from dimes_velocity.__main__ import main
code = main(sys.argv[1:])
loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('simulator', 'campaign'))
print(json.dumps({'exit': code, 'loaded': loaded}), file=sys.stderr)
sys.exit(code)
"""


@pytest.mark.slow
def test_estimator_reads_pds3_images_with_the_simulator_unimportable(case_files, mer_a_path, tmp_path):
    """The estimator is flight software: it and its file readers run with no simulator or campaign code."""
    from planetary_files import write_pds3

    paths, measurements, _, descent = case_files
    products = [write_pds3(tmp_path / f"descent{k}.img", 256, 1024, "MSB_UNSIGNED_INTEGER", 16,
                           image.astype(">u2").tobytes(), extra_object="  SAMPLE_BIT_MASK = 2#0000111111111111#\r\n")
                for k, image in enumerate(descent.images)]
    completed = subprocess.run([sys.executable, "-c", BLOCK_SIMULATOR, *map(str, products), str(measurements),
                                "--camera", str(mer_a_path)], capture_output=True, text=True, timeout=120)
    report = json.loads(completed.stderr.strip().splitlines()[-1])
    assert completed.returncode == 0 and report == {"exit": 0, "loaded": []}, completed.stderr
    result = json.loads(completed.stdout)
    assert result["valid"] and np.hypot(result["velocity_east_mps"] - VELOCITY[0],
                                        result["velocity_north_mps"] - VELOCITY[1]) < 0.5
    assert all(item["format"] == "PDS3" and "SAMPLE_BIT_MASK 12" in item["dn_rule"] for item in result["inputs"])


@pytest.mark.parametrize("sun", [[0.3, -0.2, -0.5], [0.6, 0.8, 0.0]])
def test_sun_at_or_below_the_horizon_is_answered_invalid_with_its_reason(case_files, mer_a_path, tmp_path, capsys,
                                                                         sun):
    """The same images and measurements that give a valid answer in daylight: with the measured sun at or
    below the horizon there is no sunlit ground to track, so the estimator answers as flight software
    must (no exception, no velocity correction): invalid, reason sun_below_horizon, the IMU velocity."""
    paths, _, data, _ = case_files
    night = json.loads(json.dumps(data))
    night["sun_direction_world"] = sun
    path = tmp_path / "night.json"
    path.write_text(json.dumps(night))
    code, out, err = run_cli([*paths, path, "--camera", mer_a_path], capsys)
    assert code == 0 and err == ""
    result = json.loads(out)
    assert not result["valid"] and result["reason"] == "sun_below_horizon"
    assert [pair["reason"] for pair in result["pairs"]] == ["sun_below_horizon", "sun_below_horizon"]
    assert result["imu_bias_east_mps"] == 0.0 == result["imu_bias_north_mps"]
    assert result["velocity_east_mps"] == pytest.approx(night["images"][-1]["imu_velocity_mps"][0], abs=1e-12)
