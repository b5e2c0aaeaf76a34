"""The radiance fields of one image's three CCD periods, from the fields of its poses (paper 3.2).

The fast flush ``[t - T_flush, t]``, exposure ``[t, t + T_exp]`` and frame transfer
``[t + T_exp, t + T_exp + T_transfer]`` each get the mean of the fields at sub-poses spaced by one
terrain pixel of image shift. How the motion is integrated is chosen in one place,
:func:`simulator.scene.motion_blur.choose_blur`:

* ``"still"``: the exposure-centre field stands for all three periods (the same array object, which
  the camera chain converts once);
* ``"warp"``: warp-and-accumulate of one rendered field (:mod:`simulator.scene.blur_warp`); when the
  warp finds the scene does not allow it, the periods are integrated by sub-poses instead;
* ``"sub_poses"``: the mean of the fields rendered at each period's sub-poses
  (:func:`simulator.scene.radiance.radiance_at_pose`); with ``warp_smear_fields`` the flush and
  transfer sub-poses are warped from the exposure-centre field (:mod:`simulator.scene.smear_warp`).

Times outside the profile are clamped to its ends (the pose is held). An odd exposure sub-pose count
has its middle sub-pose at the exposure mid-time; when that instant is bit-equal to the mid-time the
centre field already rendered stands for it. The heat-shield glint (off-nominal) is added to the
finished fields (:func:`simulator.scene.glint.add_glint`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from flight_interface.camera import Camera
from simulator.fields import RadianceFields, block_means
from simulator.scene import blur_warp, glint, ground_mapping, motion_blur
from simulator.scene.descent_profile import DescentProfile, Pose
from simulator.scene.radiance import PoseField, casters, radiance_at_pose, sun_unit_vector
from simulator.scene.smear_warp import smear_field
from simulator.scene.terrain import Terrain


@dataclass(frozen=True)
class PeriodScene:
    """Radiance fields of the three CCD periods plus exposure-period masks (union over sub-poses).

    Parameters
    ----------
    fields : RadianceFields
        Flush, exposure and transfer radiance (W m^-2 sr^-1 um^-1), (H, W) float32 or, when warped,
        per binning block (H / b, W).
    sky : ndarray, shape (H, W), bool
        Pixels whose ray misses the ground at any exposure sub-pose.
    outside : ndarray, shape (H, W), bool
        Pixels that see ground outside the terrain strip.
    heat_shield : ndarray, shape (H, W), bool
        Pixels that see the heat shield.
    substeps : dict of str to int
        Period -> number of sub-poses (0 when the field is shared or unused).
    shared : bool
        One field stands for all three periods.
    exposure_centre : PoseField
        The field at the exposure mid-time (diagnostics: its camera pose is the image's). On the
        warp-and-accumulate path its radiance, masks and shadow centres are those of the one rendered field,
        at the exposure's sub-pose N / 2 (half a sub-pose step after the mid-time).
    """

    fields: RadianceFields
    sky: np.ndarray
    outside: np.ndarray
    heat_shield: np.ndarray
    substeps: dict
    shared: bool
    exposure_centre: PoseField


def clamped_pose(profile: DescentProfile, time_s: float) -> Pose:
    """The profile's pose at ``time_s``, held at the profile's ends outside its time span.

    Parameters
    ----------
    profile : DescentProfile
        The lander trajectory.
    time_s : float
        Time (s).

    Returns
    -------
    Pose
        The pose at ``time_s`` clamped to ``[profile.time_s[0], profile.time_s[-1]]``.
    """
    return profile.pose(min(max(float(time_s), float(profile.time_s[0])), float(profile.time_s[-1])))   # np.clip's value


def period_windows(camera: Camera, exposure_start_s: float) -> dict[str, tuple[float, float]]:
    """The fast flush, exposure and frame transfer windows of an image.

    Parameters
    ----------
    camera : Camera
        The camera (its timing).
    exposure_start_s : float
        Start of the exposure (s).

    Returns
    -------
    dict of str to (float, float)
        ``"flush"``, ``"exposure"``, ``"transfer"`` -> ``(start_s, end_s)``.
    """
    timing = camera.timing
    t = float(exposure_start_s)
    return {
        "flush": (t - timing.fast_flush_s, t),
        "exposure": (t, t + timing.exposure_s),
        "transfer": (t + timing.exposure_s, t + timing.exposure_s + timing.frame_transfer_s),
    }


def _mask_union(pose_fields: list[PoseField]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Union of the sky, outside-terrain and heat-shield masks of pose fields, each (H, W) bool.

    One field gives its own masks (new arrays of its render, written by nothing after it; no copy).
    """
    if len(pose_fields) == 1:
        only = pose_fields[0]
        return only.sky, only.outside, (np.zeros_like(only.sky) if only.heat_shield is None else only.heat_shield)
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


def period_fields(terrain: Terrain, camera: Camera, profile: DescentProfile, exposure_start_s: float,
                  sun_world: np.ndarray, config, need_smear_fields: bool = True, moving_shadows=None) -> PeriodScene:
    """Radiance fields of the fast flush, exposure and frame transfer of one image (see module doc).

    Parameters
    ----------
    terrain : Terrain
        Orbital I/F image with its photometric geometry.
    camera : Camera
        The descent camera.
    profile : DescentProfile
        Lander trajectory (with the heat shield's).
    exposure_start_s : float
        Start of the exposure (s).
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun, z > 0.
    config : simulator.scene_config.SceneConfig
        Scene parameters and switches.
    need_smear_fields : bool, optional
        False (the camera's smear switch is off) computes only the exposure field and passes it for
        all three periods.
    moving_shadows : simulator.off_nominal.moving_shadows.MovingShadows, optional
        Dust-devil and cloud shadows, placed on the ground (as :func:`~simulator.scene.radiance.radiance_at_pose`).

    Returns
    -------
    PeriodScene
        The three fields, the exposure masks and how they were made.
    """
    render = partial(radiance_at_pose, moving_shadows=moving_shadows)   # each pose's own shadow positions
    timing = camera.timing
    windows = period_windows(camera, exposure_start_s)
    centre_s = timing.exposure_mid_time_s(float(exposure_start_s))

    poses: dict[float, Pose] = {}
    camera_poses: dict[float, ground_mapping.CameraPose] = {}

    def pose_at(time_s: float) -> Pose:     # the same instants recur (window ends, mid-times): interpolate once
        if time_s not in poses:
            poses[time_s] = clamped_pose(profile, time_s)
        return poses[time_s]

    def cam_at(time_s: float) -> ground_mapping.CameraPose:
        if time_s not in camera_poses:
            camera_poses[time_s] = ground_mapping.camera_pose(camera, pose_at(time_s))
        return camera_poses[time_s]

    camera_height_m = cam_at(centre_s).ray_origin_m[2]
    if not camera_height_m > 0.0:
        raise ValueError(f"profile {profile.name}: the camera is at {camera_height_m:.3f} m, at or below the "
                         "ground (z = 0) at the exposure; the simulator needs it above the ground")
    choice = motion_blur.choose_blur(camera, cam_at, windows, terrain.metres_per_pixel, config, need_smear_fields)
    if choice.method == "still":
        centre = render(terrain, camera, pose_at(centre_s), sun_world, config)
        sky, outside, shield = _mask_union([centre])
        fields = RadianceFields(centre.radiance, centre.radiance, centre.radiance)
        scene = PeriodScene(fields, sky, outside, shield, choice.substeps, True, centre)
    else:
        warped = (_warped_periods(terrain, camera, pose_at, cam_at, windows, centre_s, choice, sun_world, config,
                                  render, moving_shadows) if choice.method == "warp" else None)
        scene = warped if warped is not None else _sub_pose_periods(
            terrain, camera, pose_at, windows, centre_s, choice, sun_world, config, render, moving_shadows)
    off_nominal = config.off_nominal
    if (off_nominal.heat_shield_glint and config.effects.heat_shield and profile.heat_shield_position_m is not None
            and off_nominal.heat_shield_specular_reflectance > 0):
        glint.add_glint(scene.fields, scene.shared, scene.substeps, camera, pose_at, windows, centre_s,
                              sun_world, config)
    return scene


def _warped_periods(terrain, camera, pose_at, cam_at, windows, centre_s, choice, sun_world, config, render,
                    moving_shadows) -> PeriodScene | None:
    """The periods by warp-and-accumulate, or None when the scene does not allow it.

    :func:`simulator.scene.blur_warp.warped_period_fields`.
    """
    effects = config.effects
    warped = blur_warp.warped_period_fields(
        camera, pose_at, cam_at, windows, max(choice.substeps.values()),
        lambda cam, pose: render(terrain, cam, pose, sun_world, config),
        lambda time_s: (blur_warp.moving_world_points(pose_at(time_s), casters(pose_at(time_s), config),
                                                      sun_unit_vector(sun_world)) if effects.shadows else [])
        + (moving_shadows.points_m(time_s) if moving_shadows is not None else []))
    if warped is None:
        return None
    centre = PoseField(warped.centre_radiance, warped.sky, warped.outside, warped.centre_heat_shield,
                       ground_mapping.camera_pose(camera, pose_at(centre_s)), warped.shadow_centres_m)
    return PeriodScene(warped.fields, warped.sky, warped.outside, warped.heat_shield, warped.substeps, False, centre)


def _sub_pose_periods(terrain, camera, pose_at, windows, centre_s, choice, sun_world, config, render,
                      moving_shadows) -> PeriodScene:
    """Each period as the mean of the fields at its sub-poses.

    Rendered, or for the smear periods warped from the exposure-centre field when ``choice.warp_smear_fields``).
    """
    counts = choice.substeps
    centre = render(terrain, camera, pose_at(centre_s), sun_world, config)
    averaged, exposure_fields, centre_blocks = {}, [centre], None
    for period, (start, end) in windows.items():
        count = counts[period]
        if count == 0:
            continue
        if period == "exposure" and count == 1:
            pose_fields = [centre]
        elif period != "exposure" and choice.warp_smear_fields:
            if centre_blocks is None:
                centre_blocks = block_means(centre.radiance, camera.binning_rows)
            averaged[period] = motion_blur.average_fields(
                [smear_field(terrain, camera, pose_at(float(time)), sun_world, config, centre, centre_blocks,
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
    sky, outside, shield = _mask_union(exposure_fields)
    exposure = averaged["exposure"]
    fields = RadianceFields(averaged.get("flush", exposure), exposure, averaged.get("transfer", exposure))
    return PeriodScene(fields, sky, outside, shield, counts, False, centre)
