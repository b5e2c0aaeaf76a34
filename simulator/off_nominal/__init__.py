"""Off-nominal camera and scenario effects (paper 3.3 and 5): configuration and per-case artefacts.

Every effect is switched off by its default except CCD blooming (a real CCD blooms; with nothing
saturating it changes nothing and costs nothing). The physics of each effect lives in its own module:

* dust on the front lens element  -> :mod:`simulator.off_nominal.dust` (transmission map, fixed for the case)
* hot pixels (dark spikes)        -> :mod:`simulator.hot_pixels` (extra dark rate, fixed for the case)
* energetic particle hits         -> :mod:`simulator.particle_hits` (charge tracks, new for every image)
* heat-shield specular glint      -> :mod:`simulator.heat_shield` (drawn into the radiance)
* blooming                        -> :mod:`simulator.blooming` (charge above full well spills along columns)
* high motion blur                -> :mod:`simulator.scene.descent_profile` (angular rate multiplier)
* excessive dark current          -> ``[scene.camera_effects] dark_current_scale`` (already in the chain)

TOML (``[scene.off_nominal]``, parsed by :func:`off_nominal_config_from_table`; SI units, angles in
degrees only here), with defaults::

    [scene.off_nominal]
    dust_particle_count = 0                      # Poisson mean of the particle count per case (int >= 0)
    dust_particle_diameter_mean_m = 150e-6       # exponential size distribution, truncated at the max
    dust_particle_diameter_max_m = 1.0e-3
    dust_lens_distance_m = 8.0e-3                # front element to entrance pupil
    hot_pixel_fraction = 0.0                     # fraction of pixels that are hot, 0 .. 1
    hot_pixel_amplitude_mean_e_per_s = 1.0e6     # exponential mean of the extra dark rate at the reference temperature
    particle_hit_rate_per_cm2_s = 0.0            # energetic particle flux through the CCD
    particle_hit_charge_e_per_m = 1.0e8          # electrons per metre of path in silicon (~100 e-/um)
    particle_hit_depth_m = 10.0e-6               # charge-collection depth
    particle_hit_max_track_length_m = 300e-6     # longest projected track on the array
    heat_shield_glint = false
    heat_shield_specular_reflectance = 0.05
    heat_shield_specular_roughness_deg = 3.0     # rms facet slope of the blanket's specular lobe
    blooming = true
    angular_rate_multiplier = 1.0                # scales the angular rates about each exposure mid-time

Randomness: :func:`draw_case_artefacts` draws the dust and hot pixels of a case once (the same for the
three images); :func:`with_particle_hits` adds one image's particle hits from that image's own stream.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from simulator.off_nominal.dust import DustParticles, draw_particles, transmission_map
from simulator.off_nominal.hot_pixels import HotPixels, draw_hot_pixels
from simulator.off_nominal.particle_hits import ParticleHits, draw_particle_hits
from flight_interface.camera import Camera
from flight_interface.tomlfields import Table


@dataclass(frozen=True)
class OffNominalConfig:
    """Off-nominal effect parameters (SI units); the defaults are the nominal camera (module doc)."""

    dust_particle_count: int = 0
    dust_particle_diameter_mean_m: float = 150e-6
    dust_particle_diameter_max_m: float = 1.0e-3
    dust_lens_distance_m: float = 8.0e-3
    hot_pixel_fraction: float = 0.0
    hot_pixel_amplitude_mean_e_per_s: float = 1.0e6
    particle_hit_rate_per_cm2_s: float = 0.0
    particle_hit_charge_e_per_m: float = 1.0e8
    particle_hit_depth_m: float = 10.0e-6
    particle_hit_max_track_length_m: float = 300e-6
    heat_shield_glint: bool = False
    heat_shield_specular_reflectance: float = 0.05
    heat_shield_specular_roughness_rad: float = float(np.radians(3.0))
    blooming: bool = True
    angular_rate_multiplier: float = 1.0

    @property
    def needs_case_artefacts(self) -> bool:
        """True when the case needs random artefacts (dust, hot pixels or particle hits)."""
        return self.dust_particle_count > 0 or self.hot_pixel_fraction > 0 or self.particle_hit_rate_per_cm2_s > 0


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
    """

    dust_transmission: np.ndarray | None = None
    hot_pixels: HotPixels | None = None
    particle_hits: ParticleHits | None = None
    blooming: bool = True
    dust_particles: DustParticles | None = None


def draw_case_artefacts(camera: Camera, config: OffNominalConfig, rng: np.random.Generator) -> OffNominalArtefacts:
    """The case-fixed artefacts (dust, then hot pixels, from ``rng``); no particle hits yet.

    Effects at their defaults draw nothing, so adding an effect never changes another's draws
    except by its own position in the stream (dust first, hot pixels second).
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
                               dust_particles=particles)


def with_particle_hits(artefacts: OffNominalArtefacts | None, camera: Camera, config: OffNominalConfig,
                       rng: np.random.Generator) -> OffNominalArtefacts:
    """The case artefacts plus one image's particle hits drawn from that image's own ``rng``
    (nothing is drawn when the hit rate is 0)."""
    artefacts = OffNominalArtefacts(blooming=config.blooming) if artefacts is None else artefacts
    if config.particle_hit_rate_per_cm2_s <= 0:
        return artefacts
    hits = draw_particle_hits(camera, rng, config.particle_hit_rate_per_cm2_s,
                                            config.particle_hit_charge_e_per_m, config.particle_hit_depth_m,
                                            config.particle_hit_max_track_length_m)
    return replace(artefacts, particle_hits=hits)


def off_nominal_config_from_table(table: Table) -> OffNominalConfig:
    """Build an :class:`OffNominalConfig` from a ``[scene.off_nominal]`` table; every key is optional.

    Errors are one line naming the file, the field and the allowed values.
    """
    default = OffNominalConfig()

    def number(key, minimum, maximum, exclusive_minimum=False):
        return table.number(key, default=getattr(default, key), minimum=minimum, maximum=maximum,
                            exclusive_minimum=exclusive_minimum)

    config = OffNominalConfig(
        dust_particle_count=table.integer("dust_particle_count", default=default.dust_particle_count,
                                          minimum=0, maximum=100_000),
        dust_particle_diameter_mean_m=number("dust_particle_diameter_mean_m", 0.0, 0.01, exclusive_minimum=True),
        dust_particle_diameter_max_m=number("dust_particle_diameter_max_m", 0.0, 0.05, exclusive_minimum=True),
        dust_lens_distance_m=number("dust_lens_distance_m", 0.0, 0.2, exclusive_minimum=True),
        hot_pixel_fraction=number("hot_pixel_fraction", 0.0, 1.0),
        hot_pixel_amplitude_mean_e_per_s=number("hot_pixel_amplitude_mean_e_per_s", 0.0, 1e12, exclusive_minimum=True),
        particle_hit_rate_per_cm2_s=number("particle_hit_rate_per_cm2_s", 0.0, 1e7),
        particle_hit_charge_e_per_m=number("particle_hit_charge_e_per_m", 0.0, 1e12),
        particle_hit_depth_m=number("particle_hit_depth_m", 0.0, 1e-3, exclusive_minimum=True),
        particle_hit_max_track_length_m=number("particle_hit_max_track_length_m", 0.0, 0.05, exclusive_minimum=True),
        heat_shield_glint=table.boolean("heat_shield_glint", default=default.heat_shield_glint),
        heat_shield_specular_reflectance=number("heat_shield_specular_reflectance", 0.0, 1.0),
        heat_shield_specular_roughness_rad=(float(np.radians(table.number(
            "heat_shield_specular_roughness_deg", minimum=0.5, maximum=45.0)))
            if table.has("heat_shield_specular_roughness_deg") else default.heat_shield_specular_roughness_rad),
        blooming=table.boolean("blooming", default=default.blooming),
        angular_rate_multiplier=number("angular_rate_multiplier", 0.0, 100.0),
    )
    allowed = {f.name for f in fields(OffNominalConfig)} - {"heat_shield_specular_roughness_rad"}
    allowed |= {"heat_shield_specular_roughness_deg"}
    for key in table.data:
        if key not in allowed:
            raise table.fail(key, f"is not a known field; allowed: {', '.join(sorted(allowed))}")
    return config
