"""The node grid's fused passes against independent answers (affine fields, the pixel-area filter written out in
float64) and against the OpenCV calls they stand for, bit for bit where the process found they match."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from flight_interface.camera import load_camera
from simulator.scene import ground_mapping, node_grid, node_grid_fused, radiance
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
STEP = 16


def _node_grid():
    cols, rows = np.meshgrid(node_grid.node_positions(1024, STEP), node_grid.node_positions(1024, STEP))
    return cols, rows


def test_divided_planes_are_the_quotient_of_the_interpolated_planes():
    """Affine planes interpolate exactly, so each pixel's quotient is the planes' quotient at the pixel."""
    cols, rows = _node_grid()
    numerator_col, numerator_row = 40.0 + 0.5 * cols - 0.25 * rows, -7.0 + 0.125 * rows
    denominator = -1.0 - 1e-4 * cols - 2e-4 * rows
    col, row = np.empty((1024, 1024), np.float32), np.empty((1024, 1024), np.float32)
    node_grid_fused.divided_node_planes(numerator_col, numerator_row, denominator, STEP, col, row)
    pixel_cols, pixel_rows = np.meshgrid(np.arange(1024.0), np.arange(1024.0))
    divisor = -1.0 - 1e-4 * pixel_cols - 2e-4 * pixel_rows
    np.testing.assert_allclose(col, (40.0 + 0.5 * pixel_cols - 0.25 * pixel_rows) / divisor, rtol=2e-6, atol=2e-4)
    np.testing.assert_allclose(row, (-7.0 + 0.125 * pixel_rows) / divisor, rtol=2e-6, atol=2e-4)
    if node_grid_fused.fused_passes_match_opencv(1024, 1024, STEP):
        upsampled = [node_grid.upsample_nodes(plane, STEP, 1024, 1024)
                     for plane in (numerator_col, numerator_row, denominator)]
        np.testing.assert_array_equal(col.view(np.uint32), cv2.divide(upsampled[0], upsampled[2]).view(np.uint32))
        np.testing.assert_array_equal(row.view(np.uint32), cv2.divide(upsampled[1], upsampled[2]).view(np.uint32))


def test_area_filter_times_nodes_is_the_filter_written_out_times_the_interpolated_factor():
    """[1, 22, 1] / 24 along rows and columns with replicated edges, times a bilinear factor (float64 reference)."""
    rng = np.random.default_rng(30)
    samples = rng.uniform(0.05, 0.35, (1024, 1024)).astype(np.float32)
    cols, rows = _node_grid()
    factor_nodes = 1.3 + 1e-4 * cols - 5e-5 * rows
    got = node_grid_fused.area_filtered_times_nodes(samples, radiance.PIXEL_AREA_KERNEL, factor_nodes, STEP)
    padded = np.pad(samples.astype(np.float64), 1, mode="edge")
    across = (padded[:, :-2] + 22.0 * padded[:, 1:-1] + padded[:, 2:]) / 24.0
    filtered = (across[:-2] + 22.0 * across[1:-1] + across[2:]) / 24.0
    pixel_cols, pixel_rows = np.meshgrid(np.arange(1024.0), np.arange(1024.0))
    np.testing.assert_allclose(got, filtered * (1.3 + 1e-4 * pixel_cols - 5e-5 * pixel_rows), rtol=2e-6)
    taps = tuple(float(tap) for tap in radiance.PIXEL_AREA_KERNEL)
    if node_grid_fused.fused_passes_match_opencv(1024, 1024, STEP, taps):
        separate = radiance.pixel_area_average(samples) * node_grid.upsample_nodes(factor_nodes, STEP, 1024, 1024)
        np.testing.assert_array_equal(got.view(np.uint32), separate.view(np.uint32))


def test_fused_passes_refuse_what_they_do_not_cover():
    assert not node_grid_fused.fused_passes_match_opencv(1024, 1024, 1)          # no interpolation to fuse
    with pytest.raises(ValueError, match="symmetric"):
        node_grid_fused.area_filtered_times_nodes(np.ones((8, 8), np.float32), np.array([1.0, 2.0, 3.0], np.float32),
                                            np.ones((3, 3)), 8)


def test_a_pose_renders_the_same_bits_with_and_without_the_fused_passes(monkeypatch):
    """The default render (coarse rays and photometry, pixel-area filter, no sky) through the fused passes and
    through the OpenCV calls one after the other."""
    rng = np.random.default_rng(31)
    size, mpp = 1400, 1.0
    half = 0.5 * (size - 1) * mpp
    terrain = Terrain((0.2 + 0.03 * rng.standard_normal((size, size))).astype(np.float32), mpp,
                      np.array([-half, half]), np.radians(30), 0.0, np.radians(30), "fused")
    profile = constant_velocity_profile([3.0, -2.0, 1200.0], [5.0, 1.0, -60.0], np.array([1.0, 0.0, 0.0, 0.0]),
                                        1.0, [0.1])
    sun = np.array([np.sin(np.radians(40.0)), 0.0, np.cos(np.radians(40.0))])
    config = SceneConfig()
    pose = profile.pose(0.1)
    assert not ground_mapping.map_to_ground_grid(CAMERA, ground_mapping.camera_pose(CAMERA, pose),
                                                 (-half, half), mpp, STEP).any_sky
    fused = radiance.radiance_at_pose(terrain, CAMERA, pose, sun, config)
    radiance_fused, outside_fused = fused.radiance.copy(), fused.outside.copy()
    monkeypatch.setattr(node_grid_fused, "fused_passes_match_opencv", lambda *args: False)
    separate = radiance.radiance_at_pose(terrain, CAMERA, pose, sun, config)
    np.testing.assert_array_equal(radiance_fused.view(np.uint32), separate.radiance.view(np.uint32))
    np.testing.assert_array_equal(outside_fused, separate.outside)


@pytest.mark.parametrize("step", [4, 8, 32])
def test_contiguous_upsampling_equals_the_full_resize_and_interpolates_linear_ramps_exactly(step):
    rng = np.random.default_rng(3)
    rows, cols = 1024 // step + 2, 1024 // step + 2
    for _ in range(10):
        nodes = (rng.random((rows, cols)) ** rng.uniform(0.2, 5.0)).astype(np.float32)
        full = cv2.resize(nodes, (cols * step, rows * step), interpolation=cv2.INTER_LINEAR)
        upsampled = node_grid.upsample_nodes_contiguous(nodes, step, 1024, 1024)
        assert upsampled.flags.c_contiguous
        assert np.array_equal(upsampled, full[step:step + 1024, step:step + 1024])
    nodes = rng.random((1022 // step + 2, 1026 // step + 2)).astype(np.float32)   # sizes off the step: full resize
    full = cv2.resize(nodes, (nodes.shape[1] * step, nodes.shape[0] * step), interpolation=cv2.INTER_LINEAR)
    assert np.array_equal(node_grid.upsample_nodes_contiguous(nodes, step, 1022, 1026), full[step:step + 1022, step:step + 1026])
    # node k sits at pixel (k + 0.5) step - 0.5, k from -1: a ramp over the nodes is the same ramp over the pixels
    node_col = np.arange(cols) - 1.0
    nodes = (0.5 + 1e-3 * ((node_col + 0.5) * step - 0.5))[None, :].repeat(rows, axis=0).astype(np.float32)
    ramp = 0.5 + 1e-3 * np.arange(1024.0)
    assert np.allclose(node_grid.upsample_nodes_contiguous(nodes, step, 1024, 1024), ramp[None, :], rtol=0.0, atol=1e-6)
    assert np.allclose(node_grid.upsample_nodes_contiguous(np.ascontiguousarray(nodes.T), step, 1024, 1024),
                       ramp[:, None], rtol=0.0, atol=1e-6)
