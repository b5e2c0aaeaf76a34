"""The coarse node grid: values computed every ``step`` pixels and interpolated bilinearly to every pixel.

Node ``k`` along an axis sits at pixel ``(k + 0.5) step - 0.5`` for k = -1 .. size/step, one node beyond
each edge: the layout that ``cv2.resize`` upsamples by ``step`` (:func:`upsample_nodes`), so a field
that varies slowly across the frame (camera rays, photometric ratio, flow maps, dust transmission) is
computed at a few hundred nodes instead of a million pixels. :func:`interpolate_nodes_window` gives the
same interpolation on a pixel window only.

The compiled passes that fuse the interpolation with the step that uses it live in
:mod:`simulator.scene.node_grid_fused` (numba: loaded by rendering, not with the configuration).
"""
from __future__ import annotations

import cv2
import numpy as np

from simulator.scratch import scratch


def node_positions(size_px: int, step_px: int) -> np.ndarray:
    """Pixel coordinates of the coarse grid nodes along one axis.

    ``(k + 0.5) step - 0.5`` for k = -1 .. size/step: one node beyond each edge, the layout that
    ``cv2.resize`` upsamples.

    Parameters
    ----------
    size_px : int
        Image size along the axis (px).
    step_px : int
        Node spacing (px), >= 1, divides ``size_px``.

    Returns
    -------
    ndarray, shape (size / step + 2,)
        Node coordinates (px).

    Raises
    ------
    ValueError
        A step that is < 1 or does not divide the size.
    """
    if step_px < 1 or size_px % step_px:
        raise ValueError(f"grid step {step_px} px must be >= 1 and divide the image size {size_px} px")
    return (np.arange(-1, size_px // step_px + 1) + 0.5) * step_px - 0.5


def upsample_nodes(node_values: np.ndarray, step_px: int, height_px: int, width_px: int,
                   row_step_px: int | None = None, scratch_name: str | None = None) -> np.ndarray:
    """Bilinear interpolation of values on the :func:`node_positions` grid to every pixel.

    Parameters
    ----------
    node_values : ndarray, shape (ny, nx) or (ny, nx, channels)
        Values at the nodes, ny = height / row_step + 2, nx = width / step + 2.
    step_px : int
        Column node spacing (px).
    height_px, width_px : int
        Size of the output (px).
    row_step_px : int, optional
        Row node spacing (default ``step_px``; a different one serves a grid of coarser rows, e.g. binned
        rows, with the same node layout in its own units).
    scratch_name : str, optional
        Write into that :func:`~simulator.scratch.scratch` array (the caller must be done with it
        before the name is used again).

    Returns
    -------
    ndarray, shape (height, width[, channels]), float32
        Interpolated values (a view of the scratch array with ``scratch_name``).
    """
    row_step_px = step_px if row_step_px is None else row_step_px
    ny, nx = node_values.shape[:2]
    size = (nx * step_px, ny * row_step_px)
    nodes = np.ascontiguousarray(node_values, dtype=np.float32)
    if scratch_name is None:
        big = cv2.resize(nodes, size, interpolation=cv2.INTER_LINEAR)
    else:
        big = scratch(scratch_name, (size[1], size[0]) + node_values.shape[2:])
        cv2.resize(nodes, size, dst=big, interpolation=cv2.INTER_LINEAR)
    return big[row_step_px:row_step_px + height_px, step_px:step_px + width_px]


def upsample_nodes_contiguous(node_values: np.ndarray, step_px: int, height_px: int, width_px: int) -> np.ndarray:
    """:func:`upsample_nodes` as a new C-contiguous array, without resizing to the grid's full extent.

    The same values: a resize of the inner nodes straight to the (H, W) pixels (the same sample positions,
    ``(p + 0.5) / step - 0.5`` in inner-node units), whose ``step // 2`` outer rows and columns, which also
    weigh the outer nodes, come from resizes of the three outer node rows and columns. Sizes that are no
    multiple of the step take :func:`upsample_nodes` and a copy.

    Parameters
    ----------
    node_values : ndarray, shape (ny, nx)
        Values at the nodes, ``ny = H / step + 2``, ``nx = W / step + 2``.
    step_px : int
        Node spacing (px), rows and columns.
    height_px, width_px : int
        Size H, W of the output (px).

    Returns
    -------
    ndarray, shape (H, W), float32
        Interpolated values.
    """
    step, edge = step_px, step_px // 2
    nodes = np.ascontiguousarray(node_values, dtype=np.float32)
    if height_px % step or width_px % step or not edge:   # the inner nodes would not span the frame at the step
        return np.ascontiguousarray(upsample_nodes(nodes, step, height_px, width_px))
    node_rows, node_cols = nodes.shape
    pixels = cv2.resize(nodes[1:-1, 1:-1], (width_px, height_px), interpolation=cv2.INTER_LINEAR)
    top = cv2.resize(nodes[:3], (node_cols * step, 3 * step), interpolation=cv2.INTER_LINEAR)
    bottom = cv2.resize(nodes[-3:], (node_cols * step, 3 * step), interpolation=cv2.INTER_LINEAR)
    left = cv2.resize(nodes[:, :3], (3 * step, node_rows * step), interpolation=cv2.INTER_LINEAR)
    right = cv2.resize(nodes[:, -3:], (3 * step, node_rows * step), interpolation=cv2.INTER_LINEAR)
    pixels[:edge] = top[step:step + edge, step:step + width_px]
    pixels[-edge:] = bottom[2 * step - edge:2 * step, step:step + width_px]
    pixels[:, :edge] = left[step:step + height_px, step:step + edge]
    pixels[:, -edge:] = right[step:step + height_px, 2 * step - edge:2 * step]
    return pixels


def interpolate_nodes_window(node_values: np.ndarray, step_px: int, row0: int, row1: int, col0: int,
                             col1: int) -> np.ndarray:
    """Bilinear node-grid interpolation (as :func:`upsample_nodes`) of a pixel window only.

    Parameters
    ----------
    node_values : ndarray, shape (ny, nx) or (ny, nx, channels)
        Values at the nodes.
    step_px : int
        Node spacing (px).
    row0, row1, col0, col1 : int
        The window (px).

    Returns
    -------
    ndarray, shape (row1 - row0, col1 - col0[, channels]), float32
        Interpolated values.
    """
    def weights(start, stop, count):
        position = (np.arange(start, stop) + 0.5) / step_px + 0.5    # fractional node index
        index = np.clip(np.floor(position).astype(int), 0, count - 2)
        return index, (position - index)[:, None]
    ny, nx = node_values.shape[:2]
    r, fr = weights(row0, row1, ny)
    c, fc = weights(col0, col1, nx)
    values = np.asarray(node_values, dtype=np.float64)
    fr = fr[..., None] if values.ndim == 3 else fr
    fc = fc[None, ...] if values.ndim == 3 else fc.T
    if r.size == 0 or c.size == 0:
        return np.empty((r.size, c.size) + values.shape[2:], dtype=np.float32)
    # each node row the window reads, interpolated along the window's columns once (not once per pixel row)
    first = int(r[0])
    band = values[first:int(r[-1]) + 2]
    across = band[:, c] * (1 - fc) + band[:, c + 1] * fc
    local = r - first
    return (across[local] * (1 - fr) + across[local + 1] * fr).astype(np.float32)
