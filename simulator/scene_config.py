"""Scene configuration: every scene parameter (SI units) and effect switch of one descent image.

:class:`SceneEffects` holds the physics switches and the fidelity shortcuts, :class:`SceneConfig` the
parameters, the camera effect switches (:class:`~simulator.detector.camera_chain.CameraEffects`), the
off-nominal effects (:class:`~simulator.off_nominal.OffNominalConfig`) and the atmosphere
(:class:`AtmosphereConfig`). The presets of shortcuts are in
:mod:`simulator.fidelity`; the TOML ``[scene]`` table is read by :mod:`simulator.scene_table`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from simulator.detector.camera_chain import CameraEffects
from simulator.off_nominal import OffNominalConfig
from simulator.scene import atmosphere, photometry


@dataclass(frozen=True)
class SceneEffects:
    """Switches of the scene model; all on (the defaults) is the nominal simulator.

    Physics switches: ``photometric_correction`` (DIMES/MOC ratio of eq. 1-3, hence the opposition
    halo), ``spectral_ratio``, ``shadows`` (lander, backshell, parachute, heat shield), ``heat_shield``
    (drawn when in view), ``motion_blur`` (sub-poses per period). Fidelity shortcuts (switch off for the
    reference render): ``coarse_ray_grid`` (rays interpolated from a node grid), ``coarse_photometry``
    (ratio on the node grid), ``share_still_fields`` (one field for all three periods when the image
    moves by less than ``still_shift_terrain_px``), ``warp_smear_fields`` (fast-flush and frame-transfer
    fields warped from the exposure-centre field along the ground-plane flow instead of re-rendered,
    see :func:`simulator.scene.radiance.warped_field`), ``pixel_area_filter`` (the pixel-area integral of the
    terrain approximated from point samples, see :func:`simulator.scene.radiance.pixel_area_average`; the reference
    supersamples instead).
    """

    photometric_correction: bool = True
    spectral_ratio: bool = True
    shadows: bool = True
    heat_shield: bool = True
    motion_blur: bool = True
    coarse_ray_grid: bool = True
    coarse_photometry: bool = True
    share_still_fields: bool = True
    warp_smear_fields: bool = True
    pixel_area_filter: bool = True


@dataclass(frozen=True)
class AtmosphereConfig:
    """Dust between the ground, the orbiter and the descent camera (:mod:`simulator.scene.atmosphere`,
    equations A1-A7). Off (the default) while ``orbital_optical_depth`` is 0: the renderer then skips the
    stage and the images are those of a scene without atmosphere, bit for bit.

    ``orbital_optical_depth``: zenith dust optical depth of the whole column when the orbital terrain
    image was taken (also the column over the descent: the same dust); ``scale_height_m``: dust scale
    height; ``single_scattering_albedo``, ``forward_asymmetry``, ``backward_asymmetry``,
    ``forward_fraction``: single scattering of the dust (double Henyey-Greenstein); ``descent_path``:
    the dust below the descent camera attenuates and adds path light (off: the camera sees the ground
    clear, only the orbital haze is removed); ``diffuse_transmission``: light scattered once into the
    line of sight from the surroundings (adjacency) and skylight on the ground (off: direct beam only).
    """

    orbital_optical_depth: float = 0.0
    scale_height_m: float = atmosphere.MARS_SCALE_HEIGHT_M
    single_scattering_albedo: float = 0.94
    forward_asymmetry: float = 0.70
    backward_asymmetry: float = -0.30
    forward_fraction: float = 0.90
    descent_path: bool = True
    diffuse_transmission: bool = True

    @property
    def enabled(self) -> bool:
        return self.orbital_optical_depth > 0.0


@dataclass(frozen=True)
class SceneConfig:
    """Scene parameters (SI units) and effect switches. Defaults are documented in the modules:
    :mod:`simulator.photometry` (sun distance, spectral ratio), :mod:`simulator.shadow` (casters),
    :mod:`simulator.heat_shield`, :mod:`simulator.motion_blur`."""

    effects: SceneEffects = SceneEffects()
    camera_effects: CameraEffects = CameraEffects()
    off_nominal: OffNominalConfig = OffNominalConfig()
    atmosphere: AtmosphereConfig = AtmosphereConfig()
    sun_distance_au: float = photometry.MARS_MEAN_SUN_DISTANCE_AU
    spectral_ratio: float = 0.906
    lander_diameter_m: float = 1.9
    backshell_diameter_m: float = 2.65
    backshell_distance_m: float = 20.0
    parachute_diameter_m: float = 15.0
    parachute_distance_m: float = 30.0
    shadow_diffuse_fraction: float = 0.3
    heat_shield_diameter_m: float = 5.3
    heat_shield_cone_angle_rad: float = float(np.radians(140.0))
    heat_shield_reflectance: float = 0.07
    ray_grid_step_px: int = 16
    photometry_grid_step_px: int = 16
    max_substeps: int = 16
    still_shift_terrain_px: float = 1.0
    substeps_per_terrain_px: float = 1.0   # motion sub-poses per terrain pixel of image shift
    supersample: int = 1                   # s x s sub-pixel rays per pixel (reference render)

    def with_effects(self, **switches) -> "SceneConfig":
        """A copy with some scene effect switches changed, e.g. ``config.with_effects(shadows=False)``."""
        return replace(self, effects=replace(self.effects, **switches))


REFERENCE_EFFECTS = dict(coarse_ray_grid=False, coarse_photometry=False, share_still_fields=False,
                         warp_smear_fields=False, pixel_area_filter=False)
