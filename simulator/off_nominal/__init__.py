"""Off-nominal camera and scenario effects (paper 3.3 and 5): configuration and per-case artefacts.

Every effect is switched off by its default except CCD blooming (a real CCD blooms; with nothing
saturating it changes nothing and costs nothing). The physics of each effect lives in its own module:

* dust on the front lens element  -> :mod:`simulator.off_nominal.dust` (transmission map, fixed for the case)
* hot pixels (dark spikes)        -> :mod:`simulator.off_nominal.hot_pixels` (extra dark rate, fixed for the case)
* energetic particle hits         -> :mod:`simulator.off_nominal.particle_hits` (charge tracks, new for every image)
* heat-shield specular glint      -> :mod:`simulator.scene.glint` (added to the radiance by the scene stage)
* blooming                        -> :mod:`simulator.detector.blooming` (charge above full well spills along columns)
* high motion blur                -> :mod:`simulator.scene.descent_profile` (angular rate multiplier)
* dust-devil and cloud shadows    -> :mod:`simulator.off_nominal.moving_shadows` (drawn per case, moving)
* excessive dark current          -> ``[scene.camera_effects] dark_current_scale`` (already in the chain)

TOML: ``[scene.off_nominal]``, declared once by :class:`OffNominalConfig` (SI units, angles in degrees
at this edge; every key optional, defaults = the nominal camera; ``campaign schema scene`` prints them).

Randomness: :func:`draw_case_artefacts` draws the dust and hot pixels of a case once (the same for the
three images); :func:`with_particle_hits` adds one image's particle hits from that image's own stream.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from pydantic import Field

from config_tables.models import ConfigModel
from flight_interface.camera import Camera
from simulator.off_nominal.dust import DustParticles, draw_particles, transmission_map
from simulator.off_nominal.hot_pixels import HotPixels, draw_hot_pixels
from simulator.off_nominal.moving_shadows import MovingShadowDraws, MovingShadowsConfig, draw_moving_shadows
from simulator.off_nominal.particle_hits import ParticleHits, draw_particle_hits


class _CameraAndScenarioKeys(ConfigModel):
    """The keys of ``[scene.off_nominal]`` before the moving shadows' (declared first, listed first)."""

    dust_particle_count: int = Field(0, ge=0, le=100_000)
    """Poisson mean of the number of dust particles on the front element per case."""
    dust_particle_diameter_mean_m: float = Field(150e-6, gt=0.0, le=0.01)
    """Mean of the exponential particle diameter distribution (m)."""
    dust_particle_diameter_max_m: float = Field(1.0e-3, gt=0.0, le=0.05)
    """Largest particle diameter (m; the distribution is truncated here)."""
    dust_lens_distance_m: float = Field(8.0e-3, gt=0.0, le=0.2)
    """Front element to entrance pupil (m)."""
    hot_pixel_fraction: float = Field(0.0, ge=0.0, le=1.0)
    """Fraction of pixels that are hot."""
    hot_pixel_amplitude_mean_e_per_s: float = Field(1.0e6, gt=0.0, le=1e12)
    """Exponential mean of a hot pixel's extra dark rate at the reference temperature (e-/s)."""
    particle_hit_rate_per_cm2_s: float = Field(0.0, ge=0.0, le=1e7)
    """Energetic particle flux through the CCD (hits per cm^2 per s)."""
    particle_hit_charge_e_per_m: float = Field(1.0e8, ge=0.0, le=1e12)
    """Electrons per metre of path in silicon (~100 e-/um)."""
    particle_hit_depth_m: float = Field(10.0e-6, gt=0.0, le=1e-3)
    """Charge-collection depth (m)."""
    particle_hit_max_track_length_m: float = Field(300e-6, gt=0.0, le=0.05)
    """Longest projected track on the array (m)."""
    heat_shield_glint: bool = False
    """Specular glint of the sun on the heat-shield lining."""
    heat_shield_specular_reflectance: float = Field(0.05, ge=0.0, le=1.0)
    """Specular reflectance of the lining."""
    heat_shield_specular_roughness_deg: float = Field(3.0, ge=0.5, le=45.0)
    """RMS facet slope of the lining's specular lobe (deg)."""
    blooming: bool = True
    """Charge above full well spills along the columns (else it is clipped)."""
    angular_rate_multiplier: float = Field(1.0, ge=0.0, le=100.0)
    """Scales the angular rates about each exposure mid-time (high motion blur)."""

    @property
    def heat_shield_specular_roughness_rad(self) -> float:
        return math.radians(self.heat_shield_specular_roughness_deg)



class OffNominalConfig(MovingShadowsConfig, _CameraAndScenarioKeys):
    """``[scene.off_nominal]``: off-nominal effect parameters (SI units; the defaults are the nominal camera)."""

    @property
    def needs_case_artefacts(self) -> bool:
        """True when the case needs random artefacts (dust, hot pixels or particle hits)."""
        return (self.dust_particle_count > 0 or self.hot_pixel_fraction > 0 or self.particle_hit_rate_per_cm2_s > 0
                or self.moving_shadow_count > 0)


@dataclass(frozen=True)
class OffNominalArtefacts:
    """What the camera chain applies for the off-nominal effects of one image.

    Attributes
    ----------
    dust_transmission : (H, W) float32 or None, relative transmission of the front element (case-fixed)
    hot_pixels : HotPixels or None, extra dark rate of the hot pixels (case-fixed)
    particle_hits : ParticleHits or None, this image's particle charge
    blooming : bool, charge above full well spills along the columns (else it is clipped)
    dust_particles : DustParticles or None, the particles behind ``dust_transmission`` (diagnostics)
    moving_shadows : MovingShadowDraws or None, the case's dust-devil and cloud shadows (scene)
    """

    dust_transmission: np.ndarray | None = None
    hot_pixels: HotPixels | None = None
    particle_hits: ParticleHits | None = None
    blooming: bool = True
    dust_particles: DustParticles | None = None
    moving_shadows: MovingShadowDraws | None = None


def draw_case_artefacts(camera: Camera, config: OffNominalConfig, rng: np.random.Generator) -> OffNominalArtefacts:
    """The case-fixed artefacts: dust, then hot pixels, then the moving shadows' draws, from ``rng``.

    Effects at their defaults draw nothing, so adding an effect never changes another's draws except
    by its own position in the stream (dust first, hot pixels second, moving shadows third). No
    particle hits yet (:func:`with_particle_hits`).

    Parameters
    ----------
    camera : Camera
        The camera.
    config : OffNominalConfig
        ``[scene.off_nominal]``.
    rng : numpy.random.Generator
        The case's artefact stream.

    Returns
    -------
    OffNominalArtefacts
        Dust transmission, hot pixels and moving-shadow draws (each None when off).
    """
    transmission = particles = hot = None
    if config.dust_particle_count > 0:
        particles = draw_particles(camera, rng, config.dust_particle_count, config.dust_particle_diameter_mean_m,
                                   config.dust_particle_diameter_max_m, config.dust_lens_distance_m)
        if particles.diameters_m.size:
            transmission = transmission_map(camera, particles, config.dust_lens_distance_m)
    if config.hot_pixel_fraction > 0:
        hot = draw_hot_pixels(camera, rng, config.hot_pixel_fraction, config.hot_pixel_amplitude_mean_e_per_s)
    return OffNominalArtefacts(dust_transmission=transmission, hot_pixels=hot, blooming=config.blooming,
                               dust_particles=particles, moving_shadows=draw_moving_shadows(config, rng))


def with_particle_hits(artefacts: OffNominalArtefacts | None, camera: Camera, config: OffNominalConfig,
                       rng: np.random.Generator) -> OffNominalArtefacts:
    """The case artefacts plus one image's particle hits (nothing is drawn when the hit rate is 0).

    Parameters
    ----------
    artefacts : OffNominalArtefacts or None
        The case artefacts (:func:`draw_case_artefacts`).
    camera : Camera
        The camera.
    config : OffNominalConfig
        ``[scene.off_nominal]``.
    rng : numpy.random.Generator
        The image's own stream.

    Returns
    -------
    OffNominalArtefacts
        A copy with ``particle_hits`` set.
    """
    artefacts = OffNominalArtefacts(blooming=config.blooming) if artefacts is None else artefacts
    if config.particle_hit_rate_per_cm2_s <= 0:
        return artefacts
    hits = draw_particle_hits(camera, rng, config.particle_hit_rate_per_cm2_s,
                                            config.particle_hit_charge_e_per_m, config.particle_hit_depth_m,
                                            config.particle_hit_max_track_length_m)
    return replace(artefacts, particle_hits=hits)
