"""Moving shadows: dust-devil and cloud shadows drifting with the wind across the ground.

A feature tracker that locks onto a shadow moving at wind speed over bland ground reports the shadow's
velocity, not the lander's; this effect lets a campaign measure that risk (``[scene.off_nominal]``
keys of :class:`MovingShadowsConfig`; physics and ranges in docs/simulator.md).

Model (flat ground z = 0, sun unit vector ``s`` with zenith angle ``theta``, ``cos(theta) = s_z``;
``a`` the horizontal unit vector pointing away from the sun, the anti-sun azimuth):

* **Darkness.** The ground in a shadow's core receives the diffuse sky light plus ``exp(-tau / cos(theta))``
  of the direct beam (``tau`` the caster's optical depth, the slant path through it ``1 / cos(theta)``
  times the vertical one). With ``f`` the diffuse fraction of the irradiance (``[scene]
  shadow_diffuse_fraction``, shared with the lander's shadows) the radiance is multiplied by
  ``f + (1 - f) exp(-tau / cos(theta))``. Overlapping shadows multiply their direct-beam
  transmissions; the sky light is never shadowed.
* **Dust devil.** A vertical column of diameter ``D`` from the ground to height ``H``. Its shadow is
  the union of the shadows of its horizontal sections: a stadium (a rectangle with round ends) of
  width ``D`` from the column's base to ``H tan(theta)`` along ``a``; the shadow of the column's top
  is offset by ``H tan(theta)`` from the base, the shadow's centre by ``H tan(theta) / 2``.
* **Cloud.** A horizontal disc of diameter ``D`` at height ``H``: its shadow is a disc of the same
  diameter offset by ``H tan(theta)`` along ``a`` from the ground point under the cloud.
* **Edge.** The shadow fraction falls linearly across an edge of width
  ``w = 2 R_sun L + EDGE_FRACTION D`` centred on the geometric outline: the penumbra of the solar disc
  (angular radius ``R_sun``) at the slant distance ``L = h / cos(theta)`` of the casting dust (``h = H / 2``
  for a dust devil, ``H`` for a cloud), plus the diffuse edge of a dust cloud.
* **Motion.** Every caster moves rigidly with its own horizontal wind velocity ``v``: its position at
  time ``t`` is ``p0 + v (t - t_ref)``, so a shadow blurs within each sub-posed CCD period and moves
  by ``v (t_j - t_i)`` between images ``i`` and ``j``.
* **Placement.** Each shadow's centre is drawn uniformly over the central 80 % (each axis) of the
  frame of the middle image at its exposure mid-time ``t_ref``, so the shadows are in view; the
  casters (column base, point under the cloud) are placed behind it toward the sun.

Randomness: :func:`draw_moving_shadows` takes four uniforms per shadow (dust devils first, then
clouds: frame column and row fractions, speed and direction spread) from the case's artefact stream;
a count of 0 draws nothing and changes no image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from config_tables.models import ConfigModel
from flight_interface.camera import Camera
from simulator.scene.descent_profile import DescentProfile

if TYPE_CHECKING:
    from simulator.scene import ground_mapping

EDGE_FRACTION = 0.1          # diffuse edge of the dust, as a fraction of the caster's diameter
PLACEMENT_FRAME_FRACTION = 0.8
RING_POINTS = 24
TRUSTED_PROJECTION_FRAMES = 1.0   # outline pixels farther than this (frames) from the centre: whole frame


class MovingShadowsConfig(ConfigModel):
    """Moving-shadow keys of ``[scene.off_nominal]`` (SI units, azimuths in degrees clockwise from north)."""

    dust_devil_count: int = Field(0, ge=0, le=20)
    """Dust-devil shadows per case (0: off)."""
    dust_devil_diameter_m: float = Field(50.0, ge=2.0, le=500.0)
    """Column diameter (m); Mars dust devils are ~10-500 m across."""
    dust_devil_height_m: float = Field(500.0, ge=10.0, le=8000.0)
    """Column height (m); Mars dust devils reach hundreds of metres to several km."""
    dust_devil_optical_depth: float = Field(1.0, ge=0.0, le=5.0)
    """Optical depth of the column's dust (vertical; the sun's slant path divides it by cos(zenith))."""
    cloud_shadow_count: int = Field(0, ge=0, le=20)
    """Cloud shadows per case (0: off)."""
    cloud_diameter_m: float = Field(1000.0, ge=50.0, le=20000.0)
    """Cloud diameter (m)."""
    cloud_height_m: float = Field(10000.0, ge=500.0, le=60000.0)
    """Cloud height above the ground (m); Mars water-ice and dust clouds lie ~10-60 km up."""
    cloud_optical_depth: float = Field(0.3, ge=0.0, le=5.0)
    """Vertical optical depth of the cloud."""
    shadow_wind_speed_mps: float = Field(15.0, ge=0.0, le=60.0)
    """Wind speed that carries the dust devils and clouds (m/s)."""
    shadow_wind_toward_azimuth_deg: float = Field(90.0, ge=0.0, le=360.0)
    """Azimuth the wind blows toward (deg clockwise from north; 90: toward east)."""
    shadow_wind_speed_spread_mps: float = Field(0.0, ge=0.0, le=30.0)
    """Per shadow: speed drawn uniformly within +- this of the wind speed (clipped at 0)."""
    shadow_wind_direction_spread_deg: float = Field(0.0, ge=0.0, le=180.0)
    """Per shadow: direction drawn uniformly within +- this of the wind azimuth."""

    @property
    def moving_shadow_count(self) -> int:
        """Number of moving shadows: dust devils plus cloud shadows."""
        return self.dust_devil_count + self.cloud_shadow_count


@dataclass(frozen=True)
class MovingShadowDraws:
    """The random part of a case's moving shadows (before they are placed on the ground).

    Attributes
    ----------
    is_cloud : (n,) bool, cloud shadow (else dust devil)
    frame_fraction : (n, 2) (column, row) position of the shadow centre as a fraction of the frame
    velocity_mps : (n, 2) east, north velocity of each caster (m/s)
    """

    is_cloud: np.ndarray
    frame_fraction: np.ndarray
    velocity_mps: np.ndarray


def draw_moving_shadows(config: MovingShadowsConfig, rng: np.random.Generator) -> MovingShadowDraws | None:
    """The case's moving-shadow draws (4 uniforms per shadow).

    Parameters
    ----------
    config : MovingShadowsConfig
        Counts and speeds.
    rng : numpy.random.Generator
        The case's artefact stream.

    Returns
    -------
    MovingShadowDraws or None
        The draws, None when the count is 0.
    """
    count = config.moving_shadow_count
    if count == 0:
        return None
    uniforms = rng.random((count, 4))
    margin = 0.5 * (1.0 - PLACEMENT_FRAME_FRACTION)
    fraction = margin + PLACEMENT_FRAME_FRACTION * uniforms[:, :2]
    speed = np.maximum(config.shadow_wind_speed_mps + config.shadow_wind_speed_spread_mps * (2 * uniforms[:, 2] - 1),
                       0.0)
    azimuth = np.radians(config.shadow_wind_toward_azimuth_deg
                         + config.shadow_wind_direction_spread_deg * (2 * uniforms[:, 3] - 1))
    velocity = np.stack([speed * np.sin(azimuth), speed * np.cos(azimuth)], axis=-1)
    is_cloud = np.arange(count) >= config.dust_devil_count
    return MovingShadowDraws(is_cloud, fraction, velocity)


@dataclass(frozen=True)
class MovingShadows:
    """Shadows placed on the ground.

    Each is a segment from ``start`` to ``start + length a`` (a disc when the length is 0) thickened by
    ``radius``, moving with ``velocity``.

    Attributes
    ----------
    start_m : ndarray, shape (n, 2)
        East, north start of each shadow's axis at ``reference_time_s`` (m).
    caster_m : ndarray, shape (n, 2)
        The caster's ground point (column base, point under the cloud) at that time (m).
    length_m, radius_m, edge_m : ndarray, shape (n,)
        Axis length, half width, edge width (m).
    velocity_mps : ndarray, shape (n, 2)
        East, north velocity (m/s).
    core_factor : ndarray, shape (n,)
        Direct-beam transmission in the shadow's core, ``exp(-tau / cos(theta))``.
    anti_sun : ndarray, shape (2,)
        Horizontal unit vector away from the sun.
    diffuse_fraction : float
        Fraction of the irradiance that is sky light.
    reference_time_s : float
        Time of the positions (s).
    """

    start_m: np.ndarray
    caster_m: np.ndarray
    length_m: np.ndarray
    radius_m: np.ndarray
    edge_m: np.ndarray
    velocity_mps: np.ndarray
    core_factor: np.ndarray
    anti_sun: np.ndarray
    diffuse_fraction: float
    reference_time_s: float

    def centres_m(self, time_s: float) -> np.ndarray:
        """World shadow centres at a time.

        Parameters
        ----------
        time_s : float
            Time (s).

        Returns
        -------
        ndarray, shape (n, 3)
            Centres (m), z = 0.
        """
        centre = self.start_m + 0.5 * self.length_m[:, None] * self.anti_sun + self.velocity_mps * (
            time_s - self.reference_time_s)
        return np.column_stack([centre, np.zeros(len(centre))])

    def points_m(self, time_s: float) -> list:
        """The shadow centres at a time as world points (they move on their own).

        Parameters
        ----------
        time_s : float
            Time (s).

        Returns
        -------
        list of ndarray, shape (3,)
            Centres (m).
        """
        return list(self.centres_m(time_s))

    def ratio_in_core(self) -> np.ndarray:
        """Radiance ratio (shadowed / lit) in each shadow's core on flat ground.

        Returns
        -------
        ndarray, shape (n,)
            The ratio.
        """
        return self.diffuse_fraction + (1.0 - self.diffuse_fraction) * self.core_factor

    def darken(self, radiance: np.ndarray, ground_map: ground_mapping.GroundMap, camera: Camera,
               pose: ground_mapping.CameraPose, time_s: float, grid_origin_m, metres_per_pixel: float) -> None:
        """Multiply a radiance field in place by the shadows' darkening at a time (module doc).

        Only the image windows that can hold a shadow are computed.

        Parameters
        ----------
        radiance : ndarray, shape (H, W), float32
            Radiance (W m^-2 sr^-1 um^-1); changed in place.
        ground_map : GroundMap
            Ground point of every pixel, as coordinates of the north-up grid.
        camera : Camera
            The camera.
        pose : CameraPose
            The camera's world pose.
        time_s : float
            Time (s).
        grid_origin_m : (float, float)
            East, north of the grid's (row 0, col 0) pixel centre (m).
        metres_per_pixel : float
            Grid spacing (m).
        """
        from simulator.off_nominal import shadow_darkening  # numba-compiled passes: loaded by rendering, not the config
        from simulator.scene import ground_mapping

        height, width = radiance.shape
        shift = self.velocity_mps * (time_s - self.reference_time_s)
        angles = np.linspace(0.0, 2 * np.pi, RING_POINTS, endpoint=False)
        circle = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
        windows = []
        for k in range(len(self.start_m)):
            start = self.start_m[k] + shift[k]
            reach = self.radius_m[k] + self.edge_m[k]
            outline = np.vstack([start + reach * circle, start + self.length_m[k] * self.anti_sun + reach * circle])
            pixels, in_front = ground_mapping.world_to_pixels(
                camera, pose, np.column_stack([outline, np.zeros(len(outline))]))
            far = np.abs(pixels - 0.5 * np.array([width, height])) > TRUSTED_PROJECTION_FRAMES * np.array([width, height])
            if not in_front.all() or far.any():
                # the outline leaves the trusted projection (far off axis, behind): decide on the ground
                if not _may_overlap_footprint(camera, pose, outline):
                    continue
                row0, row1, col0, col1 = 0, height, 0, width
            else:
                row0, row1, col0, col1 = ground_mapping.pixel_window(pixels, width, height)
            if col1 > col0 and row1 > row0:
                windows.append((k, start, row0, row1, col0, col1))
        if not windows:
            return
        chosen = [window[0] for window in windows]
        table = shadow_darkening.shadow_table(np.array([window[1] for window in windows]), grid_origin_m, self.anti_sun,
                                              self.length_m[chosen], self.radius_m[chosen], self.edge_m[chosen],
                                              self.core_factor[chosen])
        shadow_darkening.darken_windows(radiance, ground_map.col, ground_map.row, ground_map.sky, bool(ground_map.any_sky),
                                        np.float32(metres_per_pixel), table,
                                        np.array([window[2:] for window in windows], dtype=np.int64),
                                        np.float32(self.diffuse_fraction))


def _may_overlap_footprint(camera: Camera, pose: ground_mapping.CameraPose, outline_m: np.ndarray) -> bool:
    """Whether a shadow's outline may overlap the image's ground footprint.

    False only when the bounding box of a shadow's outline (k, 2) and that of the image's ground
    footprint (from its border pixels) are disjoint; True when a border ray misses the ground.
    """
    from simulator.scene import ground_mapping

    footprint, hit = ground_mapping.footprint_m(camera, pose, per_side=4)
    if not hit.all():
        return True
    return bool(np.all(outline_m.min(axis=0) <= footprint.max(axis=0)) and
                np.all(outline_m.max(axis=0) >= footprint.min(axis=0)))


def place_moving_shadows(draws: MovingShadowDraws, config: MovingShadowsConfig, camera: Camera,
                         profile: DescentProfile, sun_world: np.ndarray, sun_radius_rad: float,
                         diffuse_fraction: float) -> MovingShadows:
    """Put the drawn shadows on the ground (module doc: placement), for every image of the case alike.

    Parameters
    ----------
    draws : MovingShadowDraws
        The case's draws.
    config : MovingShadowsConfig
        Sizes, optical depths.
    camera : Camera
        The camera.
    profile : DescentProfile
        The case's trajectory (unscaled); its middle image's exposure mid-time is ``t_ref``.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun, z > 0.
    sun_radius_rad : float
        Angular radius of the solar disc (rad).
    diffuse_fraction : float
        Fraction of the irradiance that is sky light.

    Returns
    -------
    MovingShadows
        The placed shadows.
    """
    from simulator.scene import ground_mapping

    reference_s = camera.timing.exposure_mid_time_s(float(profile.image_times_s[len(profile.image_times_s) // 2]))
    pose = profile.pose(float(np.clip(reference_s, profile.time_s[0], profile.time_s[-1])))
    cam = ground_mapping.camera_pose(camera, pose)
    pixels = draws.frame_fraction * np.array([camera.width_px - 1.0, camera.height_px - 1.0])
    centres, hit = ground_mapping.ground_points(camera, cam, pixels)
    if not hit.all():
        raise ValueError(f"profile {profile.name}: a moving shadow's placement pixel sees the sky at "
                         f"{reference_s:.3f} s; moving shadows need the ground in view")
    sun = np.asarray(sun_world, dtype=float)
    cos_zenith = float(sun[2])
    tan_zenith = math.sqrt(max(1.0 - cos_zenith**2, 0.0)) / cos_zenith
    horizontal = -sun[:2]
    norm = float(np.linalg.norm(horizontal))
    anti_sun = horizontal / norm if norm > 1e-12 else np.array([1.0, 0.0])
    cloud = draws.is_cloud
    height = np.where(cloud, config.cloud_height_m, config.dust_devil_height_m)
    diameter = np.where(cloud, config.cloud_diameter_m, config.dust_devil_diameter_m)
    tau = np.where(cloud, config.cloud_optical_depth, config.dust_devil_optical_depth)
    length = np.where(cloud, 0.0, height * tan_zenith)              # dust devil: base to top's shadow
    offset = np.where(cloud, height * tan_zenith, 0.5 * length)     # caster ground point -> shadow centre
    centre = centres[:, :2]
    caster = centre - offset[:, None] * anti_sun
    start = centre - 0.5 * length[:, None] * anti_sun
    casting_height = np.where(cloud, height, 0.5 * height)
    edge = 2.0 * sun_radius_rad * casting_height / cos_zenith + EDGE_FRACTION * diameter
    return MovingShadows(start_m=start, caster_m=caster, length_m=length, radius_m=0.5 * diameter, edge_m=edge,
                         velocity_mps=draws.velocity_mps, core_factor=np.exp(-tau / cos_zenith), anti_sun=anti_sun,
                         diffuse_fraction=float(diffuse_fraction), reference_time_s=reference_s)
