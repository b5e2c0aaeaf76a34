"""PNG figures for people: the footprint map (paper Fig. 5) and the report's plots."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from campaign.plan.density import FootprintDensity  # noqa: E402
from campaign.plan.placement import footprint_outlines  # noqa: E402
from flight_interface.camera import Camera  # noqa: E402
from simulator.scene.descent_profile import DescentProfile  # noqa: E402
from simulator.scene.terrain import Terrain  # noqa: E402

IMAGE_COLOURS = ("tab:red", "tab:orange", "tab:cyan")
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


def footprint_map(terrain: Terrain, placed_profiles: list[DescentProfile], camera: Camera, path: Path,
                  title: str, max_cases: int = 60, density: FootprintDensity | None = None) -> Path:
    """The terrain strip with the first ``max_cases`` cases' lander tracks (+ at each image) and image
    footprints; with ``density``, every case's footprint centre as a translucent 2-D histogram (colour bar:
    cases per bin) under them."""
    west, east, south, north = terrain.extent_m
    height = 9.0
    width = max(3.0, height * (east - west) / max(north - south, 1e-9) + 1.5)
    figure, axes = plt.subplots(figsize=(width, height))
    axes.imshow(terrain.reflectance_if, cmap="gray", extent=(west, east, south, north), origin="upper")
    if density is not None and density.binned:
        shown = np.ma.masked_equal(density.counts, 0)
        layer = axes.imshow(shown, cmap="viridis", alpha=0.55, extent=density.extent_m, origin="upper",
                            interpolation="nearest")
        figure.colorbar(layer, ax=axes, fraction=0.05, label=f"footprint centres per bin ({density.binned} cases)")
    for profile in placed_profiles[:max_cases]:
        for index, outline in enumerate(footprint_outlines(camera, profile)):
            if outline is not None:
                closed = np.vstack([outline, outline[:1]])
                axes.plot(closed[:, 0], closed[:, 1], color=IMAGE_COLOURS[index % 3], linewidth=0.6, alpha=0.7)
        positions = np.array([profile.pose(float(t)).position_m for t in profile.image_times_s])
        axes.plot(positions[:, 0], positions[:, 1], "+", color="yellow", markersize=5)
    axes.set_xlim(west - 200, east + 200)
    axes.set_ylim(south - 200, north + 200)
    axes.set_xlabel("east (m)")
    axes.set_ylabel("north (m)")
    axes.set_title(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def error_histograms(results: pd.DataFrame, path: Path, estimator: str = "", false_valid_mps: float = 5.0,
                     classes: list[str] | None = None) -> Path:
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
    figure, axes_list = plt.subplots(1, len(classes), figsize=(4 * len(classes), 3.4), squeeze=False,
                                     sharex=True, sharey=True)
    for axes, class_name in zip(axes_list[0], classes):
        count, values, note = shown[class_name]
        if values.size:
            axes.hist(values, bins=bins, color="tab:blue")
        axes.axvline(false_valid_mps, color="tab:red", linestyle="--", linewidth=1,
                     label=f"false-valid > {false_valid_mps:g} m/s")
        axes.set_title(f"{estimator + ': ' if estimator else ''}{class_name}, {count} valid{note}", fontsize=8)
        axes.set_xlabel("horizontal velocity error (m/s)")
        axes.legend(fontsize=7)
    axes_list[0][0].set_ylabel("valid cases")
    axes_list[0][0].set_xlim(low, high)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def valid_fraction_bars(table: pd.DataFrame, path: Path, estimator: str = "") -> Path:
    """% valid of each class (valid/ran on each bar; 0 % and "n/a" written, so they are seen) and the
    site's ellipse-weighted % valid in the title."""
    classes = table.iloc[:-1]
    site = table.iloc[-1]
    figure, axes = plt.subplots(figsize=(5, 3.4))
    heights = classes["pct_valid"].astype(float).fillna(0.0).clip(0.0, 100.0)
    bars = axes.bar(classes["class"], heights, color="tab:green")
    for bar, (_, row) in zip(bars, classes.iterrows()):
        ran = int(row["cases"]) - int(row["failed"])
        text = f"{row['pct_valid']:.0f}%\n{int(row['valid'])}/{ran}" if ran else "n/a"
        axes.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + 1, text, ha="center", va="bottom", fontsize=7)
    axes.set_ylim(0, 120)
    axes.set_ylabel("% valid (valid / ran)")
    weighted = float(site["weighted_pct_valid"])
    weighted_text = f"{weighted:.1f}%" if np.isfinite(weighted) else "n/a"
    axes.set_title(f"{estimator + ': ' if estimator else ''}{site['class']} ellipse-weighted {weighted_text} valid",
                   fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def estimate_vs_truth(results: pd.DataFrame, path: Path, estimator: str = "") -> Path:
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
    figure, axes_list = plt.subplots(1, 2, figsize=(8, 4.0), sharex=True, sharey=True)
    for axes, component in zip(axes_list, ("east", "north")):
        truth, estimate = pairs[component]
        axes.scatter(truth, estimate, s=6, alpha=0.7)
        axes.plot(limits, limits, "k--", linewidth=0.8)
        note = (f"\n{hidden[component]} not drawn (non-finite or beyond {PLOT_LIMIT_MPS:g} m/s)"
                if hidden[component] else "")
        axes.set_title(f"{estimator + ': ' if estimator else ''}{component}, {truth.size} valid cases{note}", fontsize=8)
        axes.set_xlabel(f"true {component} velocity (m/s)")
        axes.set_ylabel(f"estimated {component} velocity (m/s)")
        axes.set_aspect("equal", adjustable="box")
    axes_list[0].set_xlim(*limits)
    axes_list[0].set_ylim(*limits)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path
