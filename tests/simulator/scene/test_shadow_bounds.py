"""Shadows skipped by the view bounds: the bounds hold every ground point seen, and skipping changes no bit."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.scene import ground_mapping, shadow
from simulator.scene.descent_profile import constant_velocity_profile

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
SUN = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])


def camera_pose(tilt_deg: float, altitude_m: float = 2000.0) -> ground_mapping.CameraPose:
    attitude = quat_from_axis_angle([0.6, 0.8, 0.0], np.radians(tilt_deg))
    profile = constant_velocity_profile([0.0, 0.0, altitude_m], [0.0, 0.0, 0.0], attitude, 1.0, [0.0])
    return ground_mapping.camera_pose(CAMERA, profile.pose(0.0))


@pytest.mark.parametrize("tilt_deg", [0.0, 20.0, 40.0])
def test_view_bounds_hold_every_ground_point_seen(tilt_deg):
    cam = camera_pose(tilt_deg)
    footprint, hit = ground_mapping.footprint_m(CAMERA, cam)
    west, east, south, north = shadow.view_bounds_m(footprint, hit)
    pixels = np.stack(np.meshgrid(np.arange(-0.5, 1024, 8.0), np.arange(-0.5, 1024, 8.0)), axis=-1).reshape(-1, 2)
    points, seen = ground_mapping.ground_points(CAMERA, cam, pixels)
    assert seen.all()
    assert np.all((points[:, 0] >= west) & (points[:, 0] <= east) & (points[:, 1] >= south) & (points[:, 1] <= north))


def test_unbounded_view_has_no_bounds():
    cam = camera_pose(80.0)          # the top of the frame sees the sky
    footprint, hit = ground_mapping.footprint_m(CAMERA, cam)
    assert not hit.all() and shadow.view_bounds_m(footprint, hit) is None


def test_circle_meets_box_closed_form():
    box = (0.0, 10.0, 0.0, 10.0)
    assert shadow._circle_meets_box(np.array([5.0, 5.0, 0.0]), 0.1, box)          # inside
    assert shadow._circle_meets_box(np.array([13.0, 14.0, 0.0]), 5.0, box)        # corner at distance 5
    assert not shadow._circle_meets_box(np.array([13.0, 14.0, 0.0]), 4.99, box)
    assert not shadow._circle_meets_box(np.array([-3.0, 5.0, 0.0]), 2.9, box)     # beside an edge
    assert shadow._circle_meets_box(np.array([-3.0, 5.0, 0.0]), 3.0, box)


@pytest.mark.parametrize("beyond_edge_m", [-800.0, -5.0, 30.0, 200.0, 2000.0])
def test_bounds_change_no_bit(beyond_edge_m):
    # a parachute-sized caster (7.5 m radius, 300 m up) whose shadow sits at the image centre, across the
    # footprint's east edge, just beyond it (inside the bounds' margin: projected, empty window) and far
    # beyond (skipped by the bounds): the field with the bounds equals the one without
    cam = camera_pose(0.0)
    gmap = ground_mapping.map_to_ground_grid(CAMERA, cam, (-2400.0, 2400.0), 3.0, 16)
    footprint, hit = ground_mapping.footprint_m(CAMERA, cam)
    edge_m = float(footprint[np.abs(footprint[:, 1]) < 60.0, 0].max())
    ground = np.array([edge_m + beyond_edge_m, 0.0, 0.0])
    caster = shadow.Caster("parachute", ground + (300.0 / SUN[2]) * SUN, 7.5)
    fields = []
    for bounds in (None, shadow.view_bounds_m(footprint, hit)):
        field = np.full((1024, 1024), 40.0, dtype=np.float32)
        centres = shadow.apply_shadows(field, gmap, CAMERA, cam, [caster], SUN, 3.05e-3, 0.3, view_bounds_m=bounds)
        assert np.allclose(centres[0], ground, atol=1e-9)
        fields.append(field)
    assert np.array_equal(fields[0], fields[1])
    assert (fields[0] < 40.0).any() == (beyond_edge_m < 0.0)


OFFSETS_PX = [(-1.0 / 3.0, -1.0 / 3.0), (0.0, 1.0 / 3.0), (1.0 / 3.0, -1.0 / 3.0), (1.0 / 3.0, 1.0 / 3.0)]


@pytest.mark.parametrize("tilt_deg", [0.0, 25.0])
@pytest.mark.parametrize("shift_m", [0.0, 700.0, 1150.0])
def test_pose_outlines_shifted_give_each_sample_cameras_own_windows(tilt_deg, shift_m):
    # a supersampling sample's windows come from its pose's outlines projected once with the unshifted
    # camera and shifted by the sample's offset: they must be the windows the sample's own camera projects
    from simulator.scene import heat_shield, radiance

    cam = camera_pose(tilt_deg)
    centre = shadow.shadow_centre_m(cam.ray_origin_m, SUN) + np.array([shift_m, -0.4 * shift_m, 0.0])
    caster = shadow.Caster("parachute", centre + 300.0 * SUN / SUN[2], 7.5)
    (outline,) = shadow.penumbra_outlines(CAMERA, cam, [caster], SUN, 3.05e-3)
    shield_centre = cam.ray_origin_m + np.array([0.3 * shift_m, 0.1 * shift_m, -400.0])
    shield_outline = ground_mapping.outline_extent(*ground_mapping.world_to_pixels(
        CAMERA, cam, heat_shield.cone_outline_m(shield_centre, 2.6, np.radians(140.0))))
    for dc, dr in OFFSETS_PX:
        sample_camera = radiance.subpixel_camera(CAMERA, dc, dr)
        circle_centre, outer = shadow._penumbra_circle_m(caster, SUN, 3.05e-3)
        assert np.array_equal(outline[0], circle_centre) and outline[1] == outer
        own = shadow._penumbra_window(sample_camera, cam, circle_centre, outer)
        assert ground_mapping.outline_window(outline[2], dc, dr, CAMERA.width_px, CAMERA.height_px) == own
        own_box = heat_shield.bounding_box(sample_camera, cam, shield_centre, 2.6, np.radians(140.0))
        assert ground_mapping.outline_window(shield_outline, dc, dr, CAMERA.width_px, CAMERA.height_px) == own_box


def test_outline_window_is_the_pixel_window_of_the_shifted_points():
    # closed form: bounds (10.2 .. 30.7, 5.5 .. 6.0) shifted by (+1/3, -1/3), 2 px margin below, 3 above
    pixels = np.array([[10.2, 6.0], [30.7, 5.5], [20.0, 5.8]])
    extent = ground_mapping.outline_extent(pixels, np.ones(3, dtype=bool))
    assert ground_mapping.outline_window(extent, 1.0 / 3.0, -1.0 / 3.0, 1024, 1024) == (3, 10, 7, 34)
    assert ground_mapping.pixel_window(pixels - [1.0 / 3.0, -1.0 / 3.0], 1024, 1024) == (3, 10, 7, 34)
    assert ground_mapping.outline_window(extent, 0.0, 0.0, 20, 20) == (3, 9, 8, 20)           # clipped
    straddling = ground_mapping.outline_extent(pixels, np.array([True, False, True]))
    assert ground_mapping.outline_window(straddling, 0.3, 0.3, 1024, 512) == (0, 512, 0, 1024)
    behind = ground_mapping.outline_extent(pixels, np.zeros(3, dtype=bool))
    assert ground_mapping.outline_window(behind, 0.0, 0.0, 1024, 1024) is None
    assert ground_mapping.outline_window(extent, -2000.0, 0.0, 1024, 1024) is None           # off the frame
