"""The heat shield's specular glint (off-nominal ``heat_shield_glint``), added to the period fields.

The Kapton film lining the heat shield (:mod:`simulator.scene.heat_shield`) is glossy; its quilted,
wrinkled blanket is a surface of mirror facets whose slopes are Gaussian (Beckmann distribution, rms
slope ``tan(sigma)``). Torrance-Sparrow reflection of the sun (a point source: its 0.17 deg radius at
Mars is small against sigma >= 0.5 deg), with constant Fresnel factor ``rho_s``
(``heat_shield_specular_reflectance``) and no facet shadowing::

    L = rho_s E_band D(theta_h) / (4 cos theta_v),  D = exp(-tan^2 theta_h / m^2) / (pi m^2 cos^4 theta_h)

with ``m = tan(sigma)``, ``theta_h`` the angle between the normal and the half vector of sun and
camera directions and ``theta_v`` the view angle; ``D`` is normalised (``int D cos theta_h dw = 1``),
so a narrow lobe reflects ``rho_s E cos theta_i`` in total. Its peak ``rho_s E / (4 pi m^2 cos
theta_v)`` is ~1.4 E (about 600 W m^-2 sr^-1 um^-1, 15 times the terrain) for rho_s = 0.05 and
sigma = 3 deg: well above full well in the 5.1 ms exposure, hence blooming. A glint appears when
the half vector lies within a few sigma of the lining's normals (20 deg from the cone axis).

The glint is added by the scene stage (:func:`simulator.scene.periods.period_fields` calls
:func:`add_glint`), averaged over the same sub-poses as the scene's fields.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from flight_interface.camera import Camera
from simulator.fields import RadianceFields, block_means
from simulator.scene import ground_mapping, motion_blur, photometry
from simulator.scene.descent_profile import Pose
from simulator.scene.heat_shield import bounding_box, visible_surface


def specular_radiance(normal: np.ndarray, to_sun: np.ndarray, to_camera: np.ndarray, irradiance_w_m2_um: float,
                      reflectance: float, roughness_rad: float) -> np.ndarray:
    """Radiance of the specular lobe (module doc).

    Parameters
    ----------
    normal : ndarray, shape (..., 3)
        Unit surface normals.
    to_sun : ndarray, shape (3,)
        Unit vector toward the sun.
    to_camera : ndarray, shape (..., 3)
        Unit vectors toward the camera.
    irradiance_w_m2_um : float
        Solar band irradiance normal to the sun (W m^-2 um^-1).
    reflectance : float
        Fresnel factor ``rho_s``.
    roughness_rad : float
        RMS facet slope angle (rad).

    Returns
    -------
    ndarray, shape (...)
        Radiance (W m^-2 sr^-1 um^-1).
    """
    half = to_sun + to_camera
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    cos_h = np.clip(np.einsum("...i,...i->...", normal, half), 1e-6, 1.0)
    cos_view = np.einsum("...i,...i->...", normal, to_camera)
    cos_sun = normal @ to_sun
    slope2 = np.tan(roughness_rad) ** 2
    tan2_h = (1.0 - cos_h**2) / cos_h**2
    facets = np.exp(-tan2_h / slope2) / (np.pi * slope2 * cos_h**4)
    lit = (cos_view > 0) & (cos_sun > 0)
    return np.where(lit, reflectance * irradiance_w_m2_um * facets / (4.0 * np.where(lit, cos_view, 1.0)), 0.0)


def glint_window(camera: Camera, pose: ground_mapping.CameraPose, centre_m: np.ndarray, sun_world: np.ndarray,
                 irradiance_w_m2_um: float, diameter_m: float, cone_angle_rad: float, reflectance: float,
                 roughness_rad: float) -> tuple[int, int, np.ndarray] | None:
    """The specular glint of the heat-shield lining at one camera pose.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    centre_m : ndarray, shape (3,)
        Centre of the cone's bounding cylinder (m).
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    irradiance_w_m2_um : float
        Solar band irradiance normal to the sun (W m^-2 um^-1).
    diameter_m : float
        Rim diameter (m).
    cone_angle_rad : float
        Full cone angle (rad).
    reflectance : float
        Specular Fresnel factor ``rho_s``.
    roughness_rad : float
        RMS facet slope angle (rad).

    Returns
    -------
    tuple of (int, int, ndarray) or None
        ``(row0, col0, radiance)`` with ``radiance`` a float32 (h, w) window of the image (W m^-2 sr^-1
        um^-1, 0 off the shield; exact per-pixel rays), or None when the shield is not in view.
    """
    box = bounding_box(camera, pose, centre_m, diameter_m, cone_angle_rad)
    if box is None:
        return None
    row0, row1, col0, col1 = box
    rays = camera.pixel_rays[row0:row1, col0:col1] @ pose.camera_to_world.T
    surface = visible_surface(rays, pose, np.zeros(rays.shape[:2], dtype=bool), centre_m, diameter_m,
                               cone_angle_rad)
    if surface is None:
        return None
    hit, facing = surface
    value = specular_radiance(facing, np.asarray(sun_world, dtype=float), -rays, irradiance_w_m2_um,
                              reflectance, roughness_rad)
    return row0, col0, np.where(hit, value, 0.0).astype(np.float32)


def add_glint(fields: RadianceFields, shared: bool, substeps: dict[str, int], camera: Camera,
              pose_at: Callable[[float], Pose], windows: dict[str, tuple[float, float]], centre_s: float,
              sun_world: np.ndarray, config) -> None:
    """Add the heat-shield specular glint to the period fields in place.

    Each field gets the glint averaged over the same sub-poses as the scene
    (:mod:`simulator.scene.motion_blur`); a field standing for several periods gets the glint of the
    exposure (or of the first period it stands for).

    Parameters
    ----------
    fields : RadianceFields
        The flush, exposure and transfer fields (W m^-2 sr^-1 um^-1), (H, W) or per binning block
        (H / b, W) float32; changed in place.
    shared : bool
        One field stands for all three periods (its glint is the one at the exposure mid-time).
    substeps : dict of str to int
        Sub-poses of each period.
    camera : Camera
        The descent camera.
    pose_at : callable
        ``time_s -> Pose``: the lander pose (with the heat shield position) at a time (s).
    windows : dict of str to (float, float)
        ``period -> (start_s, end_s)`` (s).
    centre_s : float
        Exposure mid-time (s).
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Heat shield geometry, ``sun_distance_au`` and the off-nominal specular reflectance and roughness.

    Returns
    -------
    None
    """
    first_periods: list[str] = []        # the first period of each distinct field object
    for period in ("exposure", "flush", "transfer"):
        if not any(getattr(fields, other) is getattr(fields, period) for other in first_periods):
            first_periods.append(period)
    irradiance = photometry.solar_band_irradiance_w_m2_um(config.sun_distance_au)
    off_nominal = config.off_nominal
    for period in first_periods:
        field_array = getattr(fields, period)
        count = 1 if shared else max(int(substeps.get(period, 1)), 1)
        times = [centre_s] if shared else motion_blur.substep_times(*windows[period], count)
        for time_s in times:
            pose = pose_at(float(time_s))
            glint = glint_window(
                camera, ground_mapping.camera_pose(camera, pose), np.asarray(pose.heat_shield_position_m, dtype=float),
                sun_world, irradiance, config.heat_shield_diameter_m, config.heat_shield_cone_angle_rad,
                off_nominal.heat_shield_specular_reflectance, off_nominal.heat_shield_specular_roughness_rad)
            if glint is not None:
                row0, col0, window = glint
                window = window * np.float32(1.0 / len(times))
                if field_array.shape[0] != camera.height_px:   # a smear field given as binning-block means
                    row0, window = _block_mean_window(row0, window, camera.height_px // field_array.shape[0])
                field_array[row0:row0 + window.shape[0], col0:col0 + window.shape[1]] += window


def _block_mean_window(row0: int, window: np.ndarray, block_rows: int) -> tuple[int, np.ndarray]:
    """A full-resolution window starting at ``row0`` as means of whole ``block_rows``-row blocks.

    (first block index, (blocks, w) float32).
    """
    first = row0 // block_rows
    end = -(-(row0 + window.shape[0]) // block_rows)
    padded = np.zeros(((end - first) * block_rows, window.shape[1]), dtype=np.float32)
    padded[row0 - first * block_rows:row0 - first * block_rows + window.shape[0]] = window
    return first, block_means(padded, block_rows)
