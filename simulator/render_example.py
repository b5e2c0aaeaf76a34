"""Render an example descent and write the estimator's exact inputs, to replay it (paper Figs. 1, 2, 5).

    python -m simulator.render_example --out DIR [--seed 1] [--camera CAMERA.toml] [--flat-field calibrated|none] [--display]

Three images at 2000, 1725 and 1450 m of a tilted, windy descent (72 m/s down, 13 m/s drift) with the
sun 25 deg from the zenith and the heat shield falling below, over a small textured crater field made
here (the simulator imports no site data; campaign terrains are rendered by ``campaign submit``).
``DIR`` receives what an estimator gets, in the layout of ``campaign export``::

    image_1.png ... image_3.png   16-bit grey PNG of the binned DN as read out (256 x 1024 for MER),
                                  unstretched (file_formats.descent_images.write_descent_image)
    measurements.json             the measured attitude, rates, radar altitude and biased IMU velocity
                                  (simulator.sensors defaults; file_formats.measurements_json)
    flat_field.npy                the simulated ground flat-field calibration (16 frames), float32,
                                  read-out shape; only with --flat-field calibrated (the default)
    truth.json                    what the estimator must not see: true velocity at the last image,
                                  wind, altitudes, the sensor errors drawn; ``replay`` is the command

``python -m dimes_velocity DIR/image_1.png DIR/image_2.png DIR/image_3.png DIR/measurements.json
--camera CAMERA.toml --flat-field DIR/flat_field.npy`` (the ``replay`` line) then runs the reference
estimator on exactly these inputs. ``--display`` adds pictures to look at: ``display_K.png`` (the
image stretched to 8 bits, Fig. 1), ``display_K_tall.png`` (rows repeated to the 45 x 45 deg aspect),
``radiance_K.png`` (the exposure radiance field: opposition halo, shadows, heat shield; Fig. 2) and
``footprint.png`` (the terrain with the image footprints and lander positions; Fig. 5).
Same seed, same files.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import cv2
import numpy as np

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from file_formats.descent_images import write_descent_image
from file_formats.flat_field_files import save_flat_field
from file_formats.measurements_json import json_ready, measurements_to_dict
from flight_interface.camera import Camera, load_camera
from flight_interface.frames import quat_from_axis_angle, quat_multiply
from simulator.calibration import DEFAULT_FLAT_FRAMES, simulate_flat_field
from simulator.descent_image import DescentImage, render_descent_image
from simulator.scene.descent_profile import DescentProfile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig
from simulator.sensors import SensorConfig, measure

ROOT = Path(__file__).resolve().parents[1]


def crater_field(seed: int, size: int = 1400, mpp: float = 3.0) -> Terrain:
    """A simple synthetic I/F strip: smooth albedo texture plus craters with dark floors and bright rims.

    Parameters
    ----------
    seed : int
        Seed of the texture and crater draws.
    size : int, optional
        Side of the square strip (pixels).
    mpp : float, optional
        Pixel size (m).

    Returns
    -------
    Terrain
        The strip, centred on the world origin.
    """
    rng = np.random.default_rng(seed)
    texture = np.zeros((size, size), np.float32)
    for sigma, weight in ((40.0, 0.5), (8.0, 0.3), (1.5, 0.2)):
        layer = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), sigma)
        texture += weight * layer / layer.std()
    reflectance = 0.22 + 0.015 * texture
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float32)
    for _ in range(160):
        radius = float(rng.pareto(2.0) * 6.0 + 4.0)
        if radius > 120:
            continue
        row, col = rng.uniform(0, size, 2)
        box = int(2 * radius) + 2
        r0, r1 = max(int(row) - box, 0), min(int(row) + box, size)
        c0, c1 = max(int(col) - box, 0), min(int(col) + box, size)
        rho = np.hypot(rows[r0:r1, c0:c1] - row, cols[r0:r1, c0:c1] - col) / radius
        profile = -0.05 * np.clip(1 - rho**2, 0, None) + 0.05 * np.exp(-((rho - 1.0) / 0.15) ** 2)
        reflectance[r0:r1, c0:c1] += profile.astype(np.float32)
    half = 0.5 * (size - 1) * mpp
    return Terrain(np.clip(reflectance, 0.02, 0.6).astype(np.float32), mpp, np.array([-half, half]),
                   np.radians(35.0), np.radians(0.5), np.radians(35.2), f"crater-field-{seed}")


def example_profile() -> DescentProfile:
    """The example descent: 72 m/s with 13 m/s drift, 15 +- 5 deg off nadir toward the anti-sun side, heat shield below.

    Returns
    -------
    DescentProfile
        The profile with its three image times.
    """
    time = np.linspace(0.0, 8.0, 33)
    velocity = np.array([12.0, -5.0, -72.0])
    position = np.array([0.0, 0.0, 2000.0]) + time[:, None] * velocity
    swing = np.radians(15.0) + np.radians(5.0) * np.sin(2 * np.pi * time / 4.0)
    heading = quat_from_axis_angle([0.0, 0.0, 1.0], np.radians(-20.0))   # boresight tilted toward azimuth 20 deg
    attitude = np.stack([quat_multiply(heading, quat_from_axis_angle([1.0, 0.0, 0.0], s)) for s in swing])
    rate = np.zeros((len(time), 3))
    rate[:, 0] = np.radians(5.0) * 2 * np.pi / 4.0 * np.cos(2 * np.pi * time / 4.0)
    shield = position + np.array([40.0, 30.0, -150.0]) + time[:, None] * np.array([0.0, 0.0, -6.0])
    return DescentProfile(time, position, np.tile(velocity, (len(time), 1)), attitude, rate,
                          np.tile([12.0, -5.0, 0.0], (len(time), 1)), shield,
                          np.array([0.0, 275.0 / 72.0, 550.0 / 72.0]), "example")


def stretch(values: np.ndarray, low_pct: float = 0.5, high_pct: float = 99.5) -> np.ndarray:
    """Percentile stretch of an array to 8 bits, for pictures to look at.

    Parameters
    ----------
    values : ndarray
        Any real array.
    low_pct, high_pct : float, optional
        Percentiles mapped to 0 and 255.

    Returns
    -------
    ndarray, uint8, shape of ``values``
        The stretched picture.
    """
    low, high = np.percentile(values, [low_pct, high_pct])
    return (np.clip((values - low) / max(high - low, 1e-12), 0, 1) * 255).astype(np.uint8)


IMAGE_NAMES = ("image_1.png", "image_2.png", "image_3.png")
FLAT_FIELD_NAME = "flat_field.npy"


def example_sun() -> np.ndarray:
    """Unit vector toward the sun of the example: 25 deg from the zenith, azimuth 200 deg.

    Returns
    -------
    ndarray, shape (3,)
        World unit vector (x east, y north, z up).
    """
    incidence, azimuth = np.radians(25.0), np.radians(200.0)
    return np.array([np.sin(incidence) * np.sin(azimuth), np.sin(incidence) * np.cos(azimuth), np.cos(incidence)])


def write_display(out: Path, terrain: Terrain, camera: Camera, rendered: list[DescentImage]) -> None:
    """Write the pictures to look at (``--display``): stretched images, radiance fields, footprint map.

    Parameters
    ----------
    out : Path
        Output directory.
    terrain : Terrain
        The example terrain.
    camera : Camera
        The camera.
    rendered : list of DescentImage
        The three rendered images.
    """
    view = stretch(terrain.reflectance_if)
    scale = min(1.0, 1400.0 / max(terrain.shape))
    canvas = cv2.cvtColor(cv2.resize(view, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2BGR)
    colours = [(0, 0, 255), (0, 200, 0), (255, 80, 0)]
    for index, result in enumerate(rendered):
        number, diag = index + 1, result.diagnostics
        picture = stretch(result.dn.astype(np.float32))
        cv2.imwrite(str(out / f"display_{number}.png"), picture)
        cv2.imwrite(str(out / f"display_{number}_tall.png"), np.repeat(picture, camera.binning_rows, axis=0))
        cv2.imwrite(str(out / f"radiance_{number}.png"), stretch(result.radiance.exposure))
        rows, cols = terrain.world_to_pixel(diag.footprint_m[diag.footprint_hit, 0], diag.footprint_m[diag.footprint_hit, 1])
        polygon = np.round(np.stack([cols, rows], axis=-1) * scale).astype(np.int32)
        cv2.polylines(canvas, [polygon], True, colours[index % 3], 2)
        row, col = terrain.world_to_pixel(diag.pose.position_m[0], diag.pose.position_m[1])
        cv2.drawMarker(canvas, (int(np.round(col * scale)), int(np.round(row * scale))), colours[index % 3],
                       cv2.MARKER_CROSS, 18, 2)
    cv2.imwrite(str(out / "footprint.png"), canvas)


def truth_record(profile: DescentProfile, rendered: list[DescentImage], sensor_errors: dict, seed: int,
                 camera_path: Path, flat_field_source: str, replay: list[str]) -> dict:
    """truth.json: the keys of ``campaign export``'s truth that exist outside a campaign.

    Parameters
    ----------
    profile : DescentProfile
        The true descent.
    rendered : list of DescentImage
        The rendered images.
    sensor_errors : dict
        The sensor errors drawn (:func:`simulator.sensors.measure`'s truth), SI units.
    seed : int
        The seed of the example.
    camera_path : Path
        The camera file.
    flat_field_source : str
        ``"calibrated"`` or ``"none"``.
    replay : list of str
        The command line that replays the estimate.

    Returns
    -------
    dict
        The JSON record.
    """
    last = float(profile.image_times_s[-1])
    velocity, wind = profile.pose(last).velocity_mps, profile.wind_at(last)
    return json_ready({
        "seed": seed, "profile": profile.name, "camera": str(camera_path), "flat_field_source": flat_field_source,
        "truth_velocity_east_mps": float(velocity[0]), "truth_velocity_north_mps": float(velocity[1]),
        "wind_east_mps": float(wind[0]), "wind_north_mps": float(wind[1]),
        "altitude_image1_m": float(profile.pose(float(profile.image_times_s[0])).position_m[2]),
        "altitude_image3_m": float(profile.pose(last).position_m[2]),
        "heat_shield_in_view": [bool(r.diagnostics.heat_shield_visible) for r in rendered],
        "outside_terrain_fraction": [r.outside_terrain_fraction for r in rendered],
        "sensor_errors": sensor_errors, "replay": shlex.join(replay)})


def main(argv: list[str] | None = None) -> int:
    """Command line ``python -m simulator.render_example`` (module docstring).

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 written, 2 bad input.
    """
    parser = OneLineParser(prog="python -m simulator.render_example", description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--camera", type=Path, default=ROOT / "sitedata" / "cameras" / "mer_a.toml")
    parser.add_argument("--flat-field", choices=("calibrated", "none"), default="calibrated",
                        help="write a simulated ground flat-field calibration (default) or none")
    parser.add_argument("--display", action="store_true",
                        help="also write stretched 8-bit pictures, radiance fields and the footprint map")
    args = parser.parse_args(argv)
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out}: exists and is not a directory; allowed: a directory (new or existing)")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        camera = load_camera(args.camera)
    except (ConfigError, OSError) as exc:         # a bad camera file or an --out that cannot be a directory
        message = str(exc) if isinstance(exc, ConfigError) else f"--out {args.out}: {exc.strerror or exc}"
        print(f"python -m simulator.render_example: error: {message}", file=sys.stderr)
        return USAGE_ERROR
    return write_example(args, camera)


def write_example(args: argparse.Namespace, camera: Camera) -> int:
    """Render the example, write the files (module docstring) and print what was written.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line.
    camera : Camera
        The camera.

    Returns
    -------
    int
        Exit status 0.
    """
    terrain = crater_field(args.seed)
    profile = example_profile()
    sun = example_sun()
    # children 0..2: images (as before), 3: sensors, 4: flat-field calibration (spawned children do not
    # depend on the count)
    seeds = np.random.SeedSequence(args.seed).spawn(len(profile.image_times_s) + 2)
    count = len(profile.image_times_s)
    rendered = [render_descent_image(terrain, profile, camera, index, sun, SceneConfig(),
                                     np.random.default_rng(seeds[index])) for index in range(count)]
    measurements, sensor_errors = measure(profile, camera, sun, SensorConfig(), np.random.default_rng(seeds[count]))
    images = [args.out / name for name in IMAGE_NAMES[:count]]
    for path, result in zip(images, rendered):
        write_descent_image(path, result.dn)
    (args.out / "measurements.json").write_text(json.dumps(measurements_to_dict(measurements), indent=1))
    flat_path = args.out / FLAT_FIELD_NAME
    if args.flat_field == "calibrated":
        save_flat_field(flat_path, simulate_flat_field(camera, DEFAULT_FLAT_FRAMES,
                                                       np.random.default_rng(seeds[count + 1])))
    else:
        flat_path.unlink(missing_ok=True)           # never leave another run's flat field beside the images
    camera_path = args.camera.resolve()
    replay = [sys.executable, "-m", "dimes_velocity", *(str(p.absolute()) for p in images),
              str((args.out / "measurements.json").absolute()), "--camera", str(camera_path),
              "--flat-field", str(flat_path.absolute()) if args.flat_field == "calibrated" else "none"]
    record = truth_record(profile, rendered, sensor_errors, args.seed, camera_path,
                          args.flat_field, replay)
    (args.out / "truth.json").write_text(json.dumps(record, indent=1))
    if args.display:
        write_display(args.out, terrain, camera, rendered)
    for index, result in enumerate(rendered, start=1):
        diag = result.diagnostics
        print(f"image {index}: t = {diag.exposure_start_s:.2f} s, altitude {diag.pose.position_m[2]:.0f} m, "
              f"mean DN {result.dn.mean():.0f}, heat shield in view: {diag.heat_shield_visible}, "
              f"scene {diag.scene_ms:.0f} ms, camera {diag.camera_ms:.0f} ms")
    written = ", ".join([*IMAGE_NAMES[:count], "measurements.json",
                         *([FLAT_FIELD_NAME] if args.flat_field == "calibrated" else []), "truth.json"])
    print(f"written to {args.out}: {written}" + (" and display_K.png, display_K_tall.png, radiance_K.png, "
                                                 "footprint.png" if args.display else ""))
    print(f"replay: {record['replay']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
