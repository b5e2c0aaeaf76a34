"""Trajectory-set parameter files (``sitedata/trajectories/edl_<site>.toml``): the statistics of one site's
EDL descent profiles, declared once by :class:`EdlParameters` and its tables (SI units; angles in degrees
at this edge, ``*_rad`` / ``*_radps`` properties for the generator). ``campaign schema trajectory_set``
prints the JSON Schema; the model behind the numbers is in :mod:`sitedata.edl.generator`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from pydantic import AfterValidator, Field, PrivateAttr, ValidationInfo, model_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, InputPath, fixed_vector, load

Positive = Annotated[float, Field(gt=0.0)]


def _is_range(value: tuple[float, float]) -> tuple[float, float]:
    low, high = value
    if not 0.0 <= low <= high:
        raise FieldProblem("", f"= [{low:g}, {high:g}] is not a range; allowed: [low, high] with 0 <= low <= high")
    return value


if TYPE_CHECKING:   # what fixed_vector(2) produces, for the type checker
    Pair = tuple[float, float]
else:
    Pair = fixed_vector(2)
#: A uniform range [low, high], 0 <= low <= high.
Range = Annotated[Pair, AfterValidator(_is_range)]


class SetTable(ConfigModel):
    """``[set]``: which profiles and where they are stored."""

    name: str = Field(min_length=1)
    seed: int = Field(ge=0, le=2**63 - 1)
    profiles: int = Field(ge=1, le=100_000)
    """Number of profiles in the set."""
    output: InputPath
    """Trajectory file written by ``generate`` (relative to the parameter file)."""


class ImagesTable(ConfigModel):
    """``[images]``: when the three images are taken."""

    altitudes_m: Pair
    """Lander altitudes at the start of exposure of images 1 and 2 (m), decreasing, > 0."""
    last_image_after_previous_s: Positive
    """Image 3 follows image 2 by this time (s)."""

    @model_validator(mode="after")
    def _decreasing(self):
        if not self.altitudes_m[0] > self.altitudes_m[1] > 0:
            raise FieldProblem("altitudes_m", f"= {list(self.altitudes_m)} must be decreasing and positive")
        return self


class DescentTable(ConfigModel):
    """``[descent]``: parachute descent at terminal velocity."""

    terminal_velocity_mean_mps: float = Field(ge=10.0, le=200.0)
    terminal_velocity_sigma_mps: float = Field(ge=0.0, le=10.0)
    time_before_first_image_s: float = Field(ge=1.0, le=120.0)
    """Integration starts this long above image 1 (s)."""
    initial_relative_horizontal_velocity_sigma_mps: float = Field(ge=0.0, le=30.0)
    """Per axis: system velocity minus wind at the start (m/s)."""


class PendulumTable(ConfigModel):
    """``[pendulum]``: the lander swinging on its bridle."""

    bridle_length_m: float = Field(ge=1.0, le=200.0)
    damping_ratio: float = Field(ge=0.0, le=0.9)
    initial_swing_sigma_deg: float = Field(ge=0.0, le=30.0)
    initial_swing_rate_sigma_dps: float = Field(ge=0.0, le=60.0)

    @property
    def initial_swing_sigma_rad(self) -> float:
        return math.radians(self.initial_swing_sigma_deg)

    @property
    def initial_swing_rate_sigma_radps(self) -> float:
        return math.radians(self.initial_swing_rate_sigma_dps)


class TwistTable(ConfigModel):
    """``[twist]``: the lander's torsional mode about the bridle."""

    natural_period_s: float = Field(ge=0.1, le=600.0)
    damping_ratio: float = Field(ge=0.0, le=0.9)
    initial_roll_sigma_deg: float = Field(ge=0.0, le=45.0)
    initial_roll_rate_sigma_dps: float = Field(ge=0.0, le=60.0)
    crosswind_torque_radps2_per_mps: float = Field(ge=0.0, le=1.0)
    """Yaw acceleration per m/s of crosswind on the asymmetric lander."""

    @property
    def initial_roll_sigma_rad(self) -> float:
        return math.radians(self.initial_roll_sigma_deg)

    @property
    def initial_roll_rate_sigma_radps(self) -> float:
        return math.radians(self.initial_roll_rate_sigma_dps)


class WindTable(ConfigModel):
    """``[wind]``: steady wind with shear, and Ornstein-Uhlenbeck gusts."""

    steady_sigma_mps: float = Field(ge=0.0, le=30.0)
    shear_sigma_mps_per_km: float = Field(ge=0.0, le=30.0)
    gust_horizontal_sigma_mps: float = Field(ge=0.0, le=20.0)
    gust_vertical_sigma_mps: float = Field(ge=0.0, le=20.0)
    gust_correlation_time_s: Positive

    @property
    def shear_sigma_mps_per_m(self) -> float:
        return self.shear_sigma_mps_per_km / 1000.0


class HeatShieldTable(ConfigModel):
    """``[heat_shield]``: separations from the lander (uniform ranges, m)."""

    axial_at_first_image_m: Range
    axial_growth_to_last_image_m: Range
    lateral_at_first_image_m: Range
    lateral_growth_to_last_image_m: Range
    lateral_direction_sigma_deg: float = Field(ge=0.0, le=180.0)

    @property
    def lateral_direction_sigma_rad(self) -> float:
        return math.radians(self.lateral_direction_sigma_deg)


class SamplingTable(ConfigModel):
    """``[sampling]``: integration step and stored samples (s)."""

    integration_step_s: Positive
    dense_step_s: Positive
    """Whole multiple of integration_step_s."""
    dense_half_window_s: float = Field(ge=0.0)
    coarse_step_s: Positive
    """Whole multiple of dense_step_s."""
    margin_s: float = Field(ge=0.0, le=10.0)

    @model_validator(mode="after")
    def _steps_nest(self):
        if self.integration_step_s > self.dense_step_s:
            raise FieldProblem("integration_step_s", f"= {self.integration_step_s:g} is out of range; allowed: > 0 "
                               f"and <= dense_step_s ({self.dense_step_s:g})")
        if abs(self.dense_step_s / self.integration_step_s - round(self.dense_step_s / self.integration_step_s)) > 1e-9:
            raise FieldProblem("dense_step_s", f"= {self.dense_step_s:g} must be a whole multiple of "
                               f"integration_step_s = {self.integration_step_s:g}")
        if self.coarse_step_s < self.dense_step_s or \
                abs(self.coarse_step_s / self.dense_step_s - round(self.coarse_step_s / self.dense_step_s)) > 1e-9:
            raise FieldProblem("coarse_step_s", f"= {self.coarse_step_s:g} must be a whole multiple of "
                               f"dense_step_s = {self.dense_step_s:g}")
        return self


class LimitsTable(ConfigModel):
    """``[limits]``: the envelope; a draw outside it is redrawn."""

    off_nadir_max_deg: float = Field(ge=0.0, le=90.0)
    roll_max_deg: float = Field(ge=0.0, le=180.0)
    angular_rate_max_dps: Positive
    horizontal_speed_max_mps: Positive


class EdlParameters(ConfigModel):
    """A trajectory-set parameter file."""

    set: SetTable
    images: ImagesTable
    descent: DescentTable
    pendulum: PendulumTable
    twist: TwistTable
    wind: WindTable
    heat_shield: HeatShieldTable
    sampling: SamplingTable
    limits: LimitsTable
    _source: Path = PrivateAttr(Path("."))

    @model_validator(mode="after")
    def _remember_the_file(self, info: ValidationInfo) -> EdlParameters:
        # set while validating, from the validation context; nothing sets it after validation
        self._source = Path((info.context or {}).get("parameter_path", "."))
        return self

    @property
    def source(self) -> Path:
        """The parameter file."""
        return self._source

    @property
    def name(self) -> str:
        return self.set.name

    @property
    def seed(self) -> int:
        return self.set.seed

    @property
    def output_path(self) -> Path:
        return self.set.output

    def with_seed(self, seed: int) -> EdlParameters:
        """A copy drawing from another seed."""
        return self.model_copy(update={"set": self.set.model_copy(update={"seed": seed})})


def load_edl_parameters(path: str | Path) -> EdlParameters:
    """Read a site's trajectory-set TOML (one-line ConfigError naming file, field and allowed values)."""
    path = Path(path)
    return load(EdlParameters, path, context={"base_dir": path.parent, "parameter_path": path})
