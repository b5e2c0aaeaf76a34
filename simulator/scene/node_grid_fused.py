"""Compiled passes that fuse the node grid's interpolation with the step that uses it.

Where a full-frame use of an upsampled field is one more elementwise step (the ground map's
two divisions, the photometric ratio's product with the pixel-area filter), the interpolation is done in
that step's compiled pass (:func:`divided_node_planes`, :func:`area_filtered_times_nodes`) instead of
writing the upsampled frame and reading it back. The passes repeat OpenCV's own float32 arithmetic
(``cv2.resize`` linear: ``fma(S1 - S0, a, S0)`` across then down; ``cv2.sepFilter2D``'s symmetric 3-tap
rows ``fma(S, k0, (L + R) k1)`` and columns ``fma(U + D, k1, S k0)``), so they give its bits; each is
checked against OpenCV once per process and node-grid shape (:func:`fused_passes_match_opencv`), and the
callers use OpenCV's calls where it does not match (another OpenCV build or instruction set).

Kept apart from :mod:`simulator.scene.node_grid` so that the configuration's imports load no numba.
"""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from simulator.scene.node_grid import upsample_nodes
from simulator.scratch import scratch


@intrinsic
def _fma32(typing_context, multiplicand, multiplier, addend):
    """``multiplicand x multiplier + addend`` rounded once to float32 (LLVM's ``fma``: the FMA instruction)."""
    signature = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, sig, args):
        single = ir.FloatType()
        function = builder.module.declare_intrinsic("llvm.fma", [single], ir.FunctionType(single, [single] * 3))
        return builder.call(function, args)
    return signature, codegen


@lru_cache(maxsize=16)
def _resize_coefficients(size_px: int, step_px: int, node_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of an axis: the left node index and the weight of the right one, as ``cv2.resize`` computes them.

    Pixel ``p`` is pixel ``p + step`` of the node grid upsampled by ``step`` (:func:`upsample_nodes`' crop):
    ``f = (p + step + 0.5) / step - 0.5``, index ``floor(f)``, weight ``f - floor(f)`` (float32). Read-only.
    """
    position = (np.arange(step_px, step_px + size_px) + 0.5) / step_px - 0.5
    index = np.floor(position).astype(np.int64)
    if index.min() < 0 or index.max() > node_count - 2:
        raise ValueError(f"{node_count} nodes every {step_px} px do not cover {size_px} px")
    weight = (position - index).astype(np.float32)
    index.setflags(write=False)
    weight.setflags(write=False)
    return index, weight


@njit(cache=True, nogil=True, boundscheck=False)
def _across(nodes, index, weight, out):
    """Each node row interpolated along the pixel columns: ``out[k, c] = fma(S1 - S0, a_c, S0)``."""
    for node_row in range(nodes.shape[0]):
        source, target = nodes[node_row], out[node_row]
        for col in range(index.shape[0]):
            left = source[index[col]]
            target[col] = _fma32(source[index[col] + 1] - left, weight[col], left)


@njit(cache=True, nogil=True, boundscheck=False, error_model="numpy")   # no zero check: vectorised
def _divided_planes_kernel(numerator_col, numerator_row, denominator, row_index, row_weight, col_out, row_out):
    """``col_out = N_c / D`` and ``row_out = N_r / D`` of three across-interpolated node planes.

    Each plane is interpolated down as ``fma(R1 - R0, b_r, R0)``; the divisions are IEEE's (no zero check).
    """
    for row in range(row_index.shape[0]):
        upper, weight = row_index[row], row_weight[row]
        d0, d1 = denominator[upper], denominator[upper + 1]
        c0, c1 = numerator_col[upper], numerator_col[upper + 1]
        r0, r1 = numerator_row[upper], numerator_row[upper + 1]
        col_target, row_target = col_out[row], row_out[row]
        for col in range(col_target.shape[0]):
            divisor = _fma32(d1[col] - d0[col], weight, d0[col])
            col_target[col] = _fma32(c1[col] - c0[col], weight, c0[col]) / divisor
            row_target[col] = _fma32(r1[col] - r0[col], weight, r0[col]) / divisor


def divided_node_planes(numerator_col: np.ndarray, numerator_row: np.ndarray, denominator: np.ndarray, step_px: int,
                        col_out: np.ndarray, row_out: np.ndarray) -> None:
    """``upsample(N_c) / upsample(D)`` and ``upsample(N_r) / upsample(D)`` in one pass (:func:`upsample_nodes`).

    The bits of :func:`upsample_nodes` of each plane then ``cv2.divide`` (where
    :func:`fused_passes_match_opencv`), without the three upsampled frames.

    Parameters
    ----------
    numerator_col, numerator_row, denominator : ndarray, shape (ny, nx)
        Node values (cast to float32 as :func:`upsample_nodes` does).
    step_px : int
        Node spacing (px).
    col_out, row_out : ndarray, shape (height, width), float32
        The two quotients, written.
    """
    height, width = col_out.shape
    ny, nx = denominator.shape
    col_index, col_weight = _resize_coefficients(width, step_px, nx)
    row_index, row_weight = _resize_coefficients(height, step_px, ny)
    planes = []
    for name, nodes in (("col", numerator_col), ("row", numerator_row), ("dz", denominator)):
        across = scratch(f"node_rows_{name}", (ny, width))
        _across(np.ascontiguousarray(nodes, dtype=np.float32), col_index, col_weight, across)
        planes.append(across)
    _divided_planes_kernel(planes[0], planes[1], planes[2], row_index, row_weight, col_out, row_out)


@njit(cache=True, nogil=True, boundscheck=False)
def _area_row(source, k0, k1, out):
    """One row of the symmetric 3-tap row filter, edges replicated: ``fma(S, k0, (L + R) k1)``."""
    last = source.shape[0] - 1
    out[0] = _fma32(source[0], k0, (source[0] + source[1]) * k1)
    for col in range(1, last):
        out[col] = _fma32(source[col], k0, (source[col - 1] + source[col + 1]) * k1)
    out[last] = _fma32(source[last], k0, (source[last - 1] + source[last]) * k1)


@njit(cache=True, nogil=True, boundscheck=False)
def _area_times_nodes_kernel(samples, k0, k1, nodes_across, row_index, row_weight, out):
    """``out = filter(samples) x interpolated nodes`` in one pass.

    Rows are filtered into a three-row ring, columns as ``fma(U + D, k1, S k0)`` (edges replicated), the node
    rows interpolated down; one float32 product.
    """
    rows, cols = samples.shape
    ring = np.empty((3, cols), dtype=np.float32)
    _area_row(samples[0], k0, k1, ring[1])
    _area_row(samples[min(1, rows - 1)], k0, k1, ring[2])
    for col in range(cols):
        ring[0, col] = ring[1, col]
    for row in range(rows):
        above, centre, below = ring[row % 3], ring[(row + 1) % 3], ring[(row + 2) % 3]
        upper, weight = row_index[row], row_weight[row]
        n0, n1 = nodes_across[upper], nodes_across[upper + 1]
        target = out[row]
        for col in range(cols):
            filtered = _fma32(above[col] + below[col], k1, centre[col] * k0)
            target[col] = filtered * _fma32(n1[col] - n0[col], weight, n0[col])
        if row + 1 < rows:       # the ring's oldest row takes the next row's successor (the last row replicated)
            _area_row(samples[min(row + 2, rows - 1)], k0, k1, above)


def area_filtered_times_nodes(samples: np.ndarray, kernel: np.ndarray, nodes: np.ndarray, step_px: int) -> np.ndarray:
    """``cv2.sepFilter2D(samples, kernel, kernel, BORDER_REPLICATE) x upsample_nodes(nodes)`` in one pass.

    Parameters
    ----------
    samples : ndarray, shape (height, width), float32
        The field filtered (e.g. point samples of the terrain).
    kernel : ndarray, shape (3,), float32
        A symmetric 3-tap kernel ``[k1, k0, k1]`` (rows and columns).
    nodes : ndarray, shape (ny, nx)
        Node values of the factor (cast to float32 as :func:`upsample_nodes` does).
    step_px : int
        Node spacing (px).

    Returns
    -------
    ndarray, shape (height, width), float32
        A new array: the filtered field times the interpolated nodes (the bits of the two OpenCV calls and
        numpy's product, where :func:`fused_passes_match_opencv`).
    """
    samples = np.ascontiguousarray(samples, dtype=np.float32)
    height, width = samples.shape
    k1, k0, k1_again = (np.float32(value) for value in kernel)
    if k1 != k1_again or height < 2 or width < 2:
        raise ValueError("area_filtered_times_nodes: a symmetric 3-tap kernel and a frame of at least 2 x 2 px")
    ny, nx = nodes.shape
    col_index, col_weight = _resize_coefficients(width, step_px, nx)
    row_index, row_weight = _resize_coefficients(height, step_px, ny)
    across = scratch("node_rows_factor", (ny, width))
    _across(np.ascontiguousarray(nodes, dtype=np.float32), col_index, col_weight, across)
    out = np.empty((height, width), dtype=np.float32)
    _area_times_nodes_kernel(samples, k0, k1, across, row_index, row_weight, out)
    return out


@lru_cache(maxsize=1024)   # one bool per frame size and spacing (warped frames come in many sizes)
def fused_passes_match_opencv(height_px: int, width_px: int, step_px: int, kernel: tuple[float, ...] | None = None) -> bool:
    """Whether the fused passes give OpenCV's bits for this frame and node spacing (checked once, on random data).

    Parameters
    ----------
    height_px, width_px : int
        Frame size (px).
    step_px : int
        Node spacing (px), dividing both sizes.
    kernel : tuple of 3 float, optional
        Also check :func:`area_filtered_times_nodes` with this symmetric kernel.

    Returns
    -------
    bool
        True when :func:`divided_node_planes` (and :func:`area_filtered_times_nodes`) equal ``cv2.resize``,
        ``cv2.divide`` (``cv2.sepFilter2D`` and the product) bit for bit on a random probe.
    """
    if step_px < 2 or height_px % step_px or width_px % step_px:
        return False
    rng = np.random.default_rng(20261127)
    shape = (height_px // step_px + 2, width_px // step_px + 2)
    numerator_col, numerator_row = (rng.normal(0.0, 300.0, shape).astype(np.float32) for _ in range(2))
    denominator = (-0.2 - rng.random(shape)).astype(np.float32)
    col, row = np.empty((height_px, width_px), np.float32), np.empty((height_px, width_px), np.float32)
    divided_node_planes(numerator_col, numerator_row, denominator, step_px, col, row)
    upsampled = [upsample_nodes(plane, step_px, height_px, width_px) for plane in (numerator_col, numerator_row, denominator)]
    same = (np.array_equal(col.view(np.uint32), cv2.divide(upsampled[0], upsampled[2]).view(np.uint32))
            and np.array_equal(row.view(np.uint32), cv2.divide(upsampled[1], upsampled[2]).view(np.uint32)))
    if same and kernel is not None:
        taps = np.asarray(kernel, dtype=np.float32)
        samples = (rng.random((height_px, width_px)) * 0.3).astype(np.float32)
        fused = area_filtered_times_nodes(samples, taps, numerator_col, step_px)
        separate = cv2.sepFilter2D(samples, -1, taps, taps, borderType=cv2.BORDER_REPLICATE) * upsampled[0]
        same = np.array_equal(fused.view(np.uint32), separate.view(np.uint32))
    return bool(same)
