"""The jettisoned heat shield seen from above: a 5.3 m, 140 deg cone lined with black Kapton.

Geometry (paper 3.2): a right circular cone of rim diameter ``diameter_m`` (5.3 m) and full cone angle
``cone_angle_rad`` (140 deg, half-angle 70 deg, so the cone is ``h = R / tan(70 deg) = 0.965 m`` deep).
After separation the heat shield falls nose first, so we place the apex *down* and the axis vertical;
``heat_shield_position_m`` of the profile is the centre of the cone's bounding cylinder (half-way
between apex and rim plane). Seen from the lander, 140-200 m above, the camera looks into the concave
interior, lined with carbon-loaded black Kapton.

Shading: Lambertian with hemispherical reflectance ``reflectance`` (0.07 for carbon-loaded black
Kapton, solar absorptance ~0.93), ``L = reflectance * E_band / pi * max(0, n.s)`` with ``n`` the surface
normal on the side the camera sees; the rim's cast shadow on the interior (only for sun elevations
below the 20 deg wall slope) and specular glints are not modelled.

Cost: the cone is projected into the image first; only when that footprint meets the field of view are
the rays of its bounding box intersected with the cone (:func:`draw_heat_shield`).
"""
from __future__ import annotations

import numpy as np

from . import ground_mapping
from .camera_config import Camera


def cone_depth_m(diameter_m: float, cone_angle_rad: float) -> float:
    """Apex-to-rim depth of the cone (m)."""
    return 0.5 * diameter_m / np.tan(0.5 * cone_angle_rad)


def cone_outline_m(centre_m: np.ndarray, diameter_m: float, cone_angle_rad: float, count: int = 32) -> np.ndarray:
    """World points of the rim circle and the apex, (count + 1, 3)."""
    depth = cone_depth_m(diameter_m, cone_angle_rad)
    angles = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    rim = np.stack([0.5 * diameter_m * np.cos(angles), 0.5 * diameter_m * np.sin(angles),
                    np.full_like(angles, 0.5 * depth)], axis=-1)
    apex = np.array([[0.0, 0.0, -0.5 * depth]])
    return np.asarray(centre_m, dtype=float) + np.vstack([rim, apex])


def intersect_cone(origin_m: np.ndarray, rays: np.ndarray, apex_m: np.ndarray, axis: np.ndarray,
                   cos_half_angle: float, depth_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of rays ``origin + t d`` (t > 0) with the finite cone surface.

    Parameters
    ----------
    rays : (..., 3) directions (any length)
    apex_m, axis : cone apex and unit axis (from the apex toward the opening)
    cos_half_angle : cosine of the half-angle; depth_m : apex-to-rim distance along the axis

    Returns
    -------
    t : (...) ray parameter of the hit (inf where none); hit : (...) bool
    """
    w = np.asarray(origin_m, dtype=float) - apex_m
    c2 = cos_half_angle**2
    du = rays @ axis
    wu = float(w @ axis)
    a = du * du - c2 * np.einsum("...i,...i->...", rays, rays)
    b = 2.0 * (du * wu - c2 * (rays @ w))
    c = wu * wu - c2 * float(w @ w)
    disc = b * b - 4 * a * c
    ok = disc >= 0
    root = np.sqrt(np.where(ok, disc, 0.0))
    safe_a = np.where(np.abs(a) > 1e-300, a, 1e-300)
    best = np.full(np.shape(a), np.inf)
    for t in ((-b - root) / (2 * safe_a), (-b + root) / (2 * safe_a)):
        height = wu + t * du
        valid = ok & (t > 0) & (height >= 0) & (height <= depth_m)
        best = np.where(valid & (t < best), t, best)
    return best, np.isfinite(best)


def draw_heat_shield(radiance: np.ndarray, ground_map: ground_mapping.GroundMap, camera: Camera,
                     pose: ground_mapping.CameraPose, centre_m: np.ndarray, sun_world: np.ndarray,
                     irradiance_w_m2_um: float, diameter_m: float, cone_angle_rad: float,
                     reflectance: float) -> np.ndarray | None:
    """Paint the heat shield into ``radiance`` (H, W) in place where it hides the ground or sky.

    Returns the (H, W) bool mask of heat-shield pixels, or None when its footprint misses the image
    (nothing computed beyond the projection of its outline).
    """
    height, width = radiance.shape
    outline = cone_outline_m(centre_m, diameter_m, cone_angle_rad)
    pixels, in_front = ground_mapping.world_to_pixels(camera, pose, outline)
    if not in_front.any():
        return None
    if in_front.all():
        col0 = max(int(np.floor(pixels[:, 0].min())) - 2, 0)
        col1 = min(int(np.ceil(pixels[:, 0].max())) + 3, width)
        row0 = max(int(np.floor(pixels[:, 1].min())) - 2, 0)
        row1 = min(int(np.ceil(pixels[:, 1].max())) + 3, height)
    else:   # the camera is beside or inside the cone's extent: test every pixel
        col0, col1, row0, row1 = 0, width, 0, height
    if col1 <= col0 or row1 <= row0:
        return None
    depth = cone_depth_m(diameter_m, cone_angle_rad)
    axis = np.array([0.0, 0.0, 1.0])
    apex = np.asarray(centre_m, dtype=float) - 0.5 * depth * axis
    cos_half = float(np.cos(0.5 * cone_angle_rad))
    rays = ground_map.rays(row0, row1, col0, col1).astype(np.float64)
    t, hit = intersect_cone(pose.ray_origin_m, rays, apex, axis, cos_half, depth)
    # ground hit parameter: the heat shield shows only if it is nearer than the ground
    dz = rays[..., 2]
    t_ground = np.where(ground_map.sky[row0:row1, col0:col1] | (dz >= 0), np.inf,
                        -pose.ray_origin_m[2] / np.where(dz < 0, dz, -1.0))
    hit &= t < t_ground
    if not hit.any():
        return None
    point = pose.ray_origin_m + np.where(hit, t, 0.0)[..., None] * rays
    relative = point - apex
    normal = (relative @ axis)[..., None] * axis - cos_half**2 * relative   # interior-side normal
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    facing = np.where((np.einsum("...i,...i->...", normal, rays) > 0)[..., None], -normal, normal)
    cos_sun = np.maximum(facing @ sun_world, 0.0)
    value = (reflectance * irradiance_w_m2_um / np.pi) * cos_sun
    window = radiance[row0:row1, col0:col1]
    window[hit] = value[hit].astype(np.float32)
    mask = np.zeros((height, width), dtype=bool)
    mask[row0:row1, col0:col1] = hit
    return mask
