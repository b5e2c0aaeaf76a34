"""Scene configuration: every scene parameter (SI units) and effect switch of one descent image.

The ``[scene]`` TOML table and its sub-tables are declared once, here: :class:`SceneConfig` (parameters,
``fidelity``), :class:`SceneEffects` (``[scene.effects]``), the camera effect switches
(:class:`~simulator.detector.camera_chain.CameraEffects`, ``[scene.camera_effects]``), the off-nominal
effects (:class:`~simulator.off_nominal.OffNominalConfig`, ``[scene.off_nominal]``) and the atmosphere
(:class:`AtmosphereConfig`, ``[scene.atmosphere]``). The presets of shortcuts are in
:mod:`simulator.fidelity`; ``fidelity`` names the preset the other fields start from, and any field
given explicitly overrides it. Angles are degrees at this edge (``heat_shield_cone_angle_deg``;
``*_rad`` properties for the code).
"""
from __future__ import annotations

import math
from typing import Any, Literal, cast

from pydantic import Field, field_validator, model_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel
from simulator.detector.effects import CameraEffects
from simulator.fidelity import DEFAULT_PRESET, PRESETS, REFERENCE_EFFECTS, Preset, preset_fields
from simulator.off_nominal import OffNominalConfig
from simulator.scene import atmosphere, photometry
from simulator.scene.relief_config import ReliefConfig

FRAME_PX = 1024

__all__ = ["REFERENCE_EFFECTS", "AtmosphereConfig", "SceneConfig", "SceneEffects", "apply_preset", "preset_config"]


class SceneEffects(ConfigModel):
    """``[scene.effects]``: switches of the scene model; all on (the defaults) is the nominal simulator.

    Physics switches: ``photometric_correction``, ``spectral_ratio``, ``shadows``, ``heat_shield``,
    ``motion_blur``. Fidelity shortcuts (switch off for the reference render): ``coarse_ray_grid``,
    ``coarse_photometry``, ``share_still_fields``, ``warp_smear_fields``, ``warp_motion_blur``,
    ``pixel_area_filter``, ``binned_render``, ``interpolated_edge_rays``.
    """

    photometric_correction: bool = True
    """DIMES/MOC ratio of eq. 1-3 (hence the opposition halo)."""
    spectral_ratio: bool = True
    """Scale the MOC band radiance to the DIMES band."""
    shadows: bool = True
    """Shadows of the lander, backshell, parachute and heat shield."""
    heat_shield: bool = True
    """Draw the heat shield when in view."""
    motion_blur: bool = True
    """Sub-poses per CCD period."""
    coarse_ray_grid: bool = True
    """Shortcut: rays interpolated from a node grid."""
    coarse_photometry: bool = True
    """Shortcut: photometric ratio on the node grid."""
    share_still_fields: bool = True
    """Shortcut: one field for all three periods when the image moves by less than still_shift_terrain_px."""
    warp_smear_fields: bool = True
    """Shortcut: fast-flush and frame-transfer fields warped from the exposure-centre field along the
    ground-plane flow instead of re-rendered (simulator.scene.resample.warped_field)."""
    warp_motion_blur: bool = True
    """Shortcut: a period blurred over many sub-poses as warp-and-accumulate of one rendered field at
    binned resolution (simulator.scene.blur_warp) instead of one rendered field per sub-pose."""
    pixel_area_filter: bool = True
    """Shortcut: the pixel-area integral approximated from point samples
    (simulator.scene.radiance.pixel_area_average); the reference supersamples instead."""
    binned_render: bool = False
    """Shortcut (the fast preset): the scene rendered at the read-out's resolution, one ray per binning
    block (simulator.descent_image.binned_render_camera); the camera chain takes the fields as block means,
    which drops the in-block structure the optics' blur and the PRNU act on (see docs/simulator.md)."""
    interpolated_edge_rays: bool = False
    """Shortcut (the fast preset): the heat shield's silhouette sub-pixel rays moved to first order from the
    ground map's pixel rays (simulator.scene.heat_shield.edge_rays) instead of unprojected by the camera model."""


class AtmosphereConfig(ConfigModel):
    """``[scene.atmosphere]``: dust between the ground, the orbiter and the descent camera.

    (:mod:`simulator.scene.atmosphere`, equations A1-A7). Off (the default) while
    ``orbital_optical_depth`` is 0: the renderer then skips the stage and the images are those of a scene
    without atmosphere, bit for bit.
    """

    orbital_optical_depth: float = Field(0.0, ge=0.0, le=10.0)
    """Zenith dust optical depth of the whole column when the orbital terrain image was taken (also the
    column over the descent: the same dust)."""
    scale_height_m: float = Field(atmosphere.MARS_SCALE_HEIGHT_M, ge=1000.0, le=100000.0)
    """Dust scale height (m)."""
    single_scattering_albedo: float = Field(0.94, ge=0.0, le=1.0)
    """Single-scattering albedo of the dust."""
    forward_asymmetry: float = Field(0.70, ge=-0.95, le=0.95)
    """Double Henyey-Greenstein f HG(g1) + (1 - f) HG(g2): g1."""
    backward_asymmetry: float = Field(-0.30, ge=-0.95, le=0.95)
    """Double Henyey-Greenstein: g2."""
    forward_fraction: float = Field(0.90, ge=0.0, le=1.0)
    """Double Henyey-Greenstein: f."""
    descent_path: bool = True
    """The dust below the descent camera attenuates and adds path light (off: the camera sees the ground
    clear, only the orbital haze is removed)."""
    diffuse_transmission: bool = True
    """Light scattered once into the line of sight from the surroundings (adjacency) and skylight on the
    ground (off: direct beam only)."""

    @property
    def enabled(self) -> bool:
        """True when the atmosphere model is on (a dust optical depth above zero)."""
        return self.orbital_optical_depth > 0.0


class SceneConfig(ConfigModel):
    """``[scene]``: scene parameters (SI units, angles in degrees) and effect switches.

    Physics of the defaults: :mod:`simulator.scene.photometry` (sun distance, spectral ratio), :mod:`simulator.scene.shadow`
    (casters), :mod:`simulator.scene.heat_shield`, :mod:`simulator.scene.motion_blur`.
    """

    fidelity: Literal["reference", "high", "default", "fast"] = DEFAULT_PRESET
    """Preset of shortcuts the other fields start from (simulator.fidelity)."""
    effects: SceneEffects = SceneEffects()
    """Switches of the scene stage (``[scene.effects]``)."""
    camera_effects: CameraEffects = CameraEffects()
    """Switches of the camera chain (``[scene.camera_effects]``, simulator.detector.camera_chain)."""
    off_nominal: OffNominalConfig = OffNominalConfig()
    """Off-nominal camera and scenario effects (``[scene.off_nominal]``, simulator.off_nominal)."""
    atmosphere: AtmosphereConfig = AtmosphereConfig()
    """Dust between orbiter, ground and descent camera (``[scene.atmosphere]``, simulator.scene.atmosphere)."""
    relief: ReliefConfig = ReliefConfig()
    """How a terrain's height field is rendered (simulator.scene.relief)."""
    sun_distance_au: float = Field(photometry.MARS_MEAN_SUN_DISTANCE_AU, gt=0.1, le=100.0)
    """Sun distance (AU); a campaign's default is its site's heliocentric distance."""
    spectral_ratio: float = Field(0.906, gt=0.0, le=10.0)
    """DIMES-band to MOC-band radiance ratio of Mars soil."""
    lander_diameter_m: float = Field(1.9, ge=0.0, le=20.0)
    """Shadow caster: lander (m)."""
    backshell_diameter_m: float = Field(2.65, ge=0.0, le=20.0)
    """Shadow caster: backshell (m)."""
    backshell_distance_m: float = Field(20.0, ge=0.0, le=500.0)
    """Backshell above the lander (m)."""
    parachute_diameter_m: float = Field(15.0, ge=0.0, le=100.0)
    """Shadow caster: parachute (m)."""
    parachute_distance_m: float = Field(30.0, ge=0.0, le=500.0)
    """Parachute above the backshell (m)."""
    shadow_diffuse_fraction: float = Field(0.3, ge=0.0, le=1.0)
    """Fraction of the irradiance that is diffuse (sky) light and reaches shadowed ground."""
    heat_shield_diameter_m: float = Field(5.3, gt=0.0, le=50.0)
    """Heat shield diameter (m)."""
    heat_shield_cone_angle_deg: float = Field(140.0, gt=0.0, lt=180.0)
    """Full cone angle of the heat shield (deg)."""
    heat_shield_reflectance: float = Field(0.07, ge=0.0, le=1.0)
    """Diffuse reflectance of the heat-shield lining."""
    ray_grid_step_px: int = Field(16, ge=1, le=256)
    """Node spacing of the coarse ray grid (px; divides 1024)."""
    photometry_grid_step_px: int = Field(16, ge=1, le=256)
    """Node spacing of the coarse photometry grid (px; divides 1024)."""
    max_substeps: int = Field(16, ge=1, le=256)
    """Most motion sub-poses per CCD period."""
    still_shift_terrain_px: float = Field(1.0, ge=0.0, le=100.0)
    """An image moving less than this (terrain px) shares one field for its three periods."""
    substeps_per_terrain_px: float = Field(1.0, ge=0.1, le=64.0)
    """Motion sub-poses per terrain pixel of image shift."""
    supersample: int = Field(1, ge=1, le=8)
    """s x s sub-pixel rays per pixel (reference render)."""

    @model_validator(mode="before")
    @classmethod
    def _start_from_preset(cls, data: Any) -> Any:
        """Fields not given take the values of the ``fidelity`` preset (given fields override it)."""
        if not isinstance(data, dict) or data.get("fidelity", DEFAULT_PRESET) not in PRESETS:
            return data
        max_substeps = data.get("max_substeps", cls.model_fields["max_substeps"].default)
        if isinstance(max_substeps, bool) or not isinstance(max_substeps, int):
            max_substeps = cls.model_fields["max_substeps"].default     # the field check reports it
        merged = preset_fields(data.get("fidelity", DEFAULT_PRESET), max_substeps)
        for key, value in data.items():
            merged[key] = {**merged[key], **value} if isinstance(value, dict) and isinstance(merged.get(key), dict) \
                else value
        return merged

    @field_validator("ray_grid_step_px", "photometry_grid_step_px")
    @classmethod
    def _divides_frame(cls, value: int) -> int:
        if FRAME_PX % value:
            raise FieldProblem("", f"= {value} must divide the {FRAME_PX}-pixel frame; allowed: 1, 2, 4, ..., 256")
        return value

    @property
    def heat_shield_cone_angle_rad(self) -> float:
        """Full cone angle of the heat shield (rad)."""
        return math.radians(self.heat_shield_cone_angle_deg)

    def with_effects(self, **switches) -> SceneConfig:
        """A copy with some scene effect switches changed, e.g. ``config.with_effects(shadows=False)``.

        Parameters
        ----------
        **switches : bool
            ``[scene.effects]`` switches by name.

        Returns
        -------
        SceneConfig
            The copy (validated).
        """
        effects = SceneEffects.model_validate({**self.effects.model_dump(), **switches})
        return self.model_copy(update={"effects": effects})

    def with_fields(self, **values) -> SceneConfig:
        """A copy with some fields changed (unvalidated, like ``dataclasses.replace``).

        Parameters
        ----------
        **values
            Field values by name.

        Returns
        -------
        SceneConfig
            The copy.
        """
        return self.model_copy(update=values)


def apply_preset(config: SceneConfig, name: str) -> SceneConfig:
    """A configuration with the shortcuts of a fidelity preset, its other fields kept.

    Parameters
    ----------
    config : SceneConfig
        The configuration to change.
    name : str
        Preset name (:data:`simulator.fidelity.PRESETS`).

    Returns
    -------
    SceneConfig
        ``config`` with the preset's values.
    """
    updates = preset_fields(name, config.max_substeps)
    effects = config.effects.model_copy(update=updates.pop("effects"))
    camera_effects = config.camera_effects.model_copy(update=updates.pop("camera_effects"))
    return config.model_copy(update=dict(updates, effects=effects, camera_effects=camera_effects, fidelity=name))


def preset_config(name: str, base: SceneConfig | None = None) -> SceneConfig:
    """The :class:`SceneConfig` of a fidelity preset.

    Parameters
    ----------
    name : str
        Preset name (:data:`simulator.fidelity.PRESETS`).
    base : SceneConfig, optional
        Configuration whose other fields are kept (default: the defaults).

    Returns
    -------
    SceneConfig
        The preset's configuration.
    """
    preset_fields(name)                     # an unknown name: ValueError listing the allowed ones
    return SceneConfig(fidelity=cast(Preset, name)) if base is None else apply_preset(base, name)
