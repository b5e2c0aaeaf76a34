"""Estimators compared on shared axes (the report's comparison page).

``error_cdf.png``: one panel per class and one for the whole site (every class pooled), every panel
on the same x range (horizontal velocity error, m/s) and y range (fraction of the valid cases, 0-1),
one step line per estimator, the false-valid threshold dashed. ``valid_false_valid.png``: two panels
side by side on the same 0-100 % scale, grouped bars per class (and the site's ellipse-weighted %
valid), one bar per estimator: left % valid (valid/ran), right false-valid (false-valid/valid);
each bar carries its count text, so a 0 % bar is still seen, and a class where rows failed says how
many ("all 3 failed" where nothing ran); the CDF legend counts each estimator's valid and failed rows.
Font sizes and axis rules: :mod:`campaign.report.plots`.

The x range runs to 1.2 x the 95th percentile of the drawn errors (at least twice the false-valid
threshold, at most :data:`~campaign.report.plots.PLOT_LIMIT_MPS`): larger errors leave the axis, and a
non-finite error is never counted below any x (its line stays under 1); the panel title says how many
(a stored 1e30, inf or NaN never breaks a figure).
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from campaign.report.plots import (  # noqa: E402
    LABEL_POINTS,
    NOTE_POINTS,
    PLOT_LIMIT_MPS,
    TITLE_POINTS,
    bar_count_text,
    readable_axes,
    save,
)

FIGURE_DPI = 80
CDF_PANEL_INCHES = (4.0, 4.0)
BARS_FIGURE_INCHES = (12.0, 4.2)
LINE_STYLES = ("-", "--", "-.", ":")


def _valid_errors(rows: pd.DataFrame) -> np.ndarray:
    """Horizontal velocity errors (m/s) of the valid rows (status ok)."""
    if rows.empty:
        return np.zeros(0)
    valid = rows[(rows["status"] == "ok") & rows["valid"].astype(bool)]
    return pd.to_numeric(valid["velocity_error_mps"], errors="coerce").to_numpy(dtype=float)


def error_cdf(results: pd.DataFrame, classes: list[str], site: str, estimators: list[str], path: Path,
              false_valid_mps: float) -> Path:
    """Write :func:`error_cdf_figure` as a PNG at ``path`` (:data:`FIGURE_DPI`)."""
    return save(error_cdf_figure(results, classes, site, estimators, false_valid_mps), path, FIGURE_DPI)


def _failed_rows(rows: pd.DataFrame) -> int:
    """Rows that failed (status not 'ok': no answer)."""
    return int((rows["status"] != "ok").sum()) if not rows.empty else 0


def error_cdf_figure(results: pd.DataFrame, classes: list[str], site: str, estimators: list[str],
                     false_valid_mps: float) -> Figure:
    """The error CDF of each estimator's valid cases, per class and for the site, on shared axes (module
    docstring); an estimator's legend entry counts its valid and failed rows. Figure size:
    ``(len(classes) + 1) * CDF_PANEL_INCHES``."""
    panels = [*classes, site]
    groups = {panel: (results if panel == site else results[results["class_name"] == panel]) for panel in panels}
    errors = {(panel, name): _valid_errors(rows[rows["estimator"] == name])
              for panel, rows in groups.items() for name in estimators}
    pooled = np.concatenate([values[np.isfinite(values)] for values in errors.values()] + [np.zeros(0)])
    typical = float(np.quantile(pooled, 0.95)) if pooled.size else 0.0
    high = min(max(2.0 * false_valid_mps, 1.2 * typical), PLOT_LIMIT_MPS)
    width, height = CDF_PANEL_INCHES
    figure, axes_list = plt.subplots(1, len(panels), figsize=(width * len(panels), height), squeeze=False,
                                     sharex=True, sharey=True)
    for axes, panel in zip(axes_list[0], panels):
        not_finite = beyond = 0
        for number, name in enumerate(estimators):
            values = errors[(panel, name)]
            finite = np.sort(values[np.isfinite(values)])
            not_finite += values.size - finite.size
            beyond += int(np.count_nonzero(finite > high))
            style = {"linestyle": LINE_STYLES[number % len(LINE_STYLES)], "color": f"C{number}"}
            failed = _failed_rows(groups[panel][groups[panel]["estimator"] == name]) if not groups[panel].empty else 0
            label = f"{name} ({values.size} valid{f', {failed} failed' if failed else ''})"
            if finite.size:       # the fraction is of all valid cases: a non-finite error never reaches 1
                fraction = np.arange(1, finite.size + 1) / values.size
                ends = np.minimum(finite, 2.0 * PLOT_LIMIT_MPS)      # a 1e30 m/s step stays drawable
                axes.step(np.concatenate([[0.0], ends, [2.0 * PLOT_LIMIT_MPS]]),
                          np.concatenate([[0.0], fraction, fraction[-1:]]), where="post", label=label, **style)
            else:
                axes.plot([], [], label=label + ": none", **style)
        axes.axvline(false_valid_mps, color="tab:red", linestyle=":", linewidth=1,
                     label=f"false-valid > {false_valid_mps:g} m/s")
        notes = ([f"{beyond} beyond {high:.3g} m/s (off the axis)"] if beyond else []) + \
                ([f"{not_finite} not finite (never counted)"] if not_finite else [])
        title = f"{panel}{' (all classes)' if panel == site else ''}:\nerror CDF of valid cases"
        axes.set_title(title + ("\n" + "; ".join(notes) if notes else ""), fontsize=TITLE_POINTS)
        axes.set_xlabel("horizontal velocity error (m/s)", fontsize=LABEL_POINTS)
        axes.set_ylabel("fraction of valid cases, error <= x (0-1)", fontsize=LABEL_POINTS)
        axes.grid(alpha=0.3)
        axes.legend(fontsize=NOTE_POINTS, loc="lower right")
        readable_axes(axes)
    axes_list[0][0].set_xlim(0.0, high * 1.02)
    axes_list[0][0].set_ylim(0.0, 1.02)
    figure.suptitle(f"{site}: velocity error of each estimator ({', '.join(estimators)})", fontsize=TITLE_POINTS + 1)
    figure.tight_layout()
    return figure


def valid_false_valid_bars(comparison: pd.DataFrame, path: Path) -> Path:
    """Write :func:`valid_false_valid_bars_figure` as a PNG at ``path`` (:data:`FIGURE_DPI`)."""
    return save(valid_false_valid_bars_figure(comparison), path, FIGURE_DPI)


def valid_false_valid_bars_figure(comparison: pd.DataFrame) -> Figure:
    """% valid and false-valid per class (and site) and estimator as grouped bars on two panels with the same
    0-100 % y range, both with their tick labels (module docstring); a bar of a class where rows failed says
    how many ("all 3 failed" where nothing ran). ``comparison``:
    :func:`campaign.report.compare.comparison_table` (its last class is the site)."""
    estimators = list(dict.fromkeys(comparison["estimator"]))
    groups = list(dict.fromkeys(comparison["class"]))
    site = groups[-1]
    figure, axes_pair = plt.subplots(1, 2, figsize=BARS_FIGURE_INCHES, sharey=True)
    width = 0.8 / max(len(estimators), 1)
    positions = np.arange(len(groups), dtype=float)
    for number, name in enumerate(estimators):
        rows = comparison[comparison["estimator"] == name].set_index("class")
        offsets = positions - 0.4 + width * (number + 0.5)
        pct, fv_pct, pct_text, fv_text = [], [], [], []
        for group in groups:
            row = rows.loc[group]
            failed = int(row["failed"])
            valid, ran = int(row["valid"]), int(row["cases"]) - failed
            value = float(row["weighted_pct_valid"] if group == site else row["pct_valid"])
            pct.append(value if math.isfinite(value) else 0.0)
            if group == site and (ran or not failed):
                pct_text.append((f"{value:.0f}%" if math.isfinite(value) else "no %")
                                + (f"\n{failed} failed" if failed else ""))
            else:
                pct_text.append(bar_count_text(value, valid, ran, failed))
            false_valid = int(row["false_valid"])
            fv_pct.append(100.0 * false_valid / valid if valid else 0.0)
            fv_text.append(f"{false_valid}/{valid}" if valid else
                           (f"all {failed}\nfailed" if failed and not ran else "0 valid" if ran else "no cases"))
        for axes, heights, texts in ((axes_pair[0], pct, pct_text), (axes_pair[1], fv_pct, fv_text)):
            bars = axes.bar(offsets, heights, width=width * 0.95, color=f"C{number}", label=name)
            for bar, text in zip(bars, texts):
                axes.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + 1.0, text, ha="center",
                          va="bottom", fontsize=NOTE_POINTS)
    threshold = comparison.attrs.get("false_valid_mps", 5.0)
    for axes, ylabel, title, site_label in (
            (axes_pair[0], "% valid (valid / ran)", "% valid per class", f"{site}\n(ellipse-weighted)"),
            (axes_pair[1], "false-valid (% of valid cases)", f"false-valid (error > {threshold:g} m/s) per class",
             f"{site}\n(all classes)")):
        axes.set_xticks(positions, [group if group != site else site_label for group in groups])
        axes.set_xlim(-0.6, len(groups) - 0.4)
        axes.set_xlabel("appearance class", fontsize=LABEL_POINTS)
        axes.set_ylabel(ylabel, fontsize=LABEL_POINTS)
        axes.set_title(f"{title}: {', '.join(estimators)}", fontsize=TITLE_POINTS)
        axes.legend(fontsize=NOTE_POINTS, loc="upper center", ncol=min(len(estimators), 4))
        axes.grid(axis="y", alpha=0.3)
        readable_axes(axes)
    axes_pair[0].set_ylim(0.0, 130.0)             # room above 100 % for the count texts
    for axes in axes_pair:
        axes.set_yticks(range(0, 101, 20))
    figure.tight_layout()
    return figure
