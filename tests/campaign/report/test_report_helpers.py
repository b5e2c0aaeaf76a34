"""Report and realism helpers imported by no other test: the descent-image PNG stretch
(file_formats.descent_images), the masked-run finder of the flight plots (campaign.realism.flight_plots), the
FLIGHT.toml image entries (campaign.realism.flight_file) and the sweep-plot point choice
(campaign.report.sweep_plots), against values worked out by hand."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from campaign.realism.flight_file import FlightImageEntry
from campaign.realism.flight_plots import _runs
from campaign.report.sweep_plots import points_along
from config_tables.errors import FieldProblem
from file_formats.descent_images import write_preview_png


def test_descent_png_is_stretched_clipped_and_rows_repeated(tmp_path):
    dn = np.array([[100, 200, 300], [50, 350, 250]], dtype=np.uint16)
    path = write_preview_png(tmp_path / "image.png", dn, low_dn=100, high_dn=300)
    png = np.asarray(Image.open(path))
    assert png.shape == (8, 3) and png.dtype == np.uint8                  # rows repeated 4x (binned aspect)
    # (dn - 100) / 200 clipped to [0, 1], times 255, truncated
    assert png[0].tolist() == [0, 127, 255] and png[4].tolist() == [0, 255, 191]
    assert (png[0:4] == png[0]).all()


def test_runs_are_half_open_ranges_of_true():
    assert _runs(np.array([True, True, False, True, False, False, True])) == [(0, 2), (3, 4), (6, 7)]
    assert _runs(np.zeros(4, bool)) == [] and _runs(np.ones(3, bool)) == [(0, 3)]


def test_flight_image_pose_checks(tmp_path):
    image = tmp_path / "a.npy"
    np.save(image, np.zeros((256, 1024), np.uint16))
    entry = FlightImageEntry(file=str(image), time_s=1.0, position_m=[0, 0, 1500], attitude_quat=[1, 0, 0, 0])
    assert entry.velocity_mps == (0.0, 0.0, 0.0)
    with pytest.raises((FieldProblem, ValueError), match="above the ground plane"):
        FlightImageEntry(file=str(image), time_s=1.0, position_m=[0, 0, -1], attitude_quat=[1, 0, 0, 0])
    with pytest.raises((FieldProblem, ValueError), match="unit quaternion"):
        FlightImageEntry(file=str(image), time_s=1.0, position_m=[0, 0, 10], attitude_quat=[3, 0, 0, 0])


def test_sweep_plot_points_vary_one_axis_at_the_first_points_other_values():
    def point(dust, rate):
        return SimpleNamespace(values={"dust": dust, "rate": rate})

    points = [point(0.5, 1), point(0.1, 1), point(0.5, 2), point(0.9, 1)]
    spec = SimpleNamespace(points=points, axis_names=["dust", "rate"], axes={"dust": [0.5, 0.1, 0.9], "rate": [1, 2]})
    assert [p.values["dust"] for p in points_along(spec, "dust")] == [0.1, 0.5, 0.9]      # rate held at 1, sorted
    assert [p.values["rate"] for p in points_along(spec, "rate")] == [1, 2]               # dust held at 0.5
