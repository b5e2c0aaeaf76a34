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

The three CCD periods (:func:`period_fields`): the fast flush ``[t - T_flush, t]``, exposure
``[t, t + T_exp]`` and frame transfer ``[t + T_exp, t + T_exp + T_transfer]`` each get the mean of the
fields at sub-poses spaced by one terrain pixel of image shift (motion_blur). When the whole window moves
the image by less than ``still_shift_terrain_px`` the exposure-centre field stands for all three (the
same array object, which the camera chain converts once). Times outside the profile are clamped to its
ends (the pose is held). An odd exposure sub-pose count has its middle sub-pose at the exposure mid-time;
when that instant is bit-equal to the mid-time the centre field already rendered stands for it.

Supersampling (``supersample = s > 1``, the reference) renders the ``s x s`` sub-pixel samples one after
the other, each into scratch arrays (:func:`~simulator.scene.ground_mapping.scratch`), and adds each to
the pose's sum before the next (the order and float32 sums of :func:`~simulator.scene.motion_blur.average_fields`);
per-pixel photometry there uses :func:`~simulator.scene.photometry.photometric_ratio_from_cosines`.

Smear fields (fidelity shortcut ``warp_smear_fields``): the fast-flush and frame-transfer fields only
enter the image through block sums of columns (smear, then 4-row binning), and their poses differ
from the exposure's by a pixel or so. Instead of rendering them, :func:`~simulator.scene.resample.warped_field` resamples the
block means of the exposure-centre field (shape (H / b, W)) along the exact ground-plane flow between
the two poses (ground point of each block centre at the smear pose, projected with the exposure pose),
computed on a node grid every :data:`WARP_GRID_STEP_PX` pixels and interpolated; the camera chain takes
such block-mean fields directly (:func:`simulator.detector.camera_chain.render_image`).
When any node's ray misses the ground or leaves the exposure image (horizon in view, violent motion)
the field is rendered exactly instead. Measured error: ``make bench`` (fidelity table).

``config`` is a :class:`simulator.descent_image.SceneConfig`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import partial

import cv2
import numpy as np

from flight_interface.camera import Camera
from flight_interface.frames import quat_to_matrix
from simulator.fields import RadianceFields, block_means
from simulator.scene import (
    atmosphere,
    blur_warp,
    ground_mapping,
    heat_shield,
    motion_blur,
    photometry,
    relief,
    resample,
    shadow,
)
from simulator.scene.descent_profile import DescentProfile, Pose
from simulator.scene.terrain import Terrain

WARP_GRID_STEP_PX = 32


@dataclass(frozen=True)
class PoseField:
    """Radiance at one pose, with its masks (all (H, W))."""

    radiance: np.ndarray               # float32, W m^-2 sr^-1 um^-1
    sky: np.ndarray                    # bool
    outside: np.ndarray                # bool, ground outside the terrain strip
    heat_shield: np.ndarray | None     # bool, or None when the heat shield is not in view
    camera_pose: ground_mapping.CameraPose
    shadow_centres_m: list = field(default_factory=list)


@dataclass(frozen=True)
class PeriodScene:
    """Radiance fields of the three CCD periods plus exposure-period masks (union over sub-poses)."""

    fields: RadianceFields
    sky: np.ndarray
    outside: np.ndarray
    heat_shield: np.ndarray
    substeps: dict                      # period -> number of sub-poses (0 when the field is shared/unused)
    shared: bool                        # one field stands for all three periods
    exposure_centre: PoseField          # the field at the exposure mid-time (diagnostics)


def sun_unit_vector(sun_world) -> np.ndarray:
    """Validate a world unit vector toward the sun (above the horizon)."""
    sun = np.asarray(sun_world, dtype=float)
    if sun.shape != (3,) or not np.all(np.isfinite(sun)) or abs(np.linalg.norm(sun) - 1.0) > 1e-6 or sun[2] <= 0:
        raise ValueError(f"sun: must be a world unit 3-vector toward the sun with z > 0 (sun above the horizon); "
                         f"got {sun_world!r}")
    return sun


def casters(pose: Pose, config) -> list[shadow.Caster]:
    """Shadow casters at a pose: lander, backshell and parachute along the lander's +z axis, heat shield."""
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


def photometric_ratio_field(camera: Camera, pose: ground_mapping.CameraPose, ground_map: ground_mapping.GroundMap,
                            sun: np.ndarray, moc_value: float, grid_step_px: int) -> np.ndarray:
    """DIMES/MOC photometric ratio of every pixel (H, W) float32; on the coarse node grid and
    interpolated when ``grid_step_px > 0``, else per pixel from the ground map's rays (emission and
    phase cosines, :func:`~simulator.scene.photometry.photometric_ratio_from_cosines`). The result is a
    :func:`~simulator.scene.ground_mapping.scratch` array: multiply it in before the next call."""
    if grid_step_px == 0:
        cos_emission, cos_phase = ground_mapping.view_cosines(camera, pose, ground_map, sun)
        return photometry.photometric_ratio_from_cosines(cos_emission, cos_phase, float(sun[2]), moc_value)
    view = ground_mapping.view_directions(camera, pose, ground_map, grid_step_px)
    return ground_mapping.field_at_pixels(photometry.photometric_ratio(view, sun, moc_value), camera, grid_step_px,
                                          scratch_name="photometric_ratio")


HEAT_SHIELD_EDGE_SAMPLES = 3   # s x s sub-pixel rays on the heat-shield silhouette (not in supersampling's samples)


PIXEL_AREA_KERNEL = np.array([1.0 / 24.0, 11.0 / 12.0, 1.0 / 24.0], dtype=np.float32)


def pixel_area_average(point_samples: np.ndarray) -> np.ndarray:
    """Pixel-area averages of a field known at pixel centres (H, W) float32, to second order.

    A pixel integrates the scene over its area; for a field smooth at the pixel scale the mean over a
    unit box is ``f + (f_xx + f_yy) / 24 + O(h^4)`` (midpoint rule with its error term), and the
    separable kernel ``[1, 22, 1] / 24`` applies exactly that correction with second differences. It
    stands in for supersampling the terrain (measured against the 3 x 3 reference by ``make bench``);
    edges are replicated.
    """
    return cv2.sepFilter2D(point_samples, -1, PIXEL_AREA_KERNEL, PIXEL_AREA_KERNEL, borderType=cv2.BORDER_REPLICATE)


def subpixel_camera(camera: Camera, column_offset_px: float, row_offset_px: float) -> Camera:
    """The camera whose pixel (c, r) sees what ``camera``'s point (c + column_offset, r + row_offset)
    sees: CAHVOR ``H' = H - dc A``, ``V' = V - dr A`` (cached per camera)."""
    cache = ground_mapping.camera_cache(camera)
    key = ("subpixel", float(column_offset_px), float(row_offset_px))
    if key not in cache:
        model = camera.model
        cache[key] = replace(camera, model=replace(model, h=model.h - column_offset_px * model.a,
                                                   v=model.v - row_offset_px * model.a))
    return cache[key]


def radiance_at_pose(terrain: Terrain, camera: Camera, pose: Pose, sun_world: np.ndarray, config,
                     _sub_sample: bool = False, moving_shadows=None) -> PoseField:
    """The radiance field (H, W) the camera sees at one instantaneous pose (see module doc).

    ``moving_shadows`` (:class:`simulator.off_nominal.moving_shadows.MovingShadows` or None) darkens
    the ground where the dust-devil and cloud shadows are at ``pose.time_s``, after the casters' shadows.

    With ``config.supersample = s > 1`` each pixel is the mean of ``s x s`` sub-pixel point samples on
    a regular grid (offsets ``(k + 0.5)/s - 0.5`` px; the samples themselves use no area shortcut);
    masks are the union over the samples. (``_sub_sample``: one such sample, whose radiance is a
    scratch array the caller adds up before rendering the next.)
    """
    samples = config.supersample
    if samples > 1:
        single = config.model_copy(update={"supersample": 1})
        offsets = (np.arange(samples) + 0.5) / samples - 0.5
        # each sample's field lives in a scratch array: summed (in sample order, as average_fields) at once
        def sample(dc: float, dr: float) -> PoseField:
            return radiance_at_pose(terrain, subpixel_camera(camera, dc, dr), pose, sun_world, single,
                                    _sub_sample=True, moving_shadows=moving_shadows)
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
        return PoseField(total, sky, outside, shield, ground_mapping.camera_pose(camera, pose), first.shadow_centres_m)
    effects = config.effects
    sun = sun_unit_vector(sun_world)
    cam = ground_mapping.camera_pose(camera, pose)

    footprint, hit = ground_mapping.footprint_m(camera, cam)
    foot_rows, foot_cols = terrain.world_to_pixel(footprint[hit, 0], footprint[hit, 1])
    bounded = bool(hit.all())
    crop = resample.footprint_crop(terrain, foot_cols, foot_rows, bounded)
    rows, cols = terrain.shape
    inside = bounded and (foot_cols.min() > 0.5 and foot_rows.min() > 0.5
                          and foot_cols.max() < cols - 1.5 and foot_rows.max() < rows - 1.5)

    ray_step = config.ray_grid_step_px if effects.coarse_ray_grid else 0
    gmap = ground_mapping.map_to_ground_grid(camera, cam, (terrain.origin_m[0], terrain.origin_m[1]),
                                             terrain.metres_per_pixel, ray_step, scratch_maps=True)
    relief_hits = None
    if relief.has_relief(terrain, config):   # parallax and occlusion of the height field (scene.relief)
        gmap, relief_hits = relief.relief_ground_map(terrain, camera, cam, gmap, config)
        crop, inside = relief_hits.crop, False
    area_filter = effects.pixel_area_filter and not _sub_sample   # (a supersampled render averages point samples)
    # the point samples are filtered into a new array at once, and a supersampling sample's field is summed
    # by the caller before the next sample: both live in scratch arrays
    moc_if, outside = resample.sample_terrain(terrain, gmap.col, gmap.row, gmap.sky if gmap.any_sky else None,
                                              crop, may_leave_terrain=not inside,
                                              out=ground_mapping.scratch("point_samples", gmap.col.shape)
                                              if area_filter or _sub_sample else None)
    if area_filter:
        moc_if = pixel_area_average(moc_if)
        if gmap.any_sky:
            moc_if[gmap.sky] = 0.0        # no terrain bleeding across the horizon

    irradiance = photometry.solar_band_irradiance_w_m2_um(config.sun_distance_au)
    scale = irradiance / np.pi * (config.spectral_ratio if effects.spectral_ratio else 1.0)
    radiance = moc_if
    photo_step = config.photometry_grid_step_px if effects.coarse_photometry else 0
    moc_value = None
    if effects.photometric_correction:
        moc_value = photometry.moc_reflectance_model(terrain.moc_incidence_rad, terrain.moc_emission_rad,
                                                     terrain.moc_phase_rad)
    added = None
    if config.atmosphere.enabled:
        # orbital haze out, descent gain and added light on the photometry grid (simulator.scene.atmosphere)
        haze = atmosphere.orbital_haze(terrain, config.atmosphere)
        atmosphere.remove_orbital_haze(radiance, haze)
        gain, added = atmosphere.descent_fields(camera, cam, gmap, sun, moc_value, scale, haze, config.atmosphere,
                                                 photo_step)
        radiance *= gain
    elif moc_value is not None:      # effects.photometric_correction
        # the radiometric scale is folded into the ratio (on the node grid when coarse): one full-frame pass
        radiance *= photometric_ratio_field(camera, cam, gmap, sun, moc_value / scale, photo_step)
    else:
        radiance *= np.float32(scale)

    if relief_hits is not None:      # slope photometry and cast shadows of the relief
        radiance *= relief.shading_factor(relief_hits, sun, config)
    centres = []
    if effects.shadows:
        centres = shadow.apply_shadows(radiance, gmap, camera, cam, casters(pose, config), sun,
                                       photometry.solar_angular_radius_rad(config.sun_distance_au),
                                       config.shadow_diffuse_fraction)
    if moving_shadows is not None:
        moving_shadows.darken(radiance, gmap, camera, cam, pose.time_s, terrain.origin_m, terrain.metres_per_pixel)
    if added is not None:          # path and adjacency light: not shadowed, none where the ray sees sky
        radiance += added
        if gmap.any_sky:
            radiance[gmap.sky] = 0.0
    shield = None
    if effects.heat_shield and pose.heat_shield_position_m is not None:
        shield = heat_shield.draw_heat_shield(radiance, gmap, camera, cam,
                                              np.asarray(pose.heat_shield_position_m, dtype=float), sun,
                                              irradiance, config.heat_shield_diameter_m,
                                              config.heat_shield_cone_angle_rad, config.heat_shield_reflectance,
                                              edge_samples=1 if _sub_sample else HEAT_SHIELD_EDGE_SAMPLES)
    if shield is not None:
        outside &= ~shield
    return PoseField(radiance, gmap.sky, outside, shield, cam, centres)


def flow_map(camera: Camera, source: ground_mapping.CameraPose, target: ground_mapping.CameraPose,
             step_px: int = WARP_GRID_STEP_PX, block_rows: int = 1,
             scratch_name: str | None = None) -> np.ndarray | None:
    """Where each pixel of an image taken at ``target`` finds its ground point in an image taken at ``source``.

    With ``block_rows = b > 1`` the map is for blocks of ``b`` rows (row k centred on pixel row
    ``b k + (b - 1) / 2``) and gives source coordinates in the same block units.

    Returns
    -------
    ndarray (height / b, width, 2) float32 of (column, row) source coordinates, bilinear from the node
    grid, or None when a node's ray misses the ground or its point is behind or more than one node step
    outside the source frame (the flow is then not a small smooth warp). With ``scratch_name`` the map
    is a view of that :func:`~simulator.scene.ground_mapping.scratch` array (use it before the next call).
    """
    rows = ground_mapping.node_positions(camera.height_px, step_px)
    cols = ground_mapping.node_positions(camera.width_px, step_px)
    grid = np.stack(np.meshgrid(cols, rows), axis=-1)
    points, hit = ground_mapping.ground_points(camera, target, grid)
    if not hit.all():
        return None
    source_pixels, in_front = ground_mapping.world_to_pixels(camera, source, points)
    margin = step_px + 1.0
    if (not in_front.all() or source_pixels[..., 0].min() < -margin or source_pixels[..., 1].min() < -margin
            or source_pixels[..., 0].max() > camera.width_px + margin
            or source_pixels[..., 1].max() > camera.height_px + margin):
        return None
    if block_rows == 1:
        return ground_mapping.upsample_nodes(source_pixels, step_px, camera.height_px, camera.width_px,
                                             scratch_name=scratch_name)
    # node rows (k + 1/2) s - 1/2 in pixels are (k + 1/2) (s / b) - 1/2 in blocks: the same layout
    source_pixels[..., 1] = (source_pixels[..., 1] - 0.5 * (block_rows - 1)) / block_rows
    return ground_mapping.upsample_nodes(source_pixels, step_px, camera.height_px // block_rows, camera.width_px,
                                         row_step_px=step_px // block_rows, scratch_name=scratch_name)


def _clamped_pose(profile: DescentProfile, time_s: float) -> Pose:
    return profile.pose(float(np.clip(time_s, profile.time_s[0], profile.time_s[-1])))


def period_fields(terrain: Terrain, camera: Camera, profile: DescentProfile, exposure_start_s: float,
                  sun_world: np.ndarray, config, need_smear_fields: bool = True, moving_shadows=None) -> PeriodScene:
    """Radiance fields of the fast flush, exposure and frame transfer of one image (see module doc).

    ``need_smear_fields=False`` (the camera's smear switch is off) computes only the exposure field
    and passes it for all three periods. ``moving_shadows``: as :func:`radiance_at_pose`.
    """
    render = partial(radiance_at_pose, moving_shadows=moving_shadows)   # each pose's own shadow positions
    effects = config.effects
    timing = camera.timing
    t = float(exposure_start_s)
    windows = {
        "flush": (t - timing.fast_flush_s, t),
        "exposure": (t, t + timing.exposure_s),
        "transfer": (t + timing.exposure_s, t + timing.exposure_s + timing.frame_transfer_s),
    }
    mpp = terrain.metres_per_pixel

    poses: dict[float, Pose] = {}
    camera_poses: dict[float, ground_mapping.CameraPose] = {}

    def pose_at(time_s):          # the same instants recur (window ends, mid-times): interpolate once
        if time_s not in poses:
            poses[time_s] = _clamped_pose(profile, time_s)
        return poses[time_s]

    def cam_at(time_s):
        if time_s not in camera_poses:
            camera_poses[time_s] = ground_mapping.camera_pose(camera, pose_at(time_s))
        return camera_poses[time_s]

    camera_height_m = cam_at(timing.exposure_mid_time_s(t)).ray_origin_m[2]
    if not camera_height_m > 0.0:
        raise ValueError(f"profile {profile.name}: the camera is at {camera_height_m:.3f} m, at or below the "
                         "ground (z = 0) at the exposure; the simulator needs it above the ground")
    first = windows["flush"][0] if need_smear_fields else windows["exposure"][0]
    last = windows["transfer"][1] if need_smear_fields else windows["exposure"][1]
    total_shift = motion_blur.image_shift(camera, cam_at(first), cam_at(last), mpp)
    centre_s = timing.exposure_mid_time_s(t)

    def masks(pose_fields):
        sky = pose_fields[0].sky.copy()
        outside = pose_fields[0].outside.copy()
        shield = np.zeros_like(sky)
        for item in pose_fields:
            if item is not pose_fields[0]:
                sky |= item.sky
                outside |= item.outside
            if item.heat_shield is not None:
                shield |= item.heat_shield
        return sky, outside, shield

    still = effects.share_still_fields and total_shift < config.still_shift_terrain_px
    if still or not effects.motion_blur and not need_smear_fields:
        centre = render(terrain, camera, pose_at(centre_s), sun_world, config)
        sky, outside, shield = masks([centre])
        fields = RadianceFields(centre.radiance, centre.radiance, centre.radiance)
        return PeriodScene(fields, sky, outside, shield, {"flush": 0, "exposure": 1, "transfer": 0}, True, centre)

    counts = {}
    for period, (start, end) in windows.items():
        if period != "exposure" and not need_smear_fields:
            counts[period] = 0
        elif effects.motion_blur:
            shift = motion_blur.image_shift(camera, cam_at(start), cam_at(end), mpp)
            counts[period] = motion_blur.substep_count(shift * config.substeps_per_terrain_px, config.max_substeps)
        else:
            counts[period] = 1
    if (effects.warp_motion_blur and effects.motion_blur and need_smear_fields
            and counts["exposure"] >= blur_warp.MIN_EXPOSURE_SUBSTEPS):
        warped = blur_warp.warped_period_fields(
            camera, pose_at, cam_at, windows, centre_s, max(counts.values()),
            lambda cam, pose: render(terrain, cam, pose, sun_world, config),
            lambda time_s: (blur_warp.moving_world_points(pose_at(time_s), casters(pose_at(time_s), config),
                                                          sun_unit_vector(sun_world)) if effects.shadows else [])
            + (moving_shadows.points_m(time_s) if moving_shadows is not None else []))
        if warped is not None:
            centre_pose = pose_at(centre_s)
            centre = PoseField(warped.centre_radiance, warped.sky, warped.outside, warped.centre_heat_shield,
                               ground_mapping.camera_pose(camera, centre_pose), warped.shadow_centres_m)
            return PeriodScene(warped.fields, warped.sky, warped.outside, warped.heat_shield, warped.substeps,
                               False, centre)

    centre = render(terrain, camera, pose_at(centre_s), sun_world, config)
    averaged, exposure_fields, centre_blocks = {}, [centre], None
    for period, (start, end) in windows.items():
        count = counts[period]
        if count == 0:
            continue
        if period == "exposure" and count == 1:
            pose_fields = [centre]
        elif period != "exposure" and effects.warp_smear_fields:
            if centre_blocks is None:
                centre_blocks = block_means(centre.radiance, camera.binning_rows)
            averaged[period] = motion_blur.average_fields(
                [_smear_field(terrain, camera, pose_at(float(time)), sun_world, config, centre, centre_blocks,
                              moving_shadows)
                 for time in motion_blur.substep_times(start, end, count)])
            continue
        else:   # an odd exposure count's middle sub-pose may be the centre instant itself: rendered above
            pose_fields = [centre if float(time) == centre_s else render(terrain, camera, pose_at(float(time)),
                                                                         sun_world, config)
                           for time in motion_blur.substep_times(start, end, count)]
        if period == "exposure":
            exposure_fields = pose_fields
        averaged[period] = motion_blur.average_fields([item.radiance for item in pose_fields])
    sky, outside, shield = masks(exposure_fields)
    exposure = averaged["exposure"]
    fields = RadianceFields(averaged.get("flush", exposure), exposure, averaged.get("transfer", exposure))
    return PeriodScene(fields, sky, outside, shield, counts, False, centre)


def _smear_field(terrain: Terrain, camera: Camera, pose: Pose, sun_world: np.ndarray, config, centre: PoseField,
                 centre_blocks: np.ndarray, moving_shadows=None) -> np.ndarray:
    """The radiance field at ``pose`` for smear, per binning block (block means, (H / b, W)): warped
    from the exposure-centre field's block means when the flow allows (:func:`flow_map`), else the
    block means of the field rendered exactly."""
    block_rows = camera.binning_rows
    flow = None
    if not centre.sky.any() and WARP_GRID_STEP_PX % block_rows == 0:
        flow = flow_map(camera, centre.camera_pose, ground_mapping.camera_pose(camera, pose), block_rows=block_rows,
                        scratch_name="smear_flow")
    if flow is None:
        return block_means(radiance_at_pose(terrain, camera, pose, sun_world, config,
                                            moving_shadows=moving_shadows).radiance,
                                           block_rows)
    return resample.warped_field(centre_blocks, flow)
