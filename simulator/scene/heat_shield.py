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
below the 20 deg wall slope) is not modelled.

The lining's specular glint (off-nominal) is :mod:`simulator.scene.glint`.

Cost: the cone is projected into the image first; only when that footprint meets the field of view are
the rays of its bounding box intersected with the cone (:func:`draw_heat_shield`).
"""
from __future__ import annotations

import numpy as np

from flight_interface.camera import Camera
from simulator.scene import ground_mapping, unproject_compiled


def cone_depth_m(diameter_m: float, cone_angle_rad: float) -> float:
    """Apex-to-rim depth of the cone.

    Parameters
    ----------
    diameter_m : float
        Rim diameter (m).
    cone_angle_rad : float
        Full cone angle (rad).

    Returns
    -------
    float
        Depth (m).
    """
    return 0.5 * diameter_m / np.tan(0.5 * cone_angle_rad)


def cone_outline_m(centre_m: np.ndarray, diameter_m: float, cone_angle_rad: float, count: int = 32) -> np.ndarray:
    """World points of the rim circle and the apex.

    Parameters
    ----------
    centre_m : ndarray, shape (3,)
        Centre of the cone's bounding cylinder (m).
    diameter_m : float
        Rim diameter (m).
    cone_angle_rad : float
        Full cone angle (rad).
    count : int, optional
        Points on the rim.

    Returns
    -------
    ndarray, shape (count + 1, 3)
        Rim points then the apex (m).
    """
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
    origin_m : ndarray, shape (3,)
        Ray origin (m).
    rays : ndarray, shape (..., 3)
        Directions (any length).
    apex_m : ndarray, shape (3,)
        Cone apex (m).
    axis : ndarray, shape (3,)
        Unit axis, from the apex toward the opening.
    cos_half_angle : float
        Cosine of the half-angle.
    depth_m : float
        Apex-to-rim distance along the axis (m).

    Returns
    -------
    t : ndarray, shape (...)
        Ray parameter of the hit (inf where none).
    hit : ndarray, shape (...), bool
        Whether the ray hits.
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


def bounding_box(camera: Camera, pose: ground_mapping.CameraPose, centre_m: np.ndarray, diameter_m: float,
                 cone_angle_rad: float) -> tuple[int, int, int, int] | None:
    """Image window that can hold the heat shield: its outline (:func:`cone_outline_m`) projected.

    The outline's :func:`~simulator.scene.ground_mapping.pixel_window`; the whole frame when the camera is
    beside or inside the cone's extent (part of the outline behind it). A supersampling sample's box is
    :func:`~simulator.scene.ground_mapping.outline_window` of its pose's outline extent and its offset.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    centre_m : ndarray, shape (3,)
        Centre of the cone's bounding cylinder (m).
    diameter_m : float
        Rim diameter (m).
    cone_angle_rad : float
        Full cone angle (rad).

    Returns
    -------
    tuple of int or None
        ``(row0, row1, col0, col1)``, or None when the cone misses the image.
    """
    pixels, in_front = ground_mapping.world_to_pixels(camera, pose, cone_outline_m(centre_m, diameter_m,
                                                                                   cone_angle_rad))
    return ground_mapping.outline_window(ground_mapping.outline_extent(pixels, in_front), 0.0, 0.0,
                                         camera.width_px, camera.height_px)


def visible_surface(rays: np.ndarray, pose: ground_mapping.CameraPose, sky: np.ndarray, centre_m: np.ndarray,
                     diameter_m: float, cone_angle_rad: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Where rays see the heat-shield cone nearer than the ground.

    Parameters
    ----------
    rays : ndarray, shape (h, w, 3)
        World ray directions from the camera (any length).
    pose : CameraPose
        The camera's world pose (ray origin).
    sky : ndarray, shape (h, w), bool
        Rays that see no ground.
    centre_m : ndarray, shape (3,)
        Centre of the cone's bounding cylinder (m).
    diameter_m : float
        Rim diameter (m).
    cone_angle_rad : float
        Full cone angle (rad).

    Returns
    -------
    tuple of (ndarray, ndarray) or None
        ``hit`` (h, w) bool and the facing unit normal (h, w, 3) on the camera's side of the surface,
        or None when no ray sees the cone.
    """
    depth = cone_depth_m(diameter_m, cone_angle_rad)
    axis = np.array([0.0, 0.0, 1.0])
    apex = np.asarray(centre_m, dtype=float) - 0.5 * depth * axis
    cos_half = float(np.cos(0.5 * cone_angle_rad))
    t, hit = intersect_cone(pose.ray_origin_m, rays, apex, axis, cos_half, depth)
    # ground hit parameter: the heat shield shows only if it is nearer than the ground
    dz = rays[..., 2]
    t_ground = np.where(sky | (dz >= 0), np.inf, -pose.ray_origin_m[2] / np.where(dz < 0, dz, -1.0))
    hit &= t < t_ground
    if not hit.any():
        return None
    point = pose.ray_origin_m + np.where(hit, t, 0.0)[..., None] * rays
    relative = point - apex
    normal = (relative @ axis)[..., None] * axis - cos_half**2 * relative   # interior-side normal
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    facing = np.where((np.einsum("...i,...i->...", normal, rays) > 0)[..., None], -normal, normal)
    return hit, facing


def draw_heat_shield(radiance: np.ndarray, ground_map: ground_mapping.GroundMap, camera: Camera,
                     pose: ground_mapping.CameraPose, centre_m: np.ndarray, sun_world: np.ndarray,
                     irradiance_w_m2_um: float, diameter_m: float, cone_angle_rad: float,
                     reflectance: float, edge_samples: int = 1,
                     box: tuple[int, int, int, int] | None = None,
                     interpolated_edge_rays: bool = False) -> np.ndarray | None:
    """Paint the heat shield into a radiance field in place where it hides the ground or sky.

    ``edge_samples = s > 1`` antialiases the silhouette: pixels on its edge (centre sample differs from
    one of its 8 neighbours) are re-sampled with ``s x s`` sub-pixel rays and read
    ``coverage * shield + (1 - coverage) * background``, the pixel-area mean of a sharp edge. The
    sub-pixel rays are the camera model's (CAHVOR unprojection), or with ``interpolated_edge_rays`` (the
    fast preset's shortcut) the ground map's pixel rays moved to first order (:func:`edge_rays`).

    Parameters
    ----------
    radiance : ndarray, shape (H, W), float32
        Radiance (W m^-2 sr^-1 um^-1); changed in place.
    ground_map : GroundMap
        The pose's ground map (sky mask).
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
        Hemispherical reflectance of the lining.
    edge_samples : int, optional
        Sub-pixel rays per axis on the silhouette.
    box : (int, int, int, int), optional
        This camera's :func:`bounding_box` when already known (a supersampling sample's, from its pose's
        outline: :func:`~simulator.scene.ground_mapping.outline_window`); None computes it here.
    interpolated_edge_rays : bool, optional
        Take the edge's sub-pixel rays from the ground map's rays (:func:`edge_rays`) instead of
        unprojecting each.

    Returns
    -------
    ndarray, shape (H, W), bool, or None
        Heat-shield pixels (centre samples), or None when its footprint misses the image (nothing
        computed beyond the projection of its outline).
    """
    height, width = radiance.shape
    if box is None:
        box = bounding_box(camera, pose, centre_m, diameter_m, cone_angle_rad)
    if box is None:
        return None
    row0, row1, col0, col1 = box
    rays = ground_map.rays(row0, row1, col0, col1).astype(np.float64)
    surface = visible_surface(rays, pose, ground_map.sky[row0:row1, col0:col1], centre_m, diameter_m,
                               cone_angle_rad)
    if surface is None:
        return None
    hit, facing = surface
    lambert_scale = reflectance * irradiance_w_m2_um / np.pi
    value = lambert_radiance(facing, sun_world, lambert_scale)
    window = radiance[row0:row1, col0:col1]
    edge_blend = (_edge_blend(camera, pose, hit, window, ground_map.sky[row0:row1, col0:col1], row0, col0,
                              centre_m, diameter_m, cone_angle_rad, sun_world,
                              lambert_scale, edge_samples, ground_map if interpolated_edge_rays else None)
                  if edge_samples > 1 else None)
    window[hit] = value[hit].astype(np.float32)
    if edge_blend is not None:
        edge_rows, edge_cols, blended = edge_blend
        window[edge_rows, edge_cols] = blended
    mask = np.zeros((height, width), dtype=bool)
    mask[row0:row1, col0:col1] = hit
    return mask


def lambert_radiance(normal: np.ndarray, sun_world: np.ndarray, scale_w_m2_sr_um: float) -> np.ndarray:
    """Radiance of the Lambertian Kapton surface: ``scale * max(n . s, 0)`` with ``scale = rho E / pi``.

    Parameters
    ----------
    normal : ndarray, shape (..., 3)
        Unit surface normals.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    scale_w_m2_sr_um : float
        ``rho E / pi`` (W m^-2 sr^-1 um^-1).

    Returns
    -------
    ndarray, shape (...)
        Radiance (W m^-2 sr^-1 um^-1).
    """
    return scale_w_m2_sr_um * np.maximum(normal @ sun_world, 0.0)


def edge_rays(ground_map: ground_mapping.GroundMap, rows: np.ndarray, cols: np.ndarray, row_offsets: np.ndarray,
              col_offsets: np.ndarray) -> np.ndarray:
    """World rays at sub-pixel offsets from pixels, moved to first order from the ground map's pixel rays.

    ``ray(r + dr, c + dc) = ray(r, c) + dr d ray / d row + dc d ray / d col``, the derivatives central
    differences of the neighbouring pixels' rays (one-sided on the frame's border). On a coarse ray map
    (rays bilinear between its nodes) this is the map's own ray inside a node cell; on an exact map it
    errs by the second-order change of the camera model over the offset (~1e-7 rad for a third of a pixel).

    Parameters
    ----------
    ground_map : GroundMap
        The pose's ground map (its rays).
    rows, cols : ndarray, shape (n,), int
        Frame pixels.
    row_offsets, col_offsets : ndarray, shape (m,)
        Sub-pixel offsets (px), within half a pixel.

    Returns
    -------
    ndarray, shape (n, m, 3), float64
        World ray directions (the map's length, ~unit).
    """
    height, width = ground_map.col.shape
    row0, row1 = max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, height)
    col0, col1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, width)
    window = ground_map.rays(row0, row1, col0, col1).astype(np.float64)
    if window.shape[0] < 2 or window.shape[1] < 2:      # a one-pixel frame side: no difference to take
        raise ValueError(f"edge rays: a {window.shape[:2]} ray window has no neighbours to differentiate")
    per_row, per_col = (np.asarray(change) for change in np.gradient(window, axis=(0, 1)))
    local_rows, local_cols = rows - row0, cols - col0
    return (window[local_rows, local_cols][:, None, :]
            + np.asarray(row_offsets, dtype=float)[None, :, None] * per_row[local_rows, local_cols][:, None, :]
            + np.asarray(col_offsets, dtype=float)[None, :, None] * per_col[local_rows, local_cols][:, None, :])


def _edge_blend(camera: Camera, pose: ground_mapping.CameraPose, hit: np.ndarray, background: np.ndarray,
                sky: np.ndarray, row0: int, col0: int, centre_m: np.ndarray, diameter_m: float,
                cone_angle_rad: float, sun_world: np.ndarray, lambert_scale: float, samples: int,
                ground_map: ground_mapping.GroundMap | None = None):
    """Pixel-area radiance of the silhouette's edge pixels (see :func:`draw_heat_shield`).

    ``(rows, cols, radiance float32)`` in window coordinates, or None when there is no edge. With
    ``ground_map`` the sub-pixel rays come from its rays (:func:`edge_rays`), else from the camera model.
    """
    padded = np.pad(hit, 1, mode="edge")   # 8-neighbourhood: corner-covered pixels count too
    edge = np.zeros_like(hit)
    for shift_row in (0, 1, 2):
        for shift_col in (0, 1, 2):
            edge |= padded[shift_row:shift_row + hit.shape[0], shift_col:shift_col + hit.shape[1]] != hit
    rows, cols = np.nonzero(edge)
    if rows.size == 0:
        return None
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    d_col, d_row = (axis.ravel() for axis in np.meshgrid(offsets, offsets))
    if ground_map is not None:
        rays = edge_rays(ground_map, row0 + rows, col0 + cols, d_row, d_col).reshape(-1, 3)
    else:
        pixels = np.stack([(col0 + cols)[:, None] + d_col, (row0 + rows)[:, None] + d_row], axis=-1)
        # compiled: cahvor.unproject's bits (simulator.scene.unproject_compiled), without numpy's Newton passes
        # over every sub-pixel sample (1.1 of the 3.4 ms the edge took per case)
        rays = unproject_compiled.unproject(camera.model, pixels.reshape(-1, 2)) @ pose.camera_to_world.T
    surface = visible_surface(rays[:, None, :], pose, np.repeat(sky[rows, cols], samples * samples)[:, None],
                               centre_m, diameter_m, cone_angle_rad)
    if surface is None:
        sub_hit = np.zeros((rows.size, samples * samples), dtype=bool)
        shield = np.zeros_like(sub_hit, dtype=float)
    else:
        sub_hit = surface[0][:, 0].reshape(rows.size, -1)
        shield = lambert_radiance(surface[1][:, 0], sun_world, lambert_scale).reshape(rows.size, -1)
    coverage = sub_hit.mean(axis=1)
    shield_mean = np.where(sub_hit, shield, 0.0).sum(axis=1) / np.maximum(sub_hit.sum(axis=1), 1)
    blended = coverage * shield_mean + (1.0 - coverage) * background[rows, cols]
    return rows, cols, blended.astype(np.float32)
