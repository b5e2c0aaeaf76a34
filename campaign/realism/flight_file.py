"""FLIGHT.toml of ``campaign compare-flight`` (:mod:`campaign.realism.compare_flight`), declared once by
:class:`FlightFile` (``campaign schema flight``); paths are relative to the file."""
from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, Annotated

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, ExistingFile, InputPath, fixed_vector
from dimes_velocity.config import EstimatorConfig
from simulator.scene_config import SceneConfig

MAX_IMAGES = 3

if TYPE_CHECKING:   # what fixed_vector(n) produces, for the type checker
    Vector3 = tuple[float, float, float]
    Vector4 = tuple[float, float, float, float]
else:
    Vector3 = fixed_vector(3)
    Vector4 = fixed_vector(4)


class FlightImageEntry(ConfigModel):
    """``[[images]]``: one flight image with the lander's pose (SI, world frame of the terrain)."""

    file: InputPath
    """Raw image as the camera returns it (256 x 1024): 16-bit PNG, .npy, raw uint16."""
    time_s: float
    """Start of the exposure (s)."""
    position_m: Vector3
    """Lander at time_s (east, north, up; m), above the ground plane z = 0."""
    attitude_quat: Vector4
    """Lander body-to-world (w, x, y, z)."""
    velocity_mps: Vector3 = (0.0, 0.0, 0.0)
    """Motion through the CCD periods (m/s)."""
    angular_rate_radps: Vector3 = (0.0, 0.0, 0.0)
    """Body frame (rad/s)."""
    heat_shield_position_m: Vector3 | None = None
    """Drawn, and excluded by the estimator (m)."""

    @model_validator(mode="after")
    def _pose(self):
        if not self.position_m[2] > 0:
            raise FieldProblem("position_m", f"up = {self.position_m[2]:g} m; allowed: > 0 (above the ground plane z = 0)")
        norm = float(np.linalg.norm(self.attitude_quat))
        if not 0.5 < norm < 2.0:
            raise FieldProblem("attitude_quat", f"norm {norm:.3g}; allowed: a unit quaternion (w, x, y, z)")
        return self


def _times_increase(images: list[FlightImageEntry]) -> list[FlightImageEntry]:
    times = [image.time_s for image in images]
    if any(b <= a for a, b in itertools.pairwise(times)):
        raise FieldProblem("", f"time_s = {times} must increase from image to image")
    return images


class FlightFile(ConfigModel):
    """FLIGHT.toml: the site and class under the images, the images with their poses."""

    site: ExistingFile
    """Site (or campaign) TOML: camera, sun at landing and class terrains."""
    class_name: str = Field(alias="class")
    """The appearance class whose terrain lies under the images."""
    seed: int = Field(0, ge=0, le=2**63 - 1)
    """Noise stream of the simulated images."""
    column: int | None = Field(None, ge=0)
    """Raw image column of the profile and scatter (default: the middle column)."""
    output_dir: str = "runs/compare-flight"
    """Relative to the working directory."""
    scene: SceneConfig = SceneConfig()
    """As in campaign files (fidelity, atmosphere, ...)."""
    estimator: EstimatorConfig = EstimatorConfig()
    """As in campaign files (reference estimator parameters)."""
    images: Annotated[list[FlightImageEntry], Field(min_length=1, max_length=MAX_IMAGES),
                      AfterValidator(_times_increase)]
    """One to three descent images, in time order."""
