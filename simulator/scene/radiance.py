"""Scene model: terrain I/F -> the radiance field the descent camera sees (paper section 4, Fig. 3).

One pose (:func:`radiance_at_pose`)::

    lander pose + camera mounting -> world rays of every pixel (ground_mapping, cached camera rays)
      -> ground points on z = 0; sky where a ray misses the ground (masked, radiance 0)
      -> terrain cropped to the footprint, bilinear resampling (resample; outside the strip flagged)
      -> [atmosphere on: orbital haze removed, x descent transmission (atmosphere)]
      -> x photometric ratio DIMES/MOC, eq. (1)-(3) (photometry; gives the opposition halo)
      -> x spectral ratio MOC->DIMES, x E_band / pi -> radiance W m^-2 sr^-1 um^-1
      -> shadows of lander, backshell, parachute, heat shield with penumbra (shadow)
      -> [atmosphere on: + path radiance and adjacency light of the dust below the camera]
      -> heat shield cone drawn where its footprint meets the field of view (heat_shield)

Supersampling (``supersample = s > 1``, the reference) renders the ``s x s`` sub-pixel samples one after
the other, each into scratch arrays (:func:`~simulator.scratch.scratch`), and adds each to
the pose's sum before the next (the order and float32 sums of :func:`~simulator.scene.motion_blur.average_fields`);
per-pixel photometry there uses :func:`~simulator.scene.photometry.photometric_ratio_from_cosines`.

The fields of the three CCD periods, from fields at several poses, are made by :mod:`simulator.scene.periods`.

``config`` is a :class:`simulator.scene_config.SceneConfig`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import cv2
import numpy as np

from flight_interface.camera import Camera
from flight_interface.frames import quat_to_matrix
from simulator.heap import keep_freed_buffers
from simulator.scene import (
    atmosphere,
    ground_mapping,
    heat_shield,
    node_grid_fused,
    photometry,
    relief,
    resample,
    shadow,
)
from simulator.scene.descent_profile import Pose
from simulator.scene.terrain import Terrain
from simulator.scratch import scratch


@dataclass(frozen=True)
class PoseField:
    """Radiance at one pose, with its masks.

    Attributes
    ----------
    radiance : ndarray, shape (H, W), float32
        Radiance (W m^-2 sr^-1 um^-1).
    sky : ndarray, shape (H, W), bool
        Pixels whose ray misses the ground.
    outside : ndarray, shape (H, W), bool
        Ground outside the terrain strip.
    heat_shield : ndarray, shape (H, W), bool, or None
        Pixels that see the heat shield; None when it is not in view.
    camera_pose : CameraPose
        The camera's world pose.
    shadow_centres_m : list of ndarray, shape (3,)
        Ground shadow centres of the casters (m).
    """

    radiance: np.ndarray               # float32, W m^-2 sr^-1 um^-1
    sky: np.ndarray                    # bool
    outside: np.ndarray                # bool, ground outside the terrain strip
    heat_shield: np.ndarray | None     # bool, or None when the heat shield is not in view
    camera_pose: ground_mapping.CameraPose
    shadow_centres_m: list = field(default_factory=list)


def sun_unit_vector(sun_world) -> np.ndarray:
    """Validate a world unit vector toward the sun (above the horizon).

    Parameters
    ----------
    sun_world : array_like, shape (3,)
        World vector toward the sun (x east, y north, z up).

    Returns
    -------
    ndarray, shape (3,), float64
        The vector.

    Raises
    ------
    ValueError
        Not a finite unit 3-vector with z > 0.
    """
    sun = np.asarray(sun_world, dtype=float)
    if sun.shape != (3,) or not np.all(np.isfinite(sun)) or abs(np.linalg.norm(sun) - 1.0) > 1e-6 or sun[2] <= 0:
        raise ValueError(f"sun: must be a world unit 3-vector toward the sun with z > 0 (sun above the horizon); "
                         f"got {sun_world!r}")
    return sun


def casters(pose: Pose, config) -> list[shadow.Caster]:
    """Shadow casters at a pose: lander, backshell and parachute along the lander's +z axis, heat shield.

    Parameters
    ----------
    pose : Pose
        Lander pose (with the heat shield's position).
    config : simulator.scene_config.SceneConfig
        Sizes and distances of the casters; the heat shield switch.

    Returns
    -------
    list of shadow.Caster
        The casters (world centres, radii in m).
    """
    up = quat_to_matrix(pose.attitude_quat)[:, 2]
    position = np.asarray(pose.position_m, dtype=float)
    result = [shadow.Caster("lander", position, 0.5 * config.lander_diameter_m)]
    if config.backshell_diameter_m > 0:
        result.append(shadow.Caster("backshell", position + config.backshell_distance_m * up,
                                    0.5 * config.backshell_diameter_m))
    if config.parachute_diameter_m > 0:
        result.append(shadow.Caster("parachute", position + config.parachute_distance_m * up,
                                    0.5 * config.parachute_diameter_m))
    if config.effects.heat_shield and pose.heat_shield_position_m is not None:
        result.append(shadow.Caster("heat_shield", np.asarray(pose.heat_shield_position_m, dtype=float),
                                    0.5 * config.heat_shield_diameter_m))
    return result


RATIO_SCRATCH = ground_mapping.COARSE_PLANE_SCRATCH[0]


def photometric_ratio_field(camera: Camera, pose: ground_mapping.CameraPose, ground_map: ground_mapping.GroundMap,
                            sun: np.ndarray, moc_value: float, grid_step_px: int) -> np.ndarray:
    """DIMES/MOC photometric ratio of every pixel.

    On the coarse node grid and interpolated when ``grid_step_px > 0``, else per pixel from the ground
    map's rays (emission and phase cosines,
    :func:`~simulator.scene.photometry.photometric_ratio_from_cosines`).

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    ground_map : GroundMap
        The pose's ground map.
    sun : ndarray, shape (3,)
        World unit vector toward the sun.
    moc_value : float
        The MOC geometry's reflectance model value (the ratio's denominator; may fold in a scale).
    grid_step_px : int
        Node spacing (px), 0 for per pixel.

    Returns
    -------
    ndarray, shape (H, W), float32
        The ratio: a :func:`~simulator.scratch.scratch` array, to multiply in before the next call.
    """
    if grid_step_px == 0 and ground_map.ray_dz is not None:    # exact map: unit rays, cos e = -d_z
        cos_phase = ground_mapping.phase_cosines(ground_map, sun)
        return photometry.photometric_ratio_from_ray_dz(ground_map.ray_dz, cos_phase, float(sun[2]), moc_value,
                                                        out=scratch("cos_emission", ground_map.ray_dz.shape))
    if grid_step_px == 0:
        cos_emission, cos_phase = ground_mapping.view_cosines(camera, pose, ground_map, sun)
        return photometry.photometric_ratio_from_cosines(cos_emission, cos_phase, float(sun[2]), moc_value)
    # upsampled into the ground map's numerator plane: dead since the map's division, and recently in cache
    return ground_mapping.field_at_pixels(photometric_ratio_nodes(camera, pose, ground_map, sun, moc_value, grid_step_px),
                                          camera, grid_step_px, scratch_name=RATIO_SCRATCH)


def photometric_ratio_nodes(camera: Camera, pose: ground_mapping.CameraPose, ground_map: ground_mapping.GroundMap,
                            sun: np.ndarray, moc_value: float, grid_step_px: int) -> np.ndarray:
    """The DIMES/MOC photometric ratio on the coarse node grid (:func:`photometric_ratio_field` before upsampling).

    Parameters
    ----------
    camera, pose, ground_map, sun, moc_value
        As :func:`photometric_ratio_field`.
    grid_step_px : int
        Node spacing (px), > 0.

    Returns
    -------
    ndarray, shape (H / s + 2, W / s + 2), float32
        The ratio at the nodes (:func:`simulator.scene.node_grid.node_positions`).
    """
    view = ground_mapping.view_directions(camera, pose, ground_map, grid_step_px)
    return photometry.photometric_ratio(view, sun, moc_value)


def terrain_moc_model(terrain: Terrain) -> float:
    """:func:`~simulator.scene.photometry.moc_reflectance_model` of a terrain's MOC geometry.

    Memoised on the three angles (a pure function of them), not on the terrain object.

    Parameters
    ----------
    terrain : Terrain
        The orbital image with its MOC incidence, emission and phase angles.

    Returns
    -------
    float
        The model value (the photometric ratio's denominator).
    """
    return _moc_model(float(terrain.moc_incidence_rad), float(terrain.moc_emission_rad), float(terrain.moc_phase_rad))


@lru_cache(maxsize=64)
def _moc_model(incidence_rad: float, emission_rad: float, phase_rad: float) -> float:
    return photometry.moc_reflectance_model(incidence_rad, emission_rad, phase_rad)


HEAT_SHIELD_EDGE_SAMPLES = 3   # s x s sub-pixel rays on the heat-shield silhouette (not in supersampling's samples)


PIXEL_AREA_KERNEL = np.array([1.0 / 24.0, 11.0 / 12.0, 1.0 / 24.0], dtype=np.float32)
PIXEL_AREA_TAPS = tuple(float(tap) for tap in PIXEL_AREA_KERNEL)


def pixel_area_average(point_samples: np.ndarray) -> np.ndarray:
    """Pixel-area averages of a field known at pixel centres, to second order.

    A pixel integrates the scene over its area; for a field smooth at the pixel scale the mean over a
    unit box is ``f + (f_xx + f_yy) / 24 + O(h^4)`` (midpoint rule with its error term), and the
    separable kernel ``[1, 22, 1] / 24`` applies exactly that correction with second differences. It
    stands in for supersampling the terrain (measured against the 3 x 3 reference by ``make bench``);
    edges are replicated.

    Parameters
    ----------
    point_samples : ndarray, shape (H, W), float32
        The field at the pixel centres.

    Returns
    -------
    ndarray, shape (H, W), float32
        Pixel-area means.
    """
    return cv2.sepFilter2D(point_samples, -1, PIXEL_AREA_KERNEL, PIXEL_AREA_KERNEL, borderType=cv2.BORDER_REPLICATE)


def subpixel_camera(camera: Camera, column_offset_px: float, row_offset_px: float) -> Camera:
    """The camera whose pixel (c, r) sees what ``camera``'s point (c + column_offset, r + row_offset) sees.

    CAHVOR ``H' = H - dc A``, ``V' = V - dr A`` (cached per camera).

    Parameters
    ----------
    camera : Camera
        The camera.
    column_offset_px, row_offset_px : float
        Offsets ``dc``, ``dr`` (px).

    Returns
    -------
    Camera
        The shifted camera.
    """
    cache = ground_mapping.camera_cache(camera)
    key = ("subpixel", float(column_offset_px), float(row_offset_px))
    if key not in cache:
        model = camera.model
        cache[key] = replace(camera, model=replace(model, h=model.h - column_offset_px * model.a,
                                                   v=model.v - row_offset_px * model.a))
    return cache[key]


def _pose_outlines(camera: Camera, pose: Pose, sun_world: np.ndarray, config) -> dict:
    """What a supersampled pose's samples share: casters, penumbra and heat-shield outlines.

    The outlines are projected with the unshifted camera; :func:`_sample_windows` turns them into a
    sample's windows.

    Parameters
    ----------
    camera : Camera
        The unshifted camera.
    pose : Pose
        Lander pose.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Scene parameters and switches.

    Returns
    -------
    dict
        ``casters`` (list of shadow.Caster), ``shadow_outlines`` (list per caster, or None when shadows are
        off), ``heat_shield_outline`` (:func:`~simulator.scene.ground_mapping.outline_extent`, or None when
        the heat shield is not drawn),
        ``sun`` (the checked sun vector) and ``camera_pose`` (every sample's: a sub-pixel camera differs
        only in H and V, not in its mounting or C).
    """
    sun = sun_unit_vector(sun_world)
    cam = ground_mapping.camera_pose(camera, pose)
    pose_casters = casters(pose, config)
    shadow_outlines = (shadow.penumbra_outlines(camera, cam, pose_casters, sun,
                                                photometry.solar_angular_radius_rad(config.sun_distance_au))
                       if config.effects.shadows else None)
    shield_outline = None
    if config.effects.heat_shield and pose.heat_shield_position_m is not None:
        shield_outline = ground_mapping.outline_extent(*ground_mapping.world_to_pixels(
            camera, cam, heat_shield.cone_outline_m(np.asarray(pose.heat_shield_position_m, dtype=float),
                                                    config.heat_shield_diameter_m, config.heat_shield_cone_angle_rad)))
    return dict(casters=pose_casters, shadow_outlines=shadow_outlines, heat_shield_outline=shield_outline,
                sun=sun, camera_pose=cam)


def _sample_windows(outlines: dict, column_offset_px: float, row_offset_px: float, width_px: int,
                    height_px: int) -> dict:
    """A supersampling sample's casters, penumbra windows and heat-shield box from its pose's outlines.

    The sample's camera (:func:`subpixel_camera`) sees a world point at the unshifted camera's pixel minus
    its offset, so each window is that of the outline shifted by ``-(dc, dr)``
    (:func:`~simulator.scene.ground_mapping.outline_window`): the windows the sample's own projections give
    (up to the projection's rounding), without projecting again.
    """
    shadow_windows = circles = None
    if outlines["shadow_outlines"] is not None:
        shadow_windows = [None if outline is None else
                          ground_mapping.outline_window(outline[2], column_offset_px, row_offset_px, width_px,
                                                        height_px)
                          for outline in outlines["shadow_outlines"]]
        circles = [None if outline is None else outline[:2] for outline in outlines["shadow_outlines"]]
    box = None
    if outlines["heat_shield_outline"] is not None:
        box = ground_mapping.outline_window(outlines["heat_shield_outline"], column_offset_px, row_offset_px,
                                            width_px, height_px)
    return dict(casters=outlines["casters"], shadow_windows=shadow_windows, shadow_circles=circles,
                heat_shield_box=box,
                sun=outlines["sun"], camera_pose=outlines["camera_pose"])


def radiance_at_pose(terrain: Terrain, camera: Camera, pose: Pose, sun_world: np.ndarray, config,
                     _sub_sample: bool = False, moving_shadows=None, _pose_windows: dict | None = None) -> PoseField:
    """The radiance field the camera sees at one instantaneous pose (see module doc).

    With ``config.supersample = s > 1`` each pixel is the mean of ``s x s`` sub-pixel point samples on
    a regular grid (offsets ``(k + 0.5)/s - 0.5`` px; the samples themselves use no area shortcut);
    masks are the union over the samples.

    Parameters
    ----------
    terrain : Terrain
        Orbital I/F image with its photometric geometry.
    camera : Camera
        The camera.
    pose : Pose
        Lander pose.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun, z > 0.
    config : simulator.scene_config.SceneConfig
        Scene parameters and switches.
    _sub_sample : bool, optional
        Internal: render one supersampling sample, whose radiance is a scratch array the caller adds up
        before rendering the next.
    moving_shadows : simulator.off_nominal.moving_shadows.MovingShadows, optional
        Darkens the ground where the dust-devil and cloud shadows are at ``pose.time_s``, after the
        casters' shadows.
    _pose_windows : dict, optional
        Internal: a supersampling sample's casters, penumbra circles and windows, heat-shield box, sun
        vector and camera pose (:func:`_sample_windows`, from what its pose computed once).

    Returns
    -------
    PoseField
        Radiance (H, W) float32 (W m^-2 sr^-1 um^-1) with its masks.
    """
    keep_freed_buffers()       # simulator.heap: frame-sized arrays reused from the heap
    samples = config.supersample
    if samples > 1:
        single = config.model_copy(update={"supersample": 1})
        offsets = (np.arange(samples) + 0.5) / samples - 0.5
        # each sample's field lives in a scratch array: summed (in sample order, as average_fields) at once
        outlines = _pose_outlines(camera, pose, sun_world, single)   # projected once, shifted per sample

        def sample(dc: float, dr: float) -> PoseField:
            windows = _sample_windows(outlines, dc, dr, camera.width_px, camera.height_px)
            return radiance_at_pose(terrain, subpixel_camera(camera, dc, dr), pose, sun_world, single,
                                    _sub_sample=True, moving_shadows=moving_shadows, _pose_windows=windows)
        first = sample(offsets[0], offsets[0])
        total, sky, outside, shield = first.radiance.copy(), first.sky.copy(), first.outside.copy(), first.heat_shield
        for dr in offsets:
            for dc in offsets:
                if dr == offsets[0] and dc == offsets[0]:
                    continue
                part = sample(dc, dr)
                total += part.radiance
                sky |= part.sky
                outside |= part.outside
                if part.heat_shield is not None:
                    shield = part.heat_shield.copy() if shield is None else shield | part.heat_shield
        total *= np.float32(1.0 / samples**2)
        return PoseField(total, sky, outside, shield, outlines["camera_pose"], first.shadow_centres_m)
    effects = config.effects
    if _pose_windows is None:
        sun = sun_unit_vector(sun_world)
        cam = ground_mapping.camera_pose(camera, pose)
    else:      # a sample: the sun checked by its pose; its camera differs only in H and V, so the same pose
        sun, cam = _pose_windows["sun"], _pose_windows["camera_pose"]

    footprint, hit = ground_mapping.footprint_m(camera, cam)
    foot_rows, foot_cols = terrain.world_to_pixel(footprint[hit, 0], footprint[hit, 1])
    bounded = bool(hit.all())
    crop = resample.footprint_crop(terrain, foot_cols, foot_rows, bounded)
    rows, cols = terrain.shape
    inside = bounded and (foot_cols.min() > 0.5 and foot_rows.min() > 0.5
                          and foot_cols.max() < cols - 1.5 and foot_rows.max() < rows - 1.5)

    ray_step = config.ray_grid_step_px if effects.coarse_ray_grid else 0
    photo_step = config.photometry_grid_step_px if effects.coarse_photometry else 0
    has_relief = relief.has_relief(terrain, config)
    # per-pixel photometry on an exact map: its phase cosines come with the map (one pass over the rays)
    with_phase = (ray_step == 0 and photo_step == 0 and effects.photometric_correction
                  and not config.atmosphere.enabled and not has_relief)
    gmap = ground_mapping.map_to_ground_grid(camera, cam, (terrain.origin_m[0], terrain.origin_m[1]),
                                             terrain.metres_per_pixel, ray_step, scratch_maps=True,
                                             phase_sun_world=sun if with_phase else None)
    relief_hits = None
    if relief.has_relief(terrain, config):   # parallax and occlusion of the height field (scene.relief)
        gmap, relief_hits = relief.relief_ground_map(terrain, camera, cam, gmap, config, sun)
        crop, inside = relief_hits.crop, relief.hits_inside_terrain(terrain, relief_hits)
    area_filter = effects.pixel_area_filter and not _sub_sample   # (a supersampled render averages point samples)
    # the point samples are filtered into a new array at once, and a supersampling sample's field is summed
    # by the caller before the next sample: both live in scratch arrays
    moc_if, outside = resample.sample_terrain(terrain, gmap.col, gmap.row, gmap.sky if gmap.any_sky else None,
                                              crop, may_leave_terrain=not inside,
                                              out=scratch("point_samples", gmap.col.shape)
                                              if area_filter or _sub_sample else None)
    irradiance = photometry.solar_band_irradiance_w_m2_um(config.sun_distance_au)
    scale = irradiance / np.pi * (config.spectral_ratio if effects.spectral_ratio else 1.0)
    moc_value = terrain_moc_model(terrain) if effects.photometric_correction else None
    # no sky, coarse photometry: the pixel-area filter and the ratio's interpolation and product are one pass
    fused_ratio = (area_filter and not gmap.any_sky and moc_value is not None and not config.atmosphere.enabled
                   and photo_step > 0 and node_grid_fused.fused_passes_match_opencv(*gmap.col.shape, photo_step,
                                                                                PIXEL_AREA_TAPS))
    if fused_ratio:
        assert moc_value is not None
        moc_if = node_grid_fused.area_filtered_times_nodes(
            moc_if, PIXEL_AREA_KERNEL, photometric_ratio_nodes(camera, cam, gmap, sun, moc_value / scale, photo_step),
            photo_step)
    elif area_filter:
        moc_if = pixel_area_average(moc_if)
        if gmap.any_sky:
            moc_if[gmap.sky] = 0.0        # no terrain bleeding across the horizon

    radiance = moc_if
    added = None
    if config.atmosphere.enabled:
        # orbital haze out, descent gain and added light on the photometry grid (simulator.scene.atmosphere)
        haze = atmosphere.orbital_haze(terrain, config.atmosphere)
        atmosphere.remove_orbital_haze(radiance, haze)
        gain, added = atmosphere.descent_fields(camera, cam, gmap, sun, moc_value, scale, haze, config.atmosphere,
                                                 photo_step)
        radiance *= gain
    elif moc_value is not None:      # effects.photometric_correction
        # the radiometric scale is folded into the ratio (on the node grid when coarse): one full-frame pass,
        # or none when fused with the pixel-area filter above
        if not fused_ratio:
            radiance *= photometric_ratio_field(camera, cam, gmap, sun, moc_value / scale, photo_step)
    else:
        radiance *= np.float32(scale)

    if relief_hits is not None:      # slope photometry and cast shadows of the relief
        radiance *= relief.shading_factor(relief_hits, sun, config)
    centres = []
    if effects.shadows:
        centres = shadow.apply_shadows(radiance, gmap, camera, cam,
                                       casters(pose, config) if _pose_windows is None else _pose_windows["casters"],
                                       sun, photometry.solar_angular_radius_rad(config.sun_distance_au),
                                       config.shadow_diffuse_fraction,
                                       view_bounds_m=shadow.view_bounds_m(footprint, hit),
                                       windows=None if _pose_windows is None else _pose_windows["shadow_windows"],
                                       circles=None if _pose_windows is None else _pose_windows["shadow_circles"])
    if moving_shadows is not None:
        moving_shadows.darken(radiance, gmap, camera, cam, pose.time_s, terrain.origin_m, terrain.metres_per_pixel)
    if added is not None:          # path and adjacency light: not shadowed, none where the ray sees sky
        radiance += added
        if gmap.any_sky:
            radiance[gmap.sky] = 0.0
    shield = None
    shield_box = None if _pose_windows is None else _pose_windows["heat_shield_box"]
    if effects.heat_shield and pose.heat_shield_position_m is not None and (_pose_windows is None or shield_box):
        shield = heat_shield.draw_heat_shield(radiance, gmap, camera, cam,
                                              np.asarray(pose.heat_shield_position_m, dtype=float), sun,
                                              irradiance, config.heat_shield_diameter_m,
                                              config.heat_shield_cone_angle_rad, config.heat_shield_reflectance,
                                              edge_samples=1 if _sub_sample else HEAT_SHIELD_EDGE_SAMPLES,
                                              box=shield_box, interpolated_edge_rays=effects.interpolated_edge_rays)
    if shield is not None:
        outside &= ~shield
    return PoseField(radiance, gmap.sky, outside, shield, cam, centres)
