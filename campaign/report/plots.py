"""PNG figures for people: the footprint map (paper Fig. 5) and the report's plots.

Readable at 100 % zoom: titles at least :data:`TITLE_POINTS`, axis labels :data:`LABEL_POINTS`, tick labels and
notes :data:`TICK_POINTS` / :data:`NOTE_POINTS`; every axis is labelled with its unit, every panel shows its own
tick labels, an axis of counts has integer ticks only. Each ``*_figure`` function returns the open
:class:`~matplotlib.figure.Figure` (what the tests inspect); the function of the same name without it writes
the PNG and closes the figure."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from campaign.plan.density import FootprintDensity  # noqa: E402
from campaign.plan.placement import footprint_outlines  # noqa: E402
from flight_interface.camera import Camera  # noqa: E402
from simulator.scene.descent_profile import DescentProfile  # noqa: E402
from simulator.scene.terrain import Terrain  # noqa: E402

IMAGE_COLOURS = ("tab:red", "tab:orange", "tab:cyan")
TITLE_POINTS = 11.0
LABEL_POINTS = 10.0
TICK_POINTS = 9.0
NOTE_POINTS = 8.0
"""Font sizes (points) of titles, axis labels, tick labels and in-plot notes (bar counts, legends)."""
FIGURE_DPI = 90
PLOT_LIMIT_MPS = 1000.0
"""Velocities and errors beyond this (m/s) are not to scale in the report's plots: a histogram draws them
in its last bin and says how many, a scatter leaves them out and says how many (a stored 1e30 m/s or
inf never makes a plot fail, and cases near the real 0-30 m/s range stay readable)."""


def on_scale(values: np.ndarray, limit: float = PLOT_LIMIT_MPS) -> tuple[np.ndarray, str]:
    """The finite ``values`` clipped to [-limit, limit] for a histogram, and a title note saying how many
    were not finite or clipped ("" when none)."""
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    clipped = int(np.count_nonzero(np.abs(finite) > limit))
    notes = ([f"{values.size - finite.size} not finite, not drawn"] if finite.size < values.size else []) + \
            ([f"{clipped} beyond {limit:g} drawn at +-{limit:g}"] if clipped else [])
    return np.clip(finite, -limit, limit), (" (" + "; ".join(notes) + ")" if notes else "")


def save(figure: Figure, path: Path, dpi: float = FIGURE_DPI) -> Path:
    """Write ``figure`` as a PNG at ``path`` and close it."""
    figure.savefig(path, dpi=dpi)
    plt.close(figure)
    return path


def readable_axes(axes, count_axis: str | None = None) -> None:
    """Tick labels of ``axes`` at :data:`TICK_POINTS` on both axes (shown even on a shared axis); with
    ``count_axis`` ("x" or "y") that axis gets integer ticks only (a count has no 0.5)."""
    axes.tick_params(labelsize=TICK_POINTS, labelleft=True, labelbottom=True)
    if count_axis is not None:
        getattr(axes, f"{count_axis}axis").set_major_locator(MaxNLocator(integer=True))


def footprint_map_figure(terrain: Terrain, placed_profiles: list[DescentProfile], camera: Camera, title: str,
                         max_cases: int = 60, density: FootprintDensity | None = None) -> Figure:
    """The terrain strip with the first ``max_cases`` cases' lander tracks (+ at each image) and image
    footprints, north up (an arrow says so); with ``density``, every case's footprint centre as a translucent
    2-D histogram under them: a colour bar of cases per bin (integer ticks) when bins hold different counts,
    else a legend entry saying how many centres each shaded bin holds (a one-value colour bar says nothing)."""
    west, east, south, north = terrain.extent_m
    height = 9.0
    width = max(5.5, height * (east - west) / max(north - south, 1e-9) + 2.0)
    figure, axes = plt.subplots(figsize=(width, height))
    axes.imshow(terrain.reflectance_if, cmap="gray", extent=(west, east, south, north), origin="upper")
    if density is not None and density.binned:
        shown = np.ma.masked_equal(density.counts, 0)
        occupied = density.counts[density.counts > 0]
        layer = axes.imshow(shown, cmap="viridis", alpha=0.55, extent=density.extent_m, origin="upper",
                            interpolation="nearest")
        if occupied.max() > occupied.min():
            bar = figure.colorbar(layer, ax=axes, fraction=0.05)
            bar.set_label(f"footprint centres per bin (cases; {density.binned} binned)", fontsize=LABEL_POINTS)
            bar.ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            bar.ax.tick_params(labelsize=TICK_POINTS)
        else:
            count = int(occupied.max())
            shade = np.asarray(layer.cmap(layer.norm(np.array([float(count)]))), dtype=float).reshape(-1)[:4]
            colour = (float(shade[0]), float(shade[1]), float(shade[2]))
            axes.legend(handles=[Patch(color=colour, alpha=0.55,
                                       label=f"shaded bin: {count} footprint centre{'s' if count > 1 else ''} "
                                             f"({density.binned} cases binned)")],
                        loc="lower right", fontsize=NOTE_POINTS)
    for profile in placed_profiles[:max_cases]:
        for index, outline in enumerate(footprint_outlines(camera, profile)):
            if outline is not None:
                closed = np.vstack([outline, outline[:1]])
                axes.plot(closed[:, 0], closed[:, 1], color=IMAGE_COLOURS[index % 3], linewidth=0.6, alpha=0.7)
        positions = np.array([profile.pose(float(t)).position_m for t in profile.image_times_s])
        axes.plot(positions[:, 0], positions[:, 1], "+", color="yellow", markersize=5)
    axes.set_xlim(west - 200, east + 200)
    axes.set_ylim(south - 200, north + 200)
    axes.annotate("", xy=(0.9, 0.93), xytext=(0.9, 0.84), xycoords="axes fraction", textcoords="axes fraction",
                  arrowprops={"arrowstyle": "-|>", "color": "white", "linewidth": 1.5})    # north up
    axes.text(0.9, 0.935, "N", transform=axes.transAxes, ha="center", va="bottom", fontsize=LABEL_POINTS + 2,
              fontweight="bold", color="white")
    axes.set_xlabel("east (m)", fontsize=LABEL_POINTS)
    axes.set_ylabel("north (m)", fontsize=LABEL_POINTS)
    readable_axes(axes)
    axes.set_title(title, fontsize=TITLE_POINTS)
    figure.tight_layout()
    return figure


def footprint_map(terrain: Terrain, placed_profiles: list[DescentProfile], camera: Camera, path: Path,
                  title: str, max_cases: int = 60, density: FootprintDensity | None = None) -> Path:
    """Write :func:`footprint_map_figure` as a PNG at ``path``."""
    return save(footprint_map_figure(terrain, placed_profiles, camera, title, max_cases, density), path)


def error_histograms_figure(results: pd.DataFrame, estimator: str = "", false_valid_mps: float = 5.0,
                            classes: list[str] | None = None) -> Figure:
    """One histogram of the valid cases' horizontal velocity error per class, every panel on the same
    bins, x range and y range (a class without valid cases is an empty panel that says so)."""
    classes = classes or list(dict.fromkeys(results["class_name"]))
    shown = {}
    for class_name in classes:
        members = results[(results["class_name"] == class_name) & results["valid"].astype(bool)]
        errors = pd.to_numeric(members["velocity_error_mps"], errors="coerce").to_numpy(dtype=float)
        shown[class_name] = (errors.size, *on_scale(errors))
    drawn = np.concatenate([values for _, values, _ in shown.values()] + [np.zeros(0)])
    low = min(0.0, float(drawn.min())) if drawn.size else 0.0
    high = max(2.0 * false_valid_mps, float(drawn.max()) if drawn.size else 0.0)
    bins = np.linspace(low, high, 21)
    figure, axes_list = plt.subplots(1, len(classes), figsize=(4.5 * len(classes), 3.8), squeeze=False,
                                     sharex=True, sharey=True)
    for axes, class_name in zip(axes_list[0], classes):
        count, values, note = shown[class_name]
        if values.size:
            axes.hist(values, bins=bins, color="tab:blue")
        axes.axvline(false_valid_mps, color="tab:red", linestyle="--", linewidth=1,
                     label=f"false-valid > {false_valid_mps:g} m/s")
        axes.set_title(f"{estimator + ': ' if estimator else ''}{class_name}, {count} valid"
                       + (f"\n{note.strip()}" if note else ""), fontsize=TITLE_POINTS)
        axes.set_xlabel("horizontal velocity error (m/s)", fontsize=LABEL_POINTS)
        axes.set_ylabel("valid cases (count)", fontsize=LABEL_POINTS)
        axes.legend(fontsize=NOTE_POINTS)
        readable_axes(axes, count_axis="y")
    axes_list[0][0].set_xlim(low, high)
    figure.tight_layout()
    return figure


def error_histograms(results: pd.DataFrame, path: Path, estimator: str = "", false_valid_mps: float = 5.0,
                     classes: list[str] | None = None) -> Path:
    """Write :func:`error_histograms_figure` as a PNG at ``path``."""
    return save(error_histograms_figure(results, estimator, false_valid_mps, classes), path)


def bar_count_text(pct_valid: float, valid: int, ran: int, failed: int) -> str:
    """The text on a % valid bar: ``"90%\n9/10"`` (valid/ran), a line ``"2 failed"`` when rows failed, and for a
    class where nothing ran ``"all 3 failed"`` (or ``"no cases"``), never a bare "n/a"."""
    if ran == 0:
        return f"all {failed}\nfailed" if failed else "no cases"
    return f"{pct_valid:.0f}%\n{valid}/{ran}" + (f"\n{failed} failed" if failed else "")


def valid_fraction_bars_figure(table: pd.DataFrame, estimator: str = "") -> Figure:
    """% valid of each class (valid/ran on each bar, and the failed rows; 0 % and all-failed written, so they
    are seen) and the site's ellipse-weighted % valid in the title."""
    classes = table.iloc[:-1]
    site = table.iloc[-1]
    figure, axes = plt.subplots(figsize=(5.5, 3.8))
    heights = classes["pct_valid"].astype(float).fillna(0.0).clip(0.0, 100.0)
    bars = axes.bar(classes["class"], heights, color="tab:green")
    for bar, (_, row) in zip(bars, classes.iterrows()):
        ran = int(row["cases"]) - int(row["failed"])
        text = bar_count_text(float(row["pct_valid"]), int(row["valid"]), ran, int(row["failed"]))
        axes.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + 1, text, ha="center", va="bottom",
                  fontsize=NOTE_POINTS)
    axes.set_ylim(0, 135)
    axes.set_yticks(range(0, 101, 20))
    axes.set_xlabel("appearance class", fontsize=LABEL_POINTS)
    axes.set_ylabel("% valid (valid / ran)", fontsize=LABEL_POINTS)
    readable_axes(axes)
    weighted = float(site["weighted_pct_valid"])
    weighted_text = (f"ellipse-weighted {weighted:.1f}% valid" if np.isfinite(weighted)
                     else "no ellipse-weighted % valid\n(a class ran no case)")
    failed = int(site["failed"])
    axes.set_title(f"{estimator + ': ' if estimator else ''}{site['class']} {weighted_text}"
                   + (f"\n{failed} of {int(site['cases'])} rows failed" if failed else ""), fontsize=TITLE_POINTS)
    figure.tight_layout()
    return figure


def valid_fraction_bars(table: pd.DataFrame, path: Path, estimator: str = "") -> Path:
    """Write :func:`valid_fraction_bars_figure` as a PNG at ``path``."""
    return save(valid_fraction_bars_figure(table, estimator), path)


def estimate_vs_truth_figure(results: pd.DataFrame, estimator: str = "") -> Figure:
    """Estimated against true velocity of the valid cases, east and north, both panels on the same
    square x and y range (cases with a non-finite value or one beyond PLOT_LIMIT_MPS are counted, not drawn)."""
    valid = results[results["valid"].astype(bool)]
    pairs, hidden = {}, {}
    for component in ("east", "north"):
        truth = pd.to_numeric(valid[f"truth_velocity_{component}_mps"], errors="coerce").to_numpy(dtype=float)
        estimate = pd.to_numeric(valid[f"estimate_velocity_{component}_mps"], errors="coerce").to_numpy(dtype=float)
        drawn = np.isfinite(truth) & np.isfinite(estimate) & (np.abs(truth) <= PLOT_LIMIT_MPS) & (np.abs(estimate) <= PLOT_LIMIT_MPS)
        pairs[component] = (truth[drawn], estimate[drawn])
        hidden[component] = int((~drawn).sum())
    values = np.concatenate([np.concatenate(pair) for pair in pairs.values()] + [np.zeros(1)])
    limits = [float(values.min()) - 1.0, float(values.max()) + 1.0]
    figure, axes_list = plt.subplots(1, 2, figsize=(9, 4.6), sharex=True, sharey=True)
    for axes, component in zip(axes_list, ("east", "north")):
        truth, estimate = pairs[component]
        axes.scatter(truth, estimate, s=6, alpha=0.7)
        axes.plot(limits, limits, "k--", linewidth=0.8)
        note = (f"\n{hidden[component]} not drawn (non-finite or beyond {PLOT_LIMIT_MPS:g} m/s)"
                if hidden[component] else "")
        axes.set_title(f"{estimator + ': ' if estimator else ''}{component}, {truth.size} valid cases{note}",
                       fontsize=TITLE_POINTS)
        axes.set_xlabel(f"true {component} velocity (m/s)", fontsize=LABEL_POINTS)
        axes.set_ylabel(f"estimated {component} velocity (m/s)", fontsize=LABEL_POINTS)
        axes.set_aspect("equal", adjustable="box")
        readable_axes(axes)
    axes_list[0].set_xlim(*limits)
    axes_list[0].set_ylim(*limits)
    figure.tight_layout()
    return figure


def estimate_vs_truth(results: pd.DataFrame, path: Path, estimator: str = "") -> Path:
    """Write :func:`estimate_vs_truth_figure` as a PNG at ``path``."""
    return save(estimate_vs_truth_figure(results, estimator), path)
