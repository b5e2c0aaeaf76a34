"""Smear fields by warping (fidelity shortcut ``warp_smear_fields``).

The fast-flush and frame-transfer radiance of a sub-pose, read from the exposure-centre field along the
ground-plane flow.

The fast-flush and frame-transfer fields only enter the image through block sums of columns (smear,
then 4-row binning), and their poses differ from the exposure's by a pixel or so. Instead of rendering
them, :func:`~simulator.scene.resample.warped_field` resamples the block means of the exposure-centre
field (shape (H / b, W)) along the exact ground-plane flow between the two poses (ground point of each
block centre at the smear pose, projected with the exposure pose), computed on a node grid every
:data:`WARP_GRID_STEP_PX` pixels and interpolated (:func:`flow_map`); the camera chain takes such
block-mean fields directly (:func:`simulator.detector.camera_chain.render_image`). When any node's ray
misses the ground or leaves the exposure image (horizon in view, violent motion) the field is rendered
exactly instead. Measured error: ``make bench`` (fidelity table).
"""
from __future__ import annotations

import numpy as np

from flight_interface.camera import Camera
from simulator.fields import block_means
from simulator.scene import ground_mapping, node_grid, resample
from simulator.scene.descent_profile import Pose
from simulator.scene.radiance import PoseField, radiance_at_pose
from simulator.scene.terrain import Terrain

WARP_GRID_STEP_PX = 32


def flow_map(camera: Camera, source: ground_mapping.CameraPose, target: ground_mapping.CameraPose,
             step_px: int = WARP_GRID_STEP_PX, block_rows: int = 1,
             scratch_name: str | None = None) -> np.ndarray | None:
    """Where each pixel of an image taken at ``target`` finds its ground point in an image taken at ``source``.

    Parameters
    ----------
    camera : Camera
        The camera of both images.
    source, target : CameraPose
        World poses of the camera for the image read from and the image made.
    step_px : int, optional
        Node grid step (px) on which the flow is computed exactly before bilinear interpolation.
    block_rows : int, optional
        With ``b > 1`` the map is for blocks of ``b`` rows (row k centred on pixel row
        ``b k + (b - 1) / 2``) and gives source coordinates in the same block units.
    scratch_name : str, optional
        Write the map into that :func:`~simulator.scratch.scratch` array (use it before the next call).

    Returns
    -------
    ndarray, shape (height / b, width, 2), float32, or None
        (column, row) source coordinates, bilinear from the node grid; None when a node's ray misses
        the ground or its point is behind or more than one node step outside the source frame (the
        flow is then not a small smooth warp).
    """
    rows = node_grid.node_positions(camera.height_px, step_px)
    cols = node_grid.node_positions(camera.width_px, step_px)
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
        return node_grid.upsample_nodes(source_pixels, step_px, camera.height_px, camera.width_px,
                                             scratch_name=scratch_name)
    # node rows (k + 1/2) s - 1/2 in pixels are (k + 1/2) (s / b) - 1/2 in blocks: the same layout
    source_pixels[..., 1] = (source_pixels[..., 1] - 0.5 * (block_rows - 1)) / block_rows
    return node_grid.upsample_nodes(source_pixels, step_px, camera.height_px // block_rows, camera.width_px,
                                         row_step_px=step_px // block_rows, scratch_name=scratch_name)


def smear_field(terrain: Terrain, camera: Camera, pose: Pose, sun_world: np.ndarray, config, centre: PoseField,
                centre_blocks: np.ndarray, moving_shadows=None) -> np.ndarray:
    """The radiance field at ``pose`` for smear, per binning block.

    Warped from the exposure-centre field's block means when the flow allows (:func:`flow_map`), else
    the block means of the field rendered exactly.

    Parameters
    ----------
    terrain : Terrain
        The orbital terrain (rendered from only when the warp is not possible).
    camera : Camera
        The descent camera.
    pose : Pose
        Lander pose of the smear sub-pose.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    config : simulator.scene_config.SceneConfig
        Scene configuration.
    centre : PoseField
        The field rendered at the exposure mid-time.
    centre_blocks : ndarray, shape (H / b, W), float32
        Block means of ``centre.radiance`` (W m^-2 sr^-1 um^-1).
    moving_shadows : simulator.off_nominal.moving_shadows.MovingShadows, optional
        Dust-devil and cloud shadows (as :func:`~simulator.scene.radiance.radiance_at_pose`).

    Returns
    -------
    ndarray, shape (H / b, W), float32
        Mean radiance of each binning block (W m^-2 sr^-1 um^-1).
    """
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
