"""PNG figures for people: the footprint map (paper Fig. 5) and the report's plots."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from PIL import Image

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


def error_histograms(results: pd.DataFrame, path: Path) -> Path:
    classes = list(dict.fromkeys(results["class_name"]))
    figure, axes_list = plt.subplots(1, len(classes), figsize=(4 * len(classes), 3.2), squeeze=False)
    for axes, class_name in zip(axes_list[0], classes):
        members = results[(results["class_name"] == class_name) & results["valid"].astype(bool)]
        errors = pd.to_numeric(members["velocity_error_mps"], errors="coerce").dropna().to_numpy(dtype=float)
        shown, note = on_scale(errors)
        if shown.size:
            low, high = float(shown.min()), float(shown.max())
            if high - low < 1e-6 * max(1.0, abs(high)):      # (nearly) equal values: numpy's default +-0.5 range
                low, high = low - 0.5, high + 0.5
            axes.hist(shown, bins=20, range=(low, high), color="tab:blue")
        axes.axvline(5.0, color="tab:red", linestyle="--", linewidth=1, label="5 m/s requirement")
        axes.set_title(f"{class_name}: {len(errors)} valid{note}", fontsize=9)
        axes.set_xlabel("velocity error (m/s)")
        axes.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def valid_fraction_bars(table: pd.DataFrame, path: Path) -> Path:
    classes = table.iloc[:-1]
    figure, axes = plt.subplots(figsize=(5, 3.2))
    axes.bar(classes["class"], classes["pct_valid"].fillna(0.0), color="tab:green")
    axes.set_ylim(0, 105)
    axes.set_ylabel("% valid")
    axes.set_title(f"{table.iloc[-1]['class']}: weighted {table.iloc[-1]['weighted_pct_valid']:.0f}% valid", fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def estimate_vs_truth(results: pd.DataFrame, path: Path) -> Path:
    valid = results[results["valid"].astype(bool)]
    figure, axes_list = plt.subplots(1, 2, figsize=(8, 3.8))
    for axes, component in zip(axes_list, ("east", "north")):
        truth = pd.to_numeric(valid[f"truth_velocity_{component}_mps"], errors="coerce").to_numpy(dtype=float)
        estimate = pd.to_numeric(valid[f"estimate_velocity_{component}_mps"], errors="coerce").to_numpy(dtype=float)
        drawn = np.isfinite(truth) & np.isfinite(estimate) & (np.abs(truth) <= PLOT_LIMIT_MPS) & (np.abs(estimate) <= PLOT_LIMIT_MPS)
        truth, estimate = truth[drawn], estimate[drawn]
        axes.scatter(truth, estimate, s=6, alpha=0.7)
        limits = [min(truth.min(), estimate.min(), 0) - 1, max(truth.max(), estimate.max(), 0) + 1] if drawn.any() else [-30, 30]
        axes.plot(limits, limits, "k--", linewidth=0.8)
        if not drawn.all():
            axes.set_title(f"{int((~drawn).sum())} valid cases not drawn (non-finite or beyond "
                           f"{PLOT_LIMIT_MPS:g} m/s)", fontsize=8)
        axes.set_xlabel(f"true {component} velocity (m/s)")
        axes.set_ylabel(f"estimated {component} velocity (m/s)")
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def save_descent_image(dn: np.ndarray, path: Path, low_dn: float | None = None, high_dn: float | None = None) -> Path:
    """A 12-bit descent image as an 8-bit PNG, stretched between ``low_dn`` and ``high_dn``
    (default: its 1st and 99th percentiles), rows repeated 4x to show the 1024x1024 aspect."""

    dn = np.asarray(dn, dtype=float)
    low = np.percentile(dn, 1) if low_dn is None else low_dn
    high = np.percentile(dn, 99) if high_dn is None else high_dn
    scaled = np.clip((dn - low) / max(high - low, 1e-9), 0, 1)
    Image.fromarray((255 * np.repeat(scaled, 4, axis=0)).astype(np.uint8)).save(path)
    return path
