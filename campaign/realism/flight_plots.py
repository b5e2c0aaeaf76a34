"""Figures of ``campaign compare-flight`` (paper Figs. 10 and 11): side by side, column profile, scatter."""
from __future__ import annotations

from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

GAP_PX = 16


def side_by_side(simulated_dn: np.ndarray, flight_dn: np.ndarray, column: int, binning_rows: int, path: Path) -> Path:
    """Simulated | flight, both stretched over one display range (0.5-99.5 % of the two together, like
    the paper's common 200-1200 DN), rows repeated ``binning_rows`` times to the square field of view;
    the profile column drawn in green in both (8-bit colour PNG)."""
    both = np.concatenate([simulated_dn.ravel(), flight_dn.ravel()]).astype(np.float32)
    low, high = np.percentile(both, [0.5, 99.5])
    panels = []
    for image in (simulated_dn, flight_dn):
        grey = (np.clip((image.astype(np.float32) - low) / max(high - low, 1.0), 0.0, 1.0) * 255).astype(np.uint8)
        panel = cv2.cvtColor(np.repeat(grey, binning_rows, axis=0), cv2.COLOR_GRAY2BGR)
        panel[:, column] = (0, 255, 0)
        panels.append(panel)
    gap = np.full((panels[0].shape[0], GAP_PX, 3), 255, np.uint8)
    canvas = np.concatenate([panels[0], gap, panels[1]], axis=1)
    for text, x in (("simulated", 10), ("flight", panels[0].shape[1] + GAP_PX + 10)):
        cv2.putText(canvas, text, (x, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (0, 0, 255), 2)
    cv2.putText(canvas, f"display {low:.0f}-{high:.0f} DN", (10, canvas.shape[0] - 15), cv2.FONT_HERSHEY_SIMPLEX,
                0.9, (0, 0, 255), 2)
    cv2.imwrite(str(path), canvas)
    return path


def column_plot(simulated: np.ndarray, flight: np.ndarray, usable: np.ndarray, column: int, path: Path) -> Path:
    """DN along one raw column for both images (paper Fig. 11 left); rows left out of the fit greyed."""
    figure, axes = plt.subplots(figsize=(8, 4))
    rows = np.arange(simulated.size)
    axes.plot(rows, simulated, color="tab:blue", label="simulated")
    axes.plot(rows, flight, color="tab:red", label="flight")
    for start, stop in _runs(~usable):
        axes.axvspan(start - 0.5, stop - 0.5, color="0.85", zorder=0)
    axes.set_xlabel("binned row")
    axes.set_ylabel("DN")
    axes.set_title(f"column {column}")
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def scatter_plot(simulated: np.ndarray, flight: np.ndarray, fit: dict, column: int, path: Path) -> Path:
    """Flight DN against simulated DN of the column with the best-fit line, r and slope (paper Fig. 11 right)."""
    figure, axes = plt.subplots(figsize=(5, 5))
    axes.plot(simulated, flight, ".", markersize=3, color="tab:blue")
    if np.isfinite(fit["slope"]):
        span = np.array([simulated.min(), simulated.max()], dtype=float)
        axes.plot(span, fit["slope"] * span + fit["intercept"], color="tab:red",
                  label=f"flight = {fit['slope']:.3f} x sim + {fit['intercept']:.1f}\nr = {fit['r']:.4f}")
        axes.legend(loc="upper left")
    axes.set_xlabel("simulated DN")
    axes.set_ylabel("flight DN")
    axes.set_title(f"column {column}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges where ``mask`` is True."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2], edges[1::2]))
