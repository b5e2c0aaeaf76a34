"""Render an example descent sequence and write PNGs to look at (paper Figs. 1, 2 and 5).

    python -m simulator --out DIR [--seed 1] [--camera CAMERA.toml]

Writes, for the three images at 2000, 1725 and 1450 m of a tilted, windy descent with the sun 25 deg
from the zenith and the heat shield falling below:

* ``image_K.png``     the 12-bit 1024 x 256 camera image, stretched to 8 bits (Fig. 1);
* ``image_K_display.png`` the same with rows repeated 4x to the 45 x 45 deg aspect;
* ``radiance_K.png``  the exposure radiance field (1024 x 1024): opposition halo around the anti-sun
  point with the lander/backshell/parachute shadows at its centre (Fig. 2), heat shield;
* ``footprint.png``   the terrain with the three image footprints and lander positions (+) (Fig. 5).

Terrain: a small textured crater field made here (the simulator imports no site data; campaign
terrains are rendered by ``campaign submit``, and ``python -m sitedata.terrain.mosaic`` shows them).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle, quat_multiply
from simulator.descent_image import render_descent_image
from simulator.scene.descent_profile import DescentProfile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[1]


def crater_field(seed: int, size: int = 1400, mpp: float = 3.0) -> Terrain:
    """A simple synthetic I/F strip: smooth albedo texture plus craters with dark floors and bright rims."""
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
    """Descent at 72 m/s with 13 m/s drift, 15 +- 5 deg off nadir toward the anti-sun side, heat shield below."""
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
    low, high = np.percentile(values, [low_pct, high_pct])
    return (np.clip((values - low) / max(high - low, 1e-12), 0, 1) * 255).astype(np.uint8)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--camera", type=Path, default=ROOT / "sitedata" / "cameras" / "mer_a.toml")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    camera = load_camera(args.camera)
    terrain = crater_field(args.seed)
    profile = example_profile()
    incidence, azimuth = np.radians(25.0), np.radians(200.0)
    sun = np.array([np.sin(incidence) * np.sin(azimuth), np.sin(incidence) * np.cos(azimuth), np.cos(incidence)])
    config = SceneConfig()
    seeds = np.random.SeedSequence(args.seed).spawn(len(profile.image_times_s))

    view = stretch(terrain.reflectance_if)
    scale = min(1.0, 1400.0 / max(terrain.shape))
    canvas = cv2.cvtColor(cv2.resize(view, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2BGR)
    colours = [(0, 0, 255), (0, 200, 0), (255, 80, 0)]
    for index, seed in enumerate(seeds):
        result = render_descent_image(terrain, profile, camera, index, sun, config, np.random.default_rng(seed))
        diag = result.diagnostics
        dn = result.dn.astype(np.float32)
        cv2.imwrite(str(args.out / f"image_{index}.png"), stretch(dn))
        cv2.imwrite(str(args.out / f"image_{index}_display.png"),
                    np.repeat(stretch(dn), camera.binning_rows, axis=0))
        cv2.imwrite(str(args.out / f"radiance_{index}.png"), stretch(result.radiance.exposure))
        rows, cols = terrain.world_to_pixel(diag.footprint_m[diag.footprint_hit, 0], diag.footprint_m[diag.footprint_hit, 1])
        polygon = np.round(np.stack([cols, rows], axis=-1) * scale).astype(np.int32)
        cv2.polylines(canvas, [polygon], True, colours[index % 3], 2)
        row, col = terrain.world_to_pixel(diag.pose.position_m[0], diag.pose.position_m[1])
        cv2.drawMarker(canvas, (int(np.round(col * scale)), int(np.round(row * scale))), colours[index % 3],
                       cv2.MARKER_CROSS, 18, 2)
        print(f"image {index}: t = {diag.exposure_start_s:.2f} s, altitude {diag.pose.position_m[2]:.0f} m, "
              f"mean DN {dn.mean():.0f}, sub-steps {diag.substeps}, heat shield in view: {diag.heat_shield_visible}, "
              f"anti-sun pixel {None if diag.anti_sun_pixel is None else np.round(diag.anti_sun_pixel, 1).tolist()}, "
              f"scene {diag.scene_ms:.0f} ms, camera {diag.camera_ms:.0f} ms")
    cv2.imwrite(str(args.out / "footprint.png"), canvas)
    print(f"written to {args.out}: image_K.png, image_K_display.png, radiance_K.png (K = 0..2), footprint.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
