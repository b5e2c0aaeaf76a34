"""Shadows of the lander, backshell and parachute (and heat shield) on the ground, with penumbra.

Each shadow caster is a disc of configured diameter at its world position. A ground point P sees the
solar disc (angular radius ``R_s``, 3.05e-3 rad at 1.524 AU) and the caster's disc (angular radius
``rho = asin(r / |X - P|)``) at angular separation ``theta`` between the sun direction and ``X - P``.
The fraction of the (uniform, no limb darkening) solar disc hidden is the circle-overlap area over
``pi R_s^2`` (:func:`occluded_fraction`). The caster is treated as a disc facing the sun (a sphere's
outline), which ignores the foreshortening of a horizontal canopy by the sun's incidence angle.

Direct sunlight scales by ``1 - occluded``; skylight (dust-scattered, a configured fraction
``diffuse_fraction`` of the total illumination, ~0.3 on Mars at optical depth ~0.5) still reaches the
shadow, so the radiance is multiplied by ``1 - (1 - diffuse_fraction) * occluded``.

The opposition halo is *not* modelled here: it comes from f(alpha) in :mod:`simulator.scene.photometry`,
and the shadows fall at its centre because the casters lie on the sun line through the camera.

Where the casters are (documented defaults, configurable in ``SceneConfig``): the lander disc at the
profile position; the backshell 20 m above the lander along the lander's +z axis (the MER bridle); the
parachute canopy ``parachute_distance_m`` (30 m) above the lander along the same axis, 15 m across.
At 2000 m a 15 m canopy subtends 7.5e-3 rad, barely more than the sun's 6.1e-3 rad, so its shadow is
a 2.7 m umbra inside a 27 m penumbra; the lander's shadow is a shallow partial eclipse.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flight_interface.camera import Camera
from simulator.scene import ground_mapping


@dataclass(frozen=True)
class Caster:
    """A shadow-casting disc.

    Attributes
    ----------
    name : str
        What casts the shadow (``"lander"``, ``"backshell"``, ``"parachute"``, ``"heat_shield"``).
    centre_m : ndarray, shape (3,)
        World centre (m).
    radius_m : float
        Radius (m).
    """

    name: str
    centre_m: np.ndarray
    radius_m: float


def shadow_centre_m(centre_m: np.ndarray, sun_world: np.ndarray) -> np.ndarray:
    """Where the sun line through a point meets the ground (z = 0).

    Parameters
    ----------
    centre_m : ndarray, shape (3,)
        World point (m).
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.

    Returns
    -------
    ndarray, shape (3,)
        Ground point (m).
    """
    return centre_m - (centre_m[2] / sun_world[2]) * sun_world


def circle_overlap_fraction(sun_radius: float | np.ndarray, caster_radius: np.ndarray, separation: np.ndarray) -> np.ndarray:
    """Fraction of a circle covered by another circle (broadcasting).

    Parameters
    ----------
    sun_radius : float or ndarray
        Radius of the covered circle.
    caster_radius : ndarray
        Radius of the covering circle (same angular unit).
    separation : ndarray
        Distance between their centres (same unit).

    Returns
    -------
    ndarray, float
        Covered fraction, in [0, 1].
    """
    a = np.asarray(sun_radius, dtype=np.float64)
    b = np.asarray(caster_radius, dtype=np.float64)
    d = np.asarray(separation, dtype=np.float64)
    a, b, d = np.broadcast_arrays(a, b, d)
    full = np.pi * np.minimum(a, b) ** 2
    safe_d = np.maximum(d, 1e-300)
    cos_a = np.clip((d * d + a * a - b * b) / (2 * safe_d * a), -1.0, 1.0)
    cos_b = np.clip((d * d + b * b - a * a) / (2 * safe_d * np.maximum(b, 1e-300)), -1.0, 1.0)
    kite = np.maximum((-d + a + b) * (d + a - b) * (d - a + b) * (d + a + b), 0.0)
    lens = a * a * np.arccos(cos_a) + b * b * np.arccos(cos_b) - 0.5 * np.sqrt(kite)
    area = np.where(d >= a + b, 0.0, np.where(d <= np.abs(a - b), full, lens))
    return np.clip(area / (np.pi * a * a), 0.0, 1.0)


def occluded_fraction(points_m: np.ndarray, caster: Caster, sun_world: np.ndarray,
                      sun_radius_rad: float) -> np.ndarray:
    """Fraction of the solar disc hidden by a caster, seen from ground points.

    Parameters
    ----------
    points_m : ndarray, shape (..., 3)
        World ground points (m).
    caster : Caster
        The caster.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    sun_radius_rad : float
        Angular radius of the solar disc (rad).

    Returns
    -------
    ndarray, shape (...), float32
        Hidden fraction, 0 .. 1.
    """
    to_caster = np.asarray(caster.centre_m, dtype=np.float64) - points_m
    distance = np.sqrt(np.einsum("...i,...i->...", to_caster, to_caster))
    along = to_caster @ sun_world
    across = np.sqrt(np.maximum(distance**2 - along**2, 0.0))
    separation = np.arctan2(across, along)
    rho = np.arcsin(np.clip(caster.radius_m / np.maximum(distance, 1e-9), 0.0, 1.0))
    fraction = circle_overlap_fraction(sun_radius_rad, rho, separation)
    return np.where(along > 0, fraction, 0.0).astype(np.float32)


def apply_shadows(radiance: np.ndarray, ground_map: ground_mapping.GroundMap, camera: Camera,
                  pose: ground_mapping.CameraPose, casters: list[Caster], sun_world: np.ndarray,
                  sun_radius_rad: float, diffuse_fraction: float,
                  view_bounds_m: tuple[float, float, float, float] | None = None,
                  windows: list | None = None, circles: list | None = None) -> list[np.ndarray]:
    """Darken a radiance field in place inside each caster's shadow.

    Only the image window that can hold the penumbra is computed: the ground circle of radius
    ``(r + D tan(R_s)) / cos(i)`` (D the caster's distance to the ground along the sun line, i the
    sun's incidence angle) around the shadow centre is projected into the image and its bounding box,
    padded by 2 pixels, is evaluated exactly. With ``view_bounds_m`` a circle that does not meet those
    ground bounds is not projected at all: every pixel outside the circle has a hidden fraction of
    exactly 0 (factor 1.0), so skipping it changes no bit.

    Parameters
    ----------
    radiance : ndarray, shape (H, W), float32
        Radiance (W m^-2 sr^-1 um^-1); changed in place.
    ground_map : GroundMap
        The pose's ground map.
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    casters : list of Caster
        The casters.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    sun_radius_rad : float
        Angular radius of the solar disc (rad).
    diffuse_fraction : float
        Fraction of the irradiance that is sky light (not shadowed).
    view_bounds_m : (float, float, float, float), optional
        ``(west, east, south, north)`` (m) holding every ground point the image sees
        (:func:`view_bounds_m`); None projects every caster's circle.
    windows : list, optional
        Per caster, the ``(row0, row1, col0, col1)`` window to evaluate or None (nothing in view): this
        camera's :func:`~simulator.scene.ground_mapping.outline_window` of its :func:`penumbra_outlines`
        extent (a supersampling sample's, from its pose's outlines); None projects each circle here.
    circles : list, optional
        Per caster (above the ground) its shadow centre and penumbra radius as :func:`penumbra_outlines`
        gives them for these casters and sun; None computes them here.

    Returns
    -------
    list of ndarray, shape (3,)
        Shadow centres (world, m) of the casters above the ground.
    """
    centres = []
    for index, caster in enumerate(casters):
        if caster.centre_m[2] <= 0:
            continue
        centre, outer = (_penumbra_circle_m(caster, sun_world, sun_radius_rad) if circles is None
                         else circles[index])
        centres.append(centre)
        if view_bounds_m is not None and not _circle_meets_box(centre, outer, view_bounds_m):
            continue
        window = windows[index] if windows is not None else _penumbra_window(camera, pose, centre, outer)
        if window is None:
            continue
        row0, row1, col0, col1 = window
        rays = ground_map.rays(row0, row1, col0, col1).astype(np.float64)
        window_sky = ground_map.sky[row0:row1, col0:col1]
        dz = np.where(window_sky, -1.0, rays[..., 2])
        points = pose.ray_origin_m + (-pose.ray_origin_m[2] / dz)[..., None] * rays
        occluded = occluded_fraction(points, caster, sun_world, sun_radius_rad)
        occluded[window_sky] = 0.0
        radiance[row0:row1, col0:col1] *= 1.0 - np.float32(1.0 - diffuse_fraction) * occluded
    return centres


def _penumbra_circle_m(caster: Caster, sun_world: np.ndarray, sun_radius_rad: float) -> tuple[np.ndarray, float]:
    """A caster's shadow centre on the ground (m) and the radius (m) of the ground circle holding its penumbra."""
    centre = shadow_centre_m(caster.centre_m, sun_world)
    reach = float(np.linalg.norm(caster.centre_m - centre))
    # penumbra radius across the sun line, stretched by 1/cos(incidence) along it on the ground
    return centre, (caster.radius_m + reach * np.tan(sun_radius_rad)) / sun_world[2] + 1.0


def _penumbra_outline(camera: Camera, pose: ground_mapping.CameraPose, centre_m: np.ndarray,
                      radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A ground circle's 24 ring points and centre projected: ``(pixels (25, 2), in_front (25,))``."""
    angles = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    ring = centre_m + radius_m * np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=-1)
    return ground_mapping.world_to_pixels(camera, pose, np.vstack([ring, centre_m]))


def _penumbra_window(camera: Camera, pose: ground_mapping.CameraPose, centre_m: np.ndarray,
                     radius_m: float) -> tuple[int, int, int, int] | None:
    """The frame window of a ground circle (:func:`~simulator.scene.ground_mapping.outline_window`)."""
    extent = ground_mapping.outline_extent(*_penumbra_outline(camera, pose, centre_m, radius_m))
    return ground_mapping.outline_window(extent, 0.0, 0.0, camera.width_px, camera.height_px)


def penumbra_outlines(camera: Camera, pose: ground_mapping.CameraPose, casters: list[Caster], sun_world: np.ndarray,
                      sun_radius_rad: float) -> list:
    """Per caster, its projected penumbra outline, once for a pose's supersampling samples.

    A sample's camera (:func:`simulator.scene.radiance.subpixel_camera`, offset ``(dc, dr)``) sees a world
    point at ``camera``'s pixel minus the offset, so
    :func:`~simulator.scene.ground_mapping.outline_window` of the extent and ``(dc, dr)`` is that sample's
    own window (the projection of :func:`apply_shadows`, up to the rounding of the projection).

    Parameters
    ----------
    camera : Camera
        The unshifted camera.
    pose : CameraPose
        The camera's world pose.
    casters : list of Caster
        The casters.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    sun_radius_rad : float
        Angular radius of the solar disc (rad).

    Returns
    -------
    list of tuple or None
        Per caster ``(shadow centre (3,) m, penumbra circle radius m, extent)``, the extent the
        :func:`~simulator.scene.ground_mapping.outline_extent` of the projected circle; None for a caster
        at or below the ground.
    """
    outlines: list = []
    for caster in casters:
        if caster.centre_m[2] <= 0:
            outlines.append(None)
            continue
        centre, outer = _penumbra_circle_m(caster, sun_world, sun_radius_rad)
        outlines.append((centre, outer, ground_mapping.outline_extent(*_penumbra_outline(camera, pose, centre, outer))))
    return outlines


VIEW_BOUNDS_MARGIN = 0.05      # of the footprint's extent, on each side: the border between its samples


def view_bounds_m(footprint_m: np.ndarray, hit: np.ndarray) -> tuple[float, float, float, float] | None:
    """Ground bounds holding every point an image sees, from its border footprint.

    The bounding box of the border's ground points (:func:`simulator.scene.ground_mapping.footprint_m`),
    widened by :data:`VIEW_BOUNDS_MARGIN` of its extent on each side for the border between the samples.
    The ground seen by a camera above level ground is the convex-ish region inside its border's image
    (a line of sight through an inner pixel meets the ground between those of the border), so the box
    holds it.

    Parameters
    ----------
    footprint_m : ndarray, shape (n, 2)
        East, north of the border points on the ground (m).
    hit : ndarray, shape (n,), bool
        Whether each border ray meets the ground.

    Returns
    -------
    tuple of float or None
        ``(west, east, south, north)`` (m); None when part of the border sees the sky (unbounded view).
    """
    if not hit.all():
        return None
    west, south = footprint_m.min(axis=0)
    east, north = footprint_m.max(axis=0)
    margin = VIEW_BOUNDS_MARGIN * max(east - west, north - south)
    return float(west - margin), float(east + margin), float(south - margin), float(north + margin)


def _circle_meets_box(centre_m: np.ndarray, radius_m: float, bounds_m: tuple[float, float, float, float]) -> bool:
    """Whether a ground circle meets a (west, east, south, north) box (distance to the box <= radius)."""
    west, east, south, north = bounds_m
    dx = max(west - centre_m[0], 0.0, centre_m[0] - east)
    dy = max(south - centre_m[1], 0.0, centre_m[1] - north)
    return dx * dx + dy * dy <= radius_m * radius_m
