"""CAHVOR geometry against closed forms."""
import numpy as np
import pytest

from flight_interface import cahvor


@pytest.fixture()
def distorted_model():
    return cahvor.cahvor_from_intrinsics(0.01467, 12e-6, (511.5, 511.5), (0.0, -0.01, 0.0))


def test_point_on_optical_axis_lands_on_hc_vc(distorted_model):
    pixels, in_front = cahvor.project(distorted_model, np.array([[0.0, 0.0, 1234.0]]))
    assert in_front.all()
    np.testing.assert_allclose(pixels[0], [distorted_model.hc, distorted_model.vc], atol=1e-12)
    assert distorted_model.hc == pytest.approx(511.5) and distorted_model.vc == pytest.approx(511.5)


def test_pinhole_projection_matches_focal_length_formula():
    model = cahvor.cahvor_from_intrinsics(0.01467, 12e-6, (511.5, 511.5))
    focal_px = 0.01467 / 12e-6
    point = np.array([3.0, -2.0, 10.0])
    pixels, _ = cahvor.project(model, point)
    np.testing.assert_allclose(pixels, [511.5 + focal_px * 0.3, 511.5 - focal_px * 0.2], rtol=1e-12)


def test_radial_distortion_follows_mu_polynomial(distorted_model):
    # a point at angle u = tan(theta) from O images at u * (1 + R1 u^2) in pinhole pixels
    u = 0.4
    pixels, _ = cahvor.project(distorted_model, np.array([u, 0.0, 1.0]))
    focal_px = 0.01467 / 12e-6
    assert pixels[0] - 511.5 == pytest.approx(focal_px * u * (1 - 0.01 * u**2), rel=1e-12)


def test_project_unproject_round_trip_whole_frame(distorted_model):
    grid = cahvor.pixel_grid(1024, 1024)[::7, ::7].reshape(-1, 2)
    grid = np.vstack([grid, [[0, 0], [1023, 0], [0, 1023], [1023, 1023], [-0.5, -0.5]]])
    rays = cahvor.unproject(distorted_model, grid)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    back, in_front = cahvor.project(distorted_model, rays * 2000.0)
    assert in_front.all()
    assert np.max(np.abs(back - grid)) < 1e-6


def test_unprojected_ray_angle_undoes_distortion(distorted_model):
    # closed form: the image radius of a ray at tan(theta)=u is f*u*(1+R1 u^2)
    focal_px = 0.01467 / 12e-6
    u = 0.55
    radius_px = focal_px * u * (1 - 0.01 * u**2)
    ray = cahvor.unproject(distorted_model, np.array([511.5 + radius_px, 511.5]))
    assert np.arctan2(ray[0], ray[2]) == pytest.approx(np.arctan(u), abs=1e-9)


def test_points_behind_camera_are_flagged(distorted_model):
    _, in_front = cahvor.project(distorted_model, np.array([[0.0, 0.0, -5.0], [1.0, 1.0, 5.0]]))
    assert in_front.tolist() == [False, True]


def test_transformed_model_projects_transformed_points(distorted_model):
    angle = 0.3
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    translation = np.array([10.0, -4.0, 2000.0])
    moved = distorted_model.transformed(rotation, translation)
    point = np.array([5.0, 7.0, 300.0])
    expected, _ = cahvor.project(distorted_model, point)
    actual, _ = cahvor.project(moved, rotation @ point + translation)
    np.testing.assert_allclose(actual, expected, atol=1e-9)
