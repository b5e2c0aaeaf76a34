"""Synthetic relief per appearance class: the class strip's height field, paired with the I/F its
ground would show were it level, for the relief renderer (:mod:`simulator.scene.relief`).

The height field is the one the synthetic generator already builds before photometry
(:func:`sitedata.terrain.synthetic_terrain.surface_fields`), matched to each class's kind of ground:

* background: self-affine relief (Hurst 0.8) scaled to the class's RMS bidirectional slope at the
  3 m baseline (1 deg Meridiani smooth plains .. 4 deg Gusev dark plains and knobby terrain; Kirk et al.
  2003, Beyer et al. 2003), the slope distribution of the class;
* simple craters of the class's size-frequency distribution: parabolic bowl, depth/diameter
  log-uniform from degraded hollows (0.03-0.05) to fresh craters (0.18-0.2: Pike 1977, d/D = 0.196
  for fresh lunar and Martian simple craters), rim height 0.2 x depth (0.04 D when fresh; Pike 1977
  h/D ~ 0.036) falling off as r^-3 outside the rim to zero at 2 radii (ejecta thickness, McGetchin et al.
  1973); degraded craters shallower with lower rims (Fassett and Thomson 2014: d/D decays from ~0.2
  with diffusive degradation);
* gkep: flat-topped knobs and mesas 20-150 m across, 5-40 m high, scarps ~2 px wide;
* heb: the 2 km crater's ejecta apron, hummocky, with secondaries.

Measured on the Gusev strips (seeds 4101-4103; :func:`relief_statistics`): height RMS 3.0 (gcp),
4.4 (gdcp), 11.4 (gkep) m; the 1-km mean height varies by 1-2 m RMS, so the radar altitude above the
datum z = 0 (the strip's mean plane) differs from the height above the local ground by that much.

The paired I/F (:func:`level_ground_reflectance`) is the generator's MOC image without slope shading
and cast shadows: albedo x eq. (1) of level ground at the MOC geometry, then the same MOC haze, PSF
and grain as the plain strip. The descent geometry's shading and shadows are added by the renderer,
so relief shading is never counted twice (the plain strip bakes the MOC's shading into its I/F).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from simulator.scene.height_field import ReliefTerrain
from sitedata.terrain import synthetic_features as feat
from sitedata.terrain.synthetic_classes import ClassTerrainParams
from sitedata.terrain.synthetic_terrain import (
    MOC_PSF_SIGMA_PX,
    cache_directory,
    cache_key,
    moc_geometry_rad,
    preset,
    surface_fields,
)

#: Bump when the relief terrain for given parameters changes (invalidates caches).
RELIEF_VERSION = 1


def level_ground_reflectance(params: ClassTerrainParams, albedo: np.ndarray, seed: int) -> np.ndarray:
    """MOC I/F of the class's albedo on level ground (float32 (rows, cols)): the synthetic generator's
    photometry, haze, PSF and grain without slope shading or cast shadows."""
    _, _, inc, emi, phase = moc_geometry_rad(params)
    phase_factor = feat.phase_function(phase) / feat.phase_function(0.0)
    flat = 2.0 * np.cos(inc) / (np.cos(emi) + np.cos(inc))
    surface = albedo * np.float32(phase_factor * flat)
    transmission = np.exp(-params.haze_optical_depth / np.cos(emi))
    observed = transmission * surface + (1.0 - transmission) * float(surface.mean()) + params.haze_path_if
    observed = cv2.GaussianBlur(observed.astype(np.float32), (0, 0), MOC_PSF_SIGMA_PX)
    mean_if = float(observed.mean())
    grain = np.random.default_rng(np.random.SeedSequence([int(seed), RELIEF_VERSION, 7]))
    noise = grain.standard_normal(observed.shape, dtype=np.float32)
    observed = observed + noise * np.sqrt(observed * mean_if) / np.float32(params.grain_snr)
    return np.clip(observed, 1e-4, None).astype(np.float32)


def generate_relief(params: ClassTerrainParams, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(level-ground I/F, height above the strip's mean plane in m), float32 (rows, cols); no caching."""
    height, albedo = surface_fields(params, seed)
    height -= np.float32(height.mean())
    return level_ground_reflectance(params, albedo, seed), height


def cached_relief(params: ClassTerrainParams, seed: int, cache_dir: Path | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`generate_relief`, read from / written to the on-disk cache (atomic write)."""
    directory = Path(cache_dir) if cache_dir is not None else cache_directory()
    key = hashlib.sha256(f"{cache_key(params, seed)}-relief-{RELIEF_VERSION}".encode()).hexdigest()[:20]
    path = directory / f"relief_{params.name}_{key}.npz"
    shape = (params.rows, params.cols)
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as data:
                reflectance, height = data["reflectance_if"], data["height_m"]
            if reflectance.shape == shape == height.shape and reflectance.dtype == height.dtype == np.float32:
                return reflectance, height
        except (OSError, ValueError, KeyError):
            pass                                            # corrupt cache entry: regenerate
    reflectance, height = generate_relief(params, seed)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory, suffix=".tmp", delete=False) as handle:
            np.savez(handle, reflectance_if=reflectance, height_m=height)
        os.chmod(handle.name, 0o644)
        os.replace(handle.name, path)
    except OSError:
        pass                                                # read-only cache: still return the data
    return reflectance, height


def relief_terrain(params: ClassTerrainParams | str, seed: int, cache: bool = True,
                   cache_dir: Path | None = None) -> ReliefTerrain:
    """A synthetic class strip with its height field, centred on world (0, 0), north-up (the same grid
    as :func:`sitedata.terrain.synthetic_terrain.synthetic_terrain`)."""
    if isinstance(params, str):
        params = preset(params)
    params.validate()
    reflectance, height = cached_relief(params, seed, cache_dir) if cache else generate_relief(params, seed)
    _, _, inc, emi, phase = moc_geometry_rad(params)
    mpp = params.metres_per_pixel
    origin = np.array([-0.5 * (params.cols - 1) * mpp, 0.5 * (params.rows - 1) * mpp])
    return ReliefTerrain(reflectance_if=reflectance, metres_per_pixel=mpp, origin_m=origin, moc_incidence_rad=inc,
                         moc_emission_rad=emi, moc_phase_rad=phase, name=f"relief-{params.name}-{seed}",
                         height_m=height)


def relief_statistics(terrain: ReliefTerrain) -> dict[str, float]:
    """Height and slope statistics of a relief terrain: height RMS and range (m), RMS bidirectional
    slope at the 1-pixel baseline (deg, along rows and columns), and the fraction of pixels whose
    gradient slope exceeds 10 and 20 deg."""
    height = terrain.height_m.astype(np.float64)
    mpp = terrain.metres_per_pixel
    steps = np.concatenate([np.diff(height, axis=1).ravel(), np.diff(height, axis=0).ravel()]) / mpp
    d_row, d_col = np.gradient(height, mpp)
    slope_deg = np.degrees(np.arctan(np.hypot(d_row, d_col)))
    return {"height_rms_m": float(height.std()), "height_range_m": float(height.max() - height.min()),
            "rms_slope_deg": float(np.degrees(np.arctan(np.sqrt(np.mean(steps**2))))),
            "slope_above_10_deg": float(np.mean(slope_deg > 10.0)),
            "slope_above_20_deg": float(np.mean(slope_deg > 20.0))}
