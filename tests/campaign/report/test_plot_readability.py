"""The report's and the plan's figures are readable at 100 % zoom (issue 32), checked on the matplotlib figures
themselves, not on pixels: every title at least 11 pt, every axis labelled (a numeric axis with its unit), every
panel with its own tick labels (the false-valid panel's y labels included), count axes with integer ticks only,
the footprint map with a north label and a colour bar only when bins hold different counts (integer ticks);
estimators whose rows all failed are shown with their counts, never as "n/a"."""
from __future__ import annotations

import re

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from campaign.plan.density import FootprintDensity
from campaign.report import compare_plots, plots
from campaign.report.aggregate import site_table
from campaign.report.compare import comparison_table
from flight_interface.camera import load_camera
from service_campaigns import SITEDATA
from simulator.scene.terrain import Terrain

MIN_TITLE_POINTS = 11.0
MIN_TICK_POINTS = 8.0
UNIT = re.compile(r"\([^)]*\)|%")
FRACTIONS = {"gcp": 0.6, "gdcp": 0.4, "gkep": 0.0}


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def rows(estimator: str, class_name: str, errors: list[float], failed: int = 0) -> list[dict]:
    """Valid rows with these errors (east error only) and ``failed`` failed rows."""
    made = [{"estimator": estimator, "class_name": class_name, "case_id": number, "status": "ok", "valid": True,
             "reason": "ok", "velocity_error_mps": error, "truth_velocity_east_mps": 10.0,
             "truth_velocity_north_mps": 2.0, "estimate_velocity_east_mps": 10.0 + error,
             "estimate_velocity_north_mps": 2.0} for number, error in enumerate(errors)]
    made += [{"estimator": estimator, "class_name": class_name, "case_id": 100 + number, "status": "failed",
              "valid": False, "reason": "estimator_failed", "velocity_error_mps": None,
              "truth_velocity_east_mps": None, "truth_velocity_north_mps": None, "estimate_velocity_east_mps": None,
              "estimate_velocity_north_mps": None} for number in range(failed)]
    return made


@pytest.fixture
def results() -> pd.DataFrame:
    """dimes: 3 valid cases in gcp (few: a matplotlib count axis would tick at 0.5), 2 in gdcp, 1 gkep;
    `broken`: every row failed (4 gcp, 2 gdcp)."""
    return pd.DataFrame(rows("dimes", "gcp", [1.0, 1.2, 2.5]) + rows("dimes", "gdcp", [0.8, 3.0])
                        + rows("dimes", "gkep", [1.5]) + rows("broken", "gcp", [], failed=4)
                        + rows("broken", "gdcp", [], failed=2))


def panels(figure) -> list:
    """The figure's plotting axes (colour bars excluded)."""
    return [axes for axes in figure.axes if axes.get_label() != "<colorbar>"]


def assert_readable(figure, count_axes: tuple[str, ...] = ()) -> None:
    """Titles >= 11 pt, both axes labelled (numeric ones with a unit), visible tick labels >= 8 pt on both axes
    of every panel, integer ticks on ``count_axes`` ("x"/"y")."""
    figure.canvas.draw()
    titled = figure._suptitle is not None and figure._suptitle.get_text()
    for axes in panels(figure):
        title = axes.title
        if title.get_text():
            titled = True
            assert title.get_fontsize() >= MIN_TITLE_POINTS, (title.get_text(), title.get_fontsize())
        for name in ("x", "y"):
            axis = getattr(axes, f"{name}axis")
            label = axis.get_label()
            assert label.get_text().strip(), f"{name} axis of {title.get_text()!r} has no label"
            shown = [tick for tick in axis.get_ticklabels() if tick.get_visible() and tick.get_text()]
            assert shown, f"{name} axis of {title.get_text()!r} shows no tick labels"
            assert all(tick.get_fontsize() >= MIN_TICK_POINTS for tick in shown)
            numeric = all(re.fullmatch(r"[−\-+]?[\d.]+(e[+\-]?\d+)?", tick.get_text()) for tick in shown)
            if numeric:
                assert UNIT.search(label.get_text()), f"{label.get_text()!r}: a numeric axis needs its unit"
            if name in count_axes:
                low, high = sorted(getattr(axes, f"get_{name}lim")())
                ticks = [value for value in axis.get_ticklocs() if low <= value <= high]
                assert ticks and all(float(value).is_integer() for value in ticks), (label.get_text(), ticks)
    if figure._suptitle is not None and figure._suptitle.get_text():
        assert figure._suptitle.get_fontsize() >= MIN_TITLE_POINTS
    assert titled


def texts(figure) -> list[str]:
    return [text.get_text() for axes in figure.axes for text in axes.texts]


def test_error_histograms_have_integer_count_axes_labelled_on_every_panel(results):
    dimes = results[(results["estimator"] == "dimes")]
    figure = plots.error_histograms_figure(dimes, "dimes", 5.0, list(FRACTIONS))
    assert_readable(figure, count_axes=("y",))
    assert len(panels(figure)) == 3


def test_valid_fraction_bars_count_failed_rows_instead_of_n_a(results):
    broken = results[results["estimator"] == "broken"]
    figure = plots.valid_fraction_bars_figure(site_table(broken, FRACTIONS, "Gusev"), "broken")
    assert_readable(figure)
    shown = texts(figure)
    assert "all 4\nfailed" in shown and "all 2\nfailed" in shown and "no cases" in shown
    assert not any("n/a" in text for text in shown)
    assert "6 of 6 rows failed" in figure.axes[0].get_title()


def test_estimate_vs_truth_panels_each_show_their_labels(results):
    figure = plots.estimate_vs_truth_figure(results[results["estimator"] == "dimes"], "dimes")
    assert_readable(figure)


def test_comparison_figures_are_readable_and_count_an_all_failed_estimator(results):
    comparison = comparison_table(results, FRACTIONS, "Gusev", false_valid_mps=5.0)
    bars = compare_plots.valid_false_valid_bars_figure(comparison)
    assert_readable(bars)
    false_valid_panel = panels(bars)[1]
    assert false_valid_panel.get_ylabel() == "false-valid (% of valid cases)"
    assert [tick.get_text() for tick in false_valid_panel.get_yticklabels() if tick.get_visible()][:2] == ["0", "20"]
    shown = texts(bars)
    assert "all 4\nfailed" in shown and shown.count("all 6\nfailed") == 2     # the site group on both panels
    assert not any("n/a" in text for text in shown)
    cdf = compare_plots.error_cdf_figure(results, list(FRACTIONS), "Gusev", ["dimes", "broken"], 5.0)
    assert_readable(cdf)
    legend = [text.get_text() for text in panels(cdf)[-1].get_legend().get_texts()]
    assert "broken (0 valid, 6 failed): none" in legend and "dimes (6 valid)" in legend


def _terrain() -> Terrain:
    return Terrain(reflectance_if=np.full((300, 60), 0.2, dtype=np.float32), metres_per_pixel=10.0,
                   origin_m=np.array([-300.0, 1500.0]), moc_incidence_rad=0.5, moc_emission_rad=0.0,
                   moc_phase_rad=0.5)


@pytest.mark.parametrize("counts, colour_bar", [(1, False), (3, True)])
def test_footprint_map_has_a_north_label_and_a_colour_bar_only_when_counts_differ(counts, colour_bar):
    terrain = _terrain()
    binned = np.zeros((50, 10), dtype=np.int64)
    binned[10, 3] = binned[20, 5] = 1
    binned[30, 4] = counts
    density = FootprintDensity(counts=binned, extent_m=terrain.extent_m, cases=int(binned.sum()))
    camera = load_camera(SITEDATA / "cameras" / "mer_a.toml")
    figure = plots.footprint_map_figure(terrain, [], camera, "Gusev gcp: 5 cases", density=density)
    assert_readable(figure)
    axes = panels(figure)[0]
    assert "N" in [text.get_text() for text in axes.texts]
    bars = [candidate for candidate in figure.axes if candidate.get_label() == "<colorbar>"]
    assert bool(bars) == colour_bar
    if colour_bar:
        figure.canvas.draw()
        low, high = bars[0].get_ylim()
        ticks = [value for value in bars[0].get_yticks() if low <= value <= high]
        assert ticks and all(float(value).is_integer() for value in ticks), ticks
    else:
        legend = [text.get_text() for text in axes.get_legend().get_texts()]
        assert legend == ["shaded bin: 1 footprint centre (3 cases binned)"]
