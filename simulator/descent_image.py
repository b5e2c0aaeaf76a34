"""One call renders a descent image: (terrain, profile, camera, image, sun) -> 12-bit image + masks.

Usage::

    from simulator.scene_config import SceneConfig
    from simulator.descent_image import render_descent_image
    result = render_descent_image(terrain, profile, camera, 0, sun_world, SceneConfig(), rng)
    result.dn                 # uint16 (256, 1024), what the camera returns
    result.sky_mask           # bool (1024, 1024), pixels whose ray misses the ground
    result.diagnostics.anti_sun_pixel

The configuration (:class:`~simulator.scene_config.SceneConfig`: scene parameters, effect switches,
camera effects, off-nominal effects) is in :mod:`simulator.scene_config`, which also declares the TOML
``[scene]`` table it is validated from.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED
from simulator.detector.camera_chain import RenderedImage, render_image
from simulator.fields import RadianceFields
from simulator.heap import keep_freed_buffers
from simulator.off_nominal import OffNominalArtefacts, OffNominalConfig
from simulator.off_nominal.moving_shadows import place_moving_shadows
from simulator.scene import ground_mapping, photometry, shadow, unproject_compiled
from simulator.scene.descent_profile import DescentProfile, Pose, scale_angular_rates
from simulator.scene.periods import period_fields
from simulator.scene.radiance import sun_unit_vector
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig


@dataclass(frozen=True)
class SceneDiagnostics:
    """What the scene did for one image.

    Attributes
    ----------
    exposure_start_s : float
        Start of the exposure (s).
    pose : Pose
        Lander state at the start of the exposure.
    camera_pose : CameraPose
        Camera pose at the exposure mid-time.
    substeps : dict of str to int
        Period -> sub-pose count (0: the field is shared or unused).
    shared_fields : bool
        One field stood for all three periods.
    anti_sun_ground_m : ndarray, shape (3,)
        Where the sun line through the camera meets the ground (m).
    anti_sun_pixel : ndarray, shape (2,), or None
        (column, row) of that point, or None when it is not in the image.
    shadow_centres_m : list of ndarray, shape (3,)
        Ground shadow centres of the casters (m).
    footprint_m : ndarray, shape (n, 2)
        East/north ground polygon of the image border (m).
    footprint_hit : ndarray, shape (n,), bool
        Whether each border ray meets the ground.
    heat_shield_visible : bool
        The heat shield is in the image.
    scene_ms, camera_ms : float
        Wall time of the scene and camera stages (ms).
    """

    exposure_start_s: float
    pose: Pose
    camera_pose: ground_mapping.CameraPose
    substeps: dict
    shared_fields: bool
    anti_sun_ground_m: np.ndarray
    anti_sun_pixel: np.ndarray | None
    shadow_centres_m: list
    footprint_m: np.ndarray
    footprint_hit: np.ndarray
    heat_shield_visible: bool
    scene_ms: float
    camera_ms: float


@dataclass(frozen=True)
class DescentImage:
    """A rendered descent image with its radiance fields, masks and diagnostics.

    Attributes
    ----------
    image : RenderedImage
        The read-out image (DN, expected DN and charge, binned).
    radiance : RadianceFields
        Radiance (W m^-2 sr^-1 um^-1) of the three periods, (H, W) or per binning block (H / b, W).
    sky_mask : ndarray, shape (H, W), bool
        Pixels whose ray misses the ground (exposure period, union over sub-poses).
    outside_terrain_mask : ndarray, shape (H, W), bool
        Pixels that see ground outside the terrain strip.
    heat_shield_mask : ndarray, shape (H, W), bool
        Pixels that see the heat shield.
    diagnostics : SceneDiagnostics
        What the scene did.
    """

    image: RenderedImage
    radiance: RadianceFields
    sky_mask: np.ndarray
    outside_terrain_mask: np.ndarray
    heat_shield_mask: np.ndarray
    diagnostics: SceneDiagnostics

    @property
    def dn(self) -> np.ndarray:
        """uint16 (binned rows, width) image as the camera returns it."""
        return self.image.dn

    @property
    def outside_terrain_fraction(self) -> float:
        """Fraction of the pixels that see ground outside the terrain strip.

        ``outside_terrain_mask.mean()`` as a count: the same float (an exact count over the exact size), in 0.04
        against 0.46 ms a frame.
        """
        return np.count_nonzero(self.outside_terrain_mask) / self.outside_terrain_mask.size

    def binned_mask(self, mask: np.ndarray, binning_rows: int) -> np.ndarray:
        """A full-frame mask reduced to the binned image: True where any of the binned rows is True.

        Parameters
        ----------
        mask : ndarray, shape (H, W), bool
            Full-frame mask.
        binning_rows : int
            Rows per binning block ``b``.

        Returns
        -------
        ndarray, shape (H / b, W), bool
            The binned mask.
        """
        height, width = mask.shape
        return np.asarray(mask.reshape(height // binning_rows, binning_rows, width).any(axis=1))


def image_start_time(profile: DescentProfile, image: int | float) -> float:
    """Start-of-exposure time of an image of a profile.

    Parameters
    ----------
    profile : DescentProfile
        The descent profile.
    image : int or float
        An index into ``profile.image_times_s`` (int) or a time (s, float).

    Returns
    -------
    float
        Start of the exposure (s).

    Raises
    ------
    IndexError
        An index out of range.
    TypeError
        A bool.
    """
    if isinstance(image, (bool, np.bool_)):
        raise TypeError(f"image: expected an image index (int) or a time in s (float); got {image!r}")
    if isinstance(image, (int, np.integer)):
        count = len(profile.image_times_s)
        if not -count <= image < count:
            raise IndexError(f"profile {profile.name}: image index {image} out of range; allowed: 0 .. {count - 1}")
        return float(profile.image_times_s[image])
    return float(image)


def render_descent_image(terrain: Terrain, profile: DescentProfile, camera: Camera, image: int | float,
                         sun_world, config: SceneConfig | None = None,
                         rng: np.random.Generator | None = None,
                         artefacts: OffNominalArtefacts | None = None) -> DescentImage:
    """Render one descent image: scene (all three CCD periods, motion blur) then the camera chain.

    Parameters
    ----------
    terrain : Terrain
        Orbital I/F image with its photometric geometry (world frame: east/north m, ground z = 0).
    profile : DescentProfile
        Lander trajectory (world frame), possibly with the heat shield trajectory.
    camera : Camera
    image : int or float
        Index into ``profile.image_times_s`` (int) or start-of-exposure time in s (float). The fast
        flush starts ``camera.timing.fast_flush_s`` earlier and the frame transfer ends
        ``exposure_s + frame_transfer_s`` later; poses outside the profile's time span are held at
        its ends.
    sun_world : (3,) array_like
        World unit vector toward the sun (x east, y north, z up), z > 0.
    config : SceneConfig, optional
        Scene parameters and switches (scene and camera effects); default ``SceneConfig()``.
    rng : numpy.random.Generator, optional
        Noise stream of this image (shot and read noise). None renders without noise (shot and read
        noise switched off, ``dn`` is the rounded expected image).
    artefacts : OffNominalArtefacts, optional
        The case's dust and hot pixels plus this image's particle hits
        (:func:`simulator.off_nominal.draw_case_artefacts`, :func:`~simulator.off_nominal.with_particle_hits`);
        required when ``config.off_nominal`` asks for any of them or for moving shadows (their draws
        are placed on the ground from ``profile``'s middle image). The heat-shield glint, blooming and
        the angular rate multiplier of ``config.off_nominal`` need no artefacts.

    Returns
    -------
    DescentImage
        ``.dn`` uint16 (256, 1024); ``.radiance`` the three fields (W m^-2 sr^-1 um^-1): (1024, 1024)
        or, when warped, per binning block (256, 1024) - the smear fields, and all three when a long
        blur was integrated by warp-and-accumulate (:mod:`simulator.scene.blur_warp`);
        ``.sky_mask``, ``.outside_terrain_mask``, ``.heat_shield_mask`` (1024, 1024) bool;
        ``.diagnostics`` (anti-sun pixel, sub-steps, footprint, timings...).
    """
    keep_freed_buffers()       # frame-sized arrays reused from the heap, not faulted in afresh (simulator.heap)
    config = SceneConfig() if config is None else config
    camera_effects = config.camera_effects
    if rng is None:
        camera_effects = camera_effects.model_copy(update={"shot_noise": False, "read_noise": False})
        rng = np.random.default_rng(0)   # unused: every random draw is switched off
    sun = sun_unit_vector(sun_world)
    start_s = image_start_time(profile, image)
    off_nominal = config.off_nominal
    artefacts = _camera_artefacts(off_nominal, artefacts)
    moving = None
    if artefacts is not None and artefacts.moving_shadows is not None:   # placed on the unscaled profile
        moving = place_moving_shadows(artefacts.moving_shadows, off_nominal, camera, profile, sun,
                                      photometry.solar_angular_radius_rad(config.sun_distance_au),
                                      config.shadow_diffuse_fraction)
    profile = scale_angular_rates(profile, off_nominal.angular_rate_multiplier, camera.timing.exposure_mid_time_s(start_s))

    started = time.perf_counter()
    binned = config.effects.binned_render and camera.binning_rows > 1
    render_camera = binned_render_camera(camera) if binned else camera
    for used in (camera, render_camera):      # their rays by the compiled pass, same bits (a no-op once they have them)
        unproject_compiled.prime_pixel_rays(used)
    periods = period_fields(terrain, render_camera, profile, start_s, sun, config,
                            need_smear_fields=camera_effects.smear, moving_shadows=moving)
    heat_shield_visible = bool(periods.heat_shield.any())     # (on the binned render's block mask: 1/b the pass)
    if binned:     # the masks of the full frame: each block's rows share its ray
        b = camera.binning_rows
        periods = replace(periods, sky=_full_frame_mask(periods.sky, b), outside=_full_frame_mask(periods.outside, b),
                          heat_shield=_full_frame_mask(periods.heat_shield, b))
    scene_ms = 1e3 * (time.perf_counter() - started)

    started = time.perf_counter()
    rendered = render_image(camera, periods.fields, rng, camera_effects, artefacts)
    camera_ms = 1e3 * (time.perf_counter() - started)

    cam = periods.exposure_centre.camera_pose
    anti_sun = shadow.shadow_centre_m(cam.ray_origin_m, sun) if cam.ray_origin_m[2] > 0 else cam.ray_origin_m
    pixel, in_front = ground_mapping.world_to_pixels(camera, cam, anti_sun)
    in_image = bool(in_front) and (-0.5 <= pixel[0] <= camera.width_px - 0.5) and (-0.5 <= pixel[1] <= camera.height_px - 0.5)
    footprint, hit = ground_mapping.footprint_m(camera, cam)
    diagnostics = SceneDiagnostics(
        exposure_start_s=start_s, pose=profile.pose(float(np.clip(start_s, profile.time_s[0], profile.time_s[-1]))),
        camera_pose=cam, substeps=periods.substeps, shared_fields=periods.shared, anti_sun_ground_m=anti_sun,
        anti_sun_pixel=pixel if in_image else None, shadow_centres_m=periods.exposure_centre.shadow_centres_m,
        footprint_m=footprint, footprint_hit=hit, heat_shield_visible=heat_shield_visible,
        scene_ms=scene_ms, camera_ms=camera_ms,
    )
    return DescentImage(rendered, periods.fields, periods.sky, periods.outside, periods.heat_shield, diagnostics)


def binned_render_camera(camera: Camera) -> Camera:
    """The camera whose pixel (c, k) is the centre of ``camera``'s binning block k in column c (cached).

    Row ``r'`` of it sees what ``camera``'s row ``b r' + (b - 1) / 2`` sees: CAHVOR
    ``V' = (V - (b - 1) / 2 A) / b`` over ``height / b`` rows, no binning. Rendering the scene with it
    (the ``binned_render`` shortcut) gives each period's field per binning block: one ray per block,
    and the pixel-area filter's second-order term (``simulator.scene.radiance.pixel_area_average``) in
    the block's own units, so a field smooth at the pixel scale comes out as its block means.

    Parameters
    ----------
    camera : Camera
        The descent camera.

    Returns
    -------
    Camera
        The block-centre camera (``height / b`` rows, binning 1; the same C, A, H, O, R, mounting,
        timing and radiometry).
    """
    cache = DERIVED.of(camera, "scene")
    if "binned_render_camera" not in cache:
        b = camera.binning_rows
        model = camera.model
        detector = camera.detector.model_copy(update={"height_px": camera.height_px // b, "binning_rows": 1})
        cache["binned_render_camera"] = replace(camera, detector=detector,
                                                model=replace(model, v=(model.v - 0.5 * (b - 1) * model.a) / b))
    return cache["binned_render_camera"]


def _full_frame_mask(block_mask: np.ndarray, binning_rows: int) -> np.ndarray:
    """A per-block mask (H / b, W) as the full frame's (H, W): each block's rows take its value.

    A fresh zero array with only the span of block rows holding a True value written (the sky,
    outside-terrain and heat-shield masks are usually empty or a few rows; np.repeat's writes of the whole
    frame cost ~0.17 ms a mask, mostly page faults).
    """
    block_rows = np.flatnonzero(block_mask.any(axis=1))
    full = np.zeros((block_mask.shape[0] * binning_rows, block_mask.shape[1]), dtype=bool)
    if block_rows.size:
        first, last = int(block_rows[0]), int(block_rows[-1]) + 1
        full[first * binning_rows:last * binning_rows] = np.repeat(block_mask[first:last], binning_rows, axis=0)
    return full


def _camera_artefacts(off_nominal: OffNominalConfig, artefacts: OffNominalArtefacts | None) -> OffNominalArtefacts | None:
    """The artefacts the camera chain applies: the given ones with the configured blooming switch."""
    if artefacts is None:
        if off_nominal.needs_case_artefacts:
            raise ValueError("scene.off_nominal asks for dust, hot pixels, particle hits or moving shadows but no "
                             "artefacts were given; draw them with simulator.off_nominal.draw_case_artefacts (once "
                             "per case) and with_particle_hits (per image)")
        return None if off_nominal.blooming else OffNominalArtefacts(blooming=False)
    return artefacts if artefacts.blooming == off_nominal.blooming else replace(artefacts, blooming=off_nominal.blooming)
