"""Synthetic MOC-NA-like terrain strips, one per MER landing-site appearance class (paper 2.3, 5).

No MOC images ship with the project, so each appearance class is represented by a deterministic
synthetic strip (default 1000 x 5000 px at 3 m/pixel: 3 km wide, 15 km long, north-up) built from
physical quantities, in this order:

1. Topography (m): self-affine background relief (Hurst exponent H, RMS bidirectional slope at the
   3 m pixel baseline), plus simple craters drawn from a power-law cumulative size-frequency
   distribution ``N(>D) = N_ref (D / D_ref)^-b`` per km^2 (parabolic bowl, raised rim of 0.2 x
   depth decaying as ``r^-3`` outside, depth/diameter log-uniform between degraded and fresh), plus
   class features: knobs/mesas (gkep), a large crater with its continuous ejecta, rays and secondary
   craters (heb).
2. Normal albedo: mean times ``(1 + spread * fractal)`` (power-law spectrum, outer scale 1 km),
   bright crater rims, dark dust devil tracks (gdcp), knob and ejecta albedo.

   ``contrast_scale`` s (1 unless a preset or site file sets it) multiplies the whole height field of
   step 1 (every slope: background relief, crater depths and rims, knob heights, ejecta) and every
   albedo modulation of step 2 (spread, rim, track, knob, ejecta contrasts); the mean albedo, the
   crater and track populations, the MOC geometry, haze and grain are unchanged.
3. Surface I/F at the MOC geometry: ``A * 2 mu0 / (mu + mu0) * f(alpha) / f(0)`` per facet (paper
   equations 1-3 normalised so that A is the I/F at normal incidence, emission and zero phase),
   with the direct sun beam (fraction ``exp(-tau / mu0)`` of the ground irradiance) blocked in cast
   shadows and the diffuse sky light lighting every facet like level ground.
4. MOC atmosphere: ``I/F = T * I/F_surf + (1 - T) * mean(I/F_surf) + I/F_path`` with
   ``T = exp(-tau / mu)``: light scattered out of the line of sight is spread over kilometres
   (contrast loss), and dust adds path radiance ``I/F_path`` (single scattering
   ``w0 P(alpha) / 4 * mu0 / (mu + mu0) * (1 - exp(-tau (1/mu + 1/mu0)))`` is about 0.04 for
   tau = 0.5, w0 = 0.97, P = 0.6 at 45 deg incidence).
5. MOC optics (Gaussian PSF, sigma 0.5 px) and shot-noise grain: Gaussian noise of standard deviation
   ``sqrt(I * <I>) / SNR`` (Poisson statistics, SNR given at the strip mean).

Strips are cached on disk as ``.npy`` (``$MOC2DIMES_CACHE`` or ``~/.cache/moc2dimes``), keyed by a
hash of the parameters, the seed and :data:`GENERATOR_VERSION`.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from simulator.scene.terrain import Terrain
from sitedata.terrain import synthetic_features as feat
from sitedata.terrain.synthetic_classes import CLASS_PRESETS, OUTER_SCALE_M, ClassTerrainParams

#: Bump when the generator's output for given parameters changes (invalidates caches).
GENERATOR_VERSION = 2
#: Gaussian sigma of the MOC NA point spread function at the strip scale (px).
MOC_PSF_SIGMA_PX = 0.5
#: Rim height / rim-to-floor depth of simple craters (fresh: rim 0.04 D, depth 0.2 D; Pike 1977).
RIM_TO_DEPTH = 0.2


def preset(name: str, **overrides) -> ClassTerrainParams:
    """The documented parameters of appearance class ``name``, with optional field overrides."""
    if name not in CLASS_PRESETS:
        raise ValueError(f"unknown synthetic terrain preset {name!r}; allowed: {', '.join(CLASS_PRESETS)}")
    params = dataclasses.replace(CLASS_PRESETS[name], **overrides) if overrides else CLASS_PRESETS[name]
    params.validate()
    return params


def _streams(seed: int) -> dict[str, np.random.Generator]:
    names = ("albedo", "relief", "craters", "tracks", "knobs", "ejecta", "grain")
    children = np.random.SeedSequence([int(seed), GENERATOR_VERSION]).spawn(len(names))
    return {name: np.random.default_rng(child) for name, child in zip(names, children)}


def _pareto_diameters(rng, count, d_min, d_max, exponent):
    u = rng.random(count)
    return d_min * (1.0 - u * (1.0 - (d_min / d_max) ** exponent)) ** (-1.0 / exponent)


def _crater_population(rng, params: ClassTerrainParams, area_km2, density, exponent, d_max):
    """Diameters (m) and depth/diameter ratios of a Poisson crater population."""
    d_ref, d_min = params.crater_reference_diameter_m, params.crater_min_diameter_m
    if density <= 0 or d_max <= d_min:
        return np.zeros(0), np.zeros(0)
    expected = area_km2 * density * ((d_min / d_ref) ** -exponent - (d_max / d_ref) ** -exponent)
    count = rng.poisson(expected)
    diameters = _pareto_diameters(rng, count, d_min, d_max, exponent)
    lo, hi = params.crater_depth_to_diameter
    depth_ratio = np.exp(rng.uniform(np.log(lo), np.log(hi), count))
    return diameters, depth_ratio


def _crater_height(rho, extent=2.0):
    """Unit-depth simple crater: parabolic bowl, rim of RIM_TO_DEPTH, exterior ~ rho^-3 to zero at extent."""
    taper = extent ** -3.0
    outside = RIM_TO_DEPTH * (np.maximum(rho, 1.0) ** -3.0 - taper) / (1.0 - taper)
    return np.where(rho <= 1.0, rho**2 - 1.0 + RIM_TO_DEPTH, np.where(rho < extent, outside, 0.0)).astype(np.float32)


def _rim_ring(rho):
    return np.exp(-(((rho - 1.0) / 0.1) ** 2)).astype(np.float32)


def _gaussian_bump(rho):
    return np.exp(-(rho**2)).astype(np.float32)


def _add_knobs(params: ClassTerrainParams, rng, relief_unit, height, albedo_mod) -> None:
    """Knobs/mesas: flat-topped, scarp-bounded hills with irregular outlines.

    Elliptical Gaussian footprints (log-uniform diameters, elongation 1-2.5) are summed into a
    coverage field U and a height-weighted field K; the mesa outline is where U, roughened by the
    high-passed relief field, exceeds 1/2, with a scarp ~2 px wide; the top is at the local
    weighted height K/U (knob_height_m).
    """
    shape, mpp = height.shape, params.metres_per_pixel
    count = rng.poisson(params.knob_density_per_km2 * params.area_km2)
    diam_px = np.exp(rng.uniform(*np.log(params.knob_diameter_m), count)) / mpp
    elong = rng.uniform(1.0, 2.5, count)
    axes = np.stack([0.6 * diam_px * np.sqrt(elong), 0.6 * diam_px / np.sqrt(elong)], 1)
    centres = rng.uniform((0, 0), shape, (count, 2))
    heights = rng.uniform(*params.knob_height_m, count)
    coverage, weighted = feat.splat_features(shape, centres, axes, rng.uniform(0, np.pi, count), 2.5,
                                             [(_gaussian_bump, np.ones(count)), (_gaussian_bump, heights)])
    rough = relief_unit - cv2.GaussianBlur(relief_unit, (0, 0), 8.0)
    rough /= max(float(rough.std()), 1e-12)
    outline = 1.0 / (1.0 + np.exp(-(coverage + 0.15 * rough - 0.5) / 0.04))
    height += outline * weighted / np.maximum(coverage, 0.05)
    albedo_mod += params.knob_albedo_contrast * outline


def _add_craters(shape, centres, diameters_m, depth_ratio, mpp, height, rim_albedo):
    radii = diameters_m / (2.0 * mpp)
    h, rim = feat.splat_features(shape, centres, np.stack([radii, radii], 1), np.zeros(len(radii)), 2.0,
                                 [(_crater_height, depth_ratio * diameters_m), (_rim_ring, np.ones(len(radii)))])
    height += h
    rim_albedo += rim


def _add_ejecta_craters(params: ClassTerrainParams, rng, height, albedo_mod, rim_albedo, relief_unit) -> None:
    """Large fresh craters (depth 0.15-0.2 D) centred 0.6 radius beyond alternate strip edges.

    Ejecta thickness falls as r^-3 from the rim to ``ejecta_extent_radii`` (part of the crater
    profile); the blanket albedo changes by ``ejecta_blanket_albedo_contrast`` x (R/r)^2, and patchy
    bright rays (40 random azimuths, 1.5-5 deg wide) add ``ejecta_ray_albedo_contrast`` x R/r; the
    blanket is hummocky (RMS ``ejecta_relief_rms_m`` at the rim, falling as (R/r)^1.5); secondary
    craters (SFD exponent 3, 9-60 m, fresh) cover the apron at ``secondary_density_per_km2``.
    """
    shape, mpp = height.shape, params.metres_per_pixel
    radius_px = 0.5 * params.ejecta_crater_diameter_m / mpp
    extent = params.ejecta_extent_radii
    spacing_px = params.ejecta_crater_spacing_m / mpp
    count = int(np.ceil(shape[0] / spacing_px)) + 1
    first = rng.uniform(0.0, spacing_px)
    centre_rows = first - spacing_px + spacing_px * np.arange(count) + rng.uniform(-0.1, 0.1, count) * spacing_px
    sides = (np.arange(count) + rng.integers(2)) % 2
    centre_cols = np.where(sides == 0, -0.6 * radius_px, shape[1] - 1 + 0.6 * radius_px)
    centres = np.stack([centre_rows, centre_cols], 1)
    depth = rng.uniform(0.15, 0.2, count) * params.ejecta_crater_diameter_m
    axes = np.full((count, 2), radius_px)
    rays_az = rng.uniform(0, 2 * np.pi, (count, 40))
    rays_width = np.radians(rng.uniform(1.5, 5.0, (count, 40)))
    rays_amp = rng.uniform(0.0, 1.0, (count, 40))
    h, = feat.splat_features(shape, centres, axes, np.zeros(count), extent,
                             [(lambda rho: _crater_height(rho, extent), depth)])
    height += h
    theta = np.linspace(-np.pi, np.pi, 3600, endpoint=False)
    hummocks = np.zeros(shape, np.float32)
    patchy = np.clip(1.0 + relief_unit, 0.0, 2.0)        # rays break into streaks and patches
    reach = extent * radius_px
    for i in range(count):
        r0, r1 = max(0, int(centres[i, 0] - reach)), min(shape[0], int(centres[i, 0] + reach) + 1)
        c0, c1 = max(0, int(centres[i, 1] - reach)), min(shape[1], int(centres[i, 1] + reach) + 1)
        if r0 >= r1 or c0 >= c1:
            continue
        d_row = np.arange(r0, r1, dtype=np.float32)[:, None] - np.float32(centres[i, 0])
        d_col = np.arange(c0, c1, dtype=np.float32)[None, :] - np.float32(centres[i, 1])
        rho = np.hypot(d_row, d_col) / np.float32(radius_px)
        apron = ((rho >= 1.0) & (rho < extent)).astype(np.float32)
        offset = np.angle(np.exp(1j * (theta[:, None] - rays_az[i][None, :])))
        pattern = (rays_amp[i] * np.exp(-((offset / rays_width[i]) ** 2))).sum(axis=1).astype(np.float32)
        azimuth = np.arctan2(d_col, -d_row)
        index = ((azimuth + np.pi) * (len(theta) / (2 * np.pi))).astype(np.int64) % len(theta)
        safe_rho = np.maximum(rho, 1.0)
        taper = np.clip(extent - rho, 0.0, 1.0)           # fade over the last radius
        albedo_mod[r0:r1, c0:c1] += apron * taper * (
            params.ejecta_blanket_albedo_contrast / safe_rho**2
            + params.ejecta_ray_albedo_contrast * pattern[index] * patchy[r0:r1, c0:c1] / safe_rho)
        hummocks[r0:r1, c0:c1] += apron * taper / safe_rho**1.5
    # hummocky ejecta: the relief field high-passed at ~30 m, RMS ejecta_relief_rms_m at the rim
    rough = relief_unit - cv2.GaussianBlur(relief_unit, (0, 0), 10.0)
    rough *= np.float32(params.ejecta_relief_rms_m / max(float(rough.std()), 1e-12))
    height += np.minimum(hummocks, 1.0) * rough
    # secondary craters on the aprons
    apron_km2 = count * np.pi * (extent**2 - 1.2**2) * (radius_px * mpp / 1000.0) ** 2
    diam, ratio = _crater_population(rng, dataclasses.replace(params, crater_depth_to_diameter=(0.08, 0.2)),
                                     apron_km2, params.secondary_density_per_km2, 3.0, 60.0)
    host = rng.integers(0, count, len(diam))
    rho = np.sqrt(rng.uniform(1.2**2, extent**2, len(diam)))
    angle = rng.uniform(0, 2 * np.pi, len(diam))
    sec_centres = centres[host] + radius_px * rho[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
    _add_craters(shape, sec_centres, diam, ratio, mpp, height, rim_albedo)


def surface_fields(params: ClassTerrainParams, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Height (m) and normal albedo of a class strip before photometry, float32 (rows, cols)."""
    params.validate()
    rng = _streams(seed)
    shape, mpp = (params.rows, params.cols), params.metres_per_pixel
    outer_px = OUTER_SCALE_M / mpp
    # background relief scaled to the RMS slope over one pixel
    relief = feat.gaussian_random_field(shape, 2.0 * params.hurst_exponent + 2.0, outer_px, rng["relief"])
    step_rms = float(np.sqrt(np.mean(np.diff(relief, axis=1) ** 2)))
    height = relief * np.float32(np.tan(np.radians(params.rms_slope_deg)) * mpp / max(step_rms, 1e-12))
    albedo_mod = params.albedo_relative_spread * feat.gaussian_random_field(
        shape, params.albedo_spectral_exponent, outer_px, rng["albedo"])
    rim_albedo = np.zeros(shape, np.float32)

    # plains craters, centres over the strip padded by the largest radius (uniform density at borders)
    pad = params.crater_max_diameter_m / mpp
    padded_km2 = (shape[0] + 2 * pad) * (shape[1] + 2 * pad) * (mpp / 1000.0) ** 2
    diam, ratio = _crater_population(rng["craters"], params, padded_km2, params.crater_density_per_km2,
                                     params.crater_sfd_exponent, params.crater_max_diameter_m)
    centres = rng["craters"].uniform((-pad, -pad), (shape[0] + pad, shape[1] + pad), (len(diam), 2))
    _add_craters(shape, centres, diam, ratio, mpp, height, rim_albedo)

    if params.ejecta_crater_diameter_m > 0:
        _add_ejecta_craters(params, rng["ejecta"], height, albedo_mod, rim_albedo, relief)

    if params.knob_density_per_km2 > 0:
        _add_knobs(params, rng["knobs"], relief, height, albedo_mod)

    scale = params.contrast_scale
    if scale != 1.0:            # every slope and every albedo contrast x scale (module docstring)
        height *= np.float32(scale)
        albedo_mod *= np.float32(scale)
    rim_brightening = 1.0 + scale * params.crater_rim_albedo_contrast * np.minimum(rim_albedo, 1.5)
    albedo = params.normal_albedo_mean * (1.0 + albedo_mod) * rim_brightening
    if params.track_length_per_km2 > 0:
        narrowest_m, widest_m = params.track_width_m
        tracks = feat.draw_tracks(shape, params.track_length_per_km2 * params.area_km2 * 1000.0 / mpp,
                                  (narrowest_m / mpp, widest_m / mpp), np.radians(params.track_azimuth_deg),
                                  np.radians(params.track_azimuth_spread_deg), params.track_mean_length_m / mpp,
                                  rng["tracks"])
        albedo *= 1.0 - scale * params.track_albedo_contrast * tracks
    return height.astype(np.float32), np.clip(albedo, 0.02, 0.8).astype(np.float32)


def moc_geometry_rad(params: ClassTerrainParams) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """Unit vectors to the sun and to MOC (east, north, up) and incidence, emission, phase (rad)."""
    inc, emi = np.radians(params.moc_incidence_deg), np.radians(params.moc_emission_deg)
    az_sun, az_sc = np.radians(params.moc_sun_azimuth_deg), np.radians(params.moc_spacecraft_azimuth_deg)
    sun = np.array([np.sin(inc) * np.sin(az_sun), np.sin(inc) * np.cos(az_sun), np.cos(inc)])
    view = np.array([np.sin(emi) * np.sin(az_sc), np.sin(emi) * np.cos(az_sc), np.cos(emi)])
    phase = float(np.arccos(np.clip(sun @ view, -1.0, 1.0)))
    return sun, view, float(inc), float(emi), phase


def generate_reflectance(params: ClassTerrainParams, seed: int) -> np.ndarray:
    """The MOC-observed I/F strip of a class (float32 (rows, cols)), no caching. See module doc."""
    height, albedo = surface_fields(params, seed)
    mpp = params.metres_per_pixel
    sun, view, inc, emi, phase = moc_geometry_rad(params)
    sunlit = 1.0 - feat.cast_shadow_fraction(height, mpp, np.radians(params.moc_sun_azimuth_deg), 0.5 * np.pi - inc)
    d_row, d_col = np.gradient(height, mpp)             # rows run south: dh/dnorth = -dh/drow
    del height
    nx, ny = -d_col, d_row                              # normal ~ (-dh/deast, -dh/dnorth, 1)
    inv_norm = 1.0 / np.sqrt(nx * nx + ny * ny + 1.0)
    mu0 = np.clip((nx * sun[0] + ny * sun[1] + sun[2]) * inv_norm, 0.0, 1.0)
    mu = np.clip((nx * view[0] + ny * view[1] + view[2]) * inv_norm, 0.05, 1.0)
    del d_row, d_col, nx, ny, inv_norm
    phase_factor = feat.phase_function(phase) / feat.phase_function(0.0)
    direct = np.exp(-params.haze_optical_depth / max(np.cos(inc), 0.05))
    flat = 2.0 * np.cos(inc) / (np.cos(emi) + np.cos(inc))
    lit = direct * sunlit * (2.0 * mu0 / (mu + mu0 + 1e-6)) + (1.0 - direct) * flat
    del sunlit, mu0, mu
    surface = albedo * phase_factor * lit
    transmission = np.exp(-params.haze_optical_depth / np.cos(emi))
    observed = transmission * surface + (1.0 - transmission) * float(surface.mean()) + params.haze_path_if
    observed = cv2.GaussianBlur(observed.astype(np.float32), (0, 0), MOC_PSF_SIGMA_PX)
    mean_if = float(observed.mean())
    noise = _streams(seed)["grain"].standard_normal(observed.shape, dtype=np.float32)
    observed = observed + noise * np.sqrt(observed * mean_if) / np.float32(params.grain_snr)
    return np.clip(observed, 1e-4, None).astype(np.float32)


def cache_directory() -> Path:
    """``$MOC2DIMES_CACHE`` if set, else ``~/.cache/moc2dimes``."""
    env = os.environ.get("MOC2DIMES_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "moc2dimes"


def cache_key(params: ClassTerrainParams, seed: int) -> str:
    """Hex digest identifying (generator version, parameters, seed)."""
    text = json.dumps({"version": GENERATOR_VERSION, "seed": int(seed), "params": dataclasses.asdict(params)},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def cached_reflectance(params: ClassTerrainParams, seed: int, cache_dir: Path | None = None) -> np.ndarray:
    """:func:`generate_reflectance`, read from / written to the on-disk cache (atomic write)."""
    directory = Path(cache_dir) if cache_dir is not None else cache_directory()
    path = directory / f"synthetic_{params.name}_{cache_key(params, seed)}.npy"
    if path.exists():
        try:
            data = np.load(path, allow_pickle=False)
            if data.shape == (params.rows, params.cols) and data.dtype == np.float32:
                return data
        except (OSError, ValueError):
            pass                                            # corrupt cache entry: regenerate
    data = generate_reflectance(params, seed)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory, suffix=".tmp", delete=False) as handle:
            np.save(handle, data)
        os.chmod(handle.name, 0o644)
        os.replace(handle.name, path)
    except OSError:
        pass                                                # read-only cache: still return the data
    return data


def synthetic_terrain(params: ClassTerrainParams | str, seed: int, cache: bool = True,
                      cache_dir: Path | None = None) -> Terrain:
    """A synthetic class strip as a :class:`Terrain`, centred on world (0, 0), north-up.

    Parameters
    ----------
    params : ClassTerrainParams or preset name
    seed : int, non-negative
    cache : bool, use the on-disk cache
    """
    if isinstance(params, str):
        params = preset(params)
    params.validate()
    reflectance = cached_reflectance(params, seed, cache_dir) if cache else generate_reflectance(params, seed)
    _, _, inc, emi, phase = moc_geometry_rad(params)
    mpp = params.metres_per_pixel
    origin = np.array([-0.5 * (params.cols - 1) * mpp, 0.5 * (params.rows - 1) * mpp])
    return Terrain(reflectance_if=reflectance, metres_per_pixel=mpp, origin_m=origin, moc_incidence_rad=inc,
                   moc_emission_rad=emi, moc_phase_rad=phase, name=f"synthetic-{params.name}-{seed}")
