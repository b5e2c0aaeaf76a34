"""Camera chain: ms per 1024x1024 -> 1024x256 image (target <= 20 ms on one core)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.timing import median_ms
from flight_interface.camera import load_camera
from simulator.detector.camera_chain import render_image
from simulator.fields import RadianceFields

CAMERA = Path(__file__).resolve().parents[1] / "sitedata" / "cameras" / "mer_a.toml"


def run() -> list[dict]:
    camera = load_camera(CAMERA)
    rng = np.random.default_rng(0)
    texture = (30.0 + 5.0 * rng.standard_normal((1024, 1024))).astype(np.float32)
    still = RadianceFields(texture, texture, texture)
    moving = RadianceFields(texture, np.roll(texture, 1, axis=1), np.roll(texture, 2, axis=1))
    bright = np.full((1024, 1024), 400.0, dtype=np.float32)  # saturating: full-resolution path
    rows = []
    for name, fields in (("still_camera_1_field", still), ("moving_3_fields", moving),
                         ("saturating_full_res_path", RadianceFields(bright, bright, bright))):
        ms = median_ms(lambda: render_image(camera, fields, np.random.default_rng(1)), 15)  # noqa: B023 - called here
        rows.append({"name": f"camera_chain/{name}", "ms_per_image": ms, "target_ms": 20.0})
    return rows
