"""PNG plots of a sweep's sensitivity table: each metric against each axis.

One figure per (metric, axis): ``plots/<metric>-vs-<axis field>.png`` with ``pct_valid`` (% valid)
and ``error_mean_3sigma_mps`` (velocity error mean + 3 sigma over valid cases, m/s). Each appearance
class is one line, the ellipse-weighted site total a black dashed line; with several estimators, each
estimator has its own line style and its name in the legend. The points plotted against an
axis are those whose *other* axes equal the first point's values (for a grid: the other axes held at
their first value); when that leaves fewer than two points (a list sweep whose axes vary together),
every point is plotted against the axis. Numeric axes are drawn to scale, others (booleans, strings)
as categories in sweep order.

Heat maps (grid sweeps with two or more axes): for every pair of axes and every estimator,
``plots/heatmap-<estimator>-<axis>-x-<axis>.png``, the other axes held at the first point's values.
Top row: % valid of each class (valid/ran) and the site's ellipse-weighted % valid; bottom row: false-valid
as % of the valid cases, with the count; one cell per grid point, every panel on the same 0-100 %
colour scale, each cell's number written in it (a point with 0 % valid is a dark cell reading "0%");
a point without a value (no case ran, no valid case) is grey and reads "n/a".
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

METRICS = {  # class column, site (weighted) column, axis label
    "pct_valid": ("pct_valid", "weighted_pct_valid", "% valid"),
    "error_mean_3sigma_mps": ("error_mean_3sigma_mps", "weighted_error_mps", "velocity error mean+3 sigma (m/s)"),
}


def points_along(spec, axis: str) -> list:
    """The sweep points plotted against ``axis`` (see the module docstring), sorted by its value."""
    anchor = spec.points[0].values
    others = [name for name in spec.axis_names if name != axis]
    chosen = [p for p in spec.points if all(p.values[name] == anchor[name] for name in others)]
    if len(chosen) < 2:
        chosen = list(spec.points)
    if _numeric(axis, spec):
        chosen = sorted(chosen, key=lambda p: p.values[axis])
    return chosen


def _numeric(axis: str, spec) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in spec.axes[axis])


def write_sweep_plots(spec, table: pd.DataFrame, out_dir: Path) -> list[Path]:
    """Write every (metric, axis) figure; return their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    classes = [entry.name for entry in spec.base.site.classes if spec.base.cases_per_class.get(entry.name, 0) > 0]
    site_name = spec.base.site.name
    paths = []
    for axis in spec.axis_names:
        points = points_along(spec, axis)
        numeric = _numeric(axis, spec)
        values = [p.values[axis] for p in points]
        xs = values if numeric else list(range(len(points)))
        held = {k: v for k, v in spec.points[0].values.items() if k != axis}
        estimators = list(dict.fromkeys(table["estimator"])) if "estimator" in table.columns else [None]
        for metric, (class_column, site_column, label) in METRICS.items():
            figure, axes = plt.subplots(figsize=(6.0, 4.0))
            for number, estimator in enumerate(estimators):
                prefix = f"{estimator}: " if len(estimators) > 1 else ""
                style = ("-", ":", "-.", (0, (5, 1)))[number % 4]
                for colour, name in enumerate(classes):
                    ys = [_cell(table, p.point_id, name, class_column, estimator) for p in points]
                    axes.plot(xs, ys, marker="o", linestyle=style, color=f"C{colour}", label=prefix + name)
                ys = [_cell(table, p.point_id, site_name, site_column, estimator) for p in points]
                axes.plot(xs, ys, marker="s", linestyle=style if len(estimators) > 1 else "--", color="black",
                          label=f"{prefix}{site_name} (ellipse-weighted)")
            if not numeric:
                axes.set_xticks(xs, [str(v) for v in values])
            if metric == "pct_valid":
                axes.set_ylim(-2, 102)
            axes.set_xlabel(axis)
            axes.set_ylabel(label)
            held_text = ", ".join(f"{k}={v}" for k, v in held.items())
            axes.set_title(f"{label} vs {axis}" + (f"\n({held_text})" if held_text and len(points) < len(spec.points)
                                                    else ""), fontsize=8)
            axes.grid(alpha=0.3)
            axes.legend(fontsize=7)
            figure.tight_layout()
            path = out_dir / f"{metric}-vs-{axis}.png"
            figure.savefig(path, dpi=90)
            plt.close(figure)
            paths.append(path)
    if spec.mode == "grid":
        paths += write_heat_maps(spec, table, out_dir)
    return paths


def grid_pairs(spec) -> list[tuple[str, str]]:
    """Pairs of axes (in axis order) that both have two or more values."""
    axes = [name for name in spec.axis_names if len(spec.axes[name]) >= 2]
    return [(a, b) for position, a in enumerate(axes) for b in axes[position + 1:]]


def heat_cell(table: pd.DataFrame, point_id: str | None, class_name: str, site: bool,
              estimator) -> tuple[float, float, str, str]:
    """(% valid, false-valid % of valid, % valid text, false-valid text) of one grid cell (NaN, "n/a"
    when the point or its class has no value)."""
    rows = table[(table["point_id"] == point_id) & (table["class"] == class_name)] if point_id else table.iloc[:0]
    if estimator is not None and len(rows):
        rows = rows[rows["estimator"] == estimator]
    if not len(rows):
        return math.nan, math.nan, "n/a", "n/a"
    row = rows.iloc[0]
    pct = float(row["weighted_pct_valid"] if site else row["pct_valid"])
    valid, ran = int(row["valid"]), int(row["cases"]) - int(row["failed"])
    false_valid = int(row["false_valid"])
    pct_text = "n/a" if not math.isfinite(pct) else f"{pct:.0f}%" + ("" if site else f"\n{valid}/{ran}")
    return (pct if math.isfinite(pct) else math.nan, 100.0 * false_valid / valid if valid else math.nan, pct_text,
            f"{false_valid}/{valid}" if valid else "n/a")


def write_heat_maps(spec, table: pd.DataFrame, out_dir: Path) -> list[Path]:
    """The heat maps of a grid sweep (module docstring); return their paths."""
    classes = [entry.name for entry in spec.base.site.classes if spec.base.cases_per_class.get(entry.name, 0) > 0]
    site_name = spec.base.site.name
    estimators = list(dict.fromkeys(table["estimator"])) if "estimator" in table.columns and len(table) else [None]
    anchor = spec.points[0].values
    colours = plt.get_cmap("viridis").with_extremes(bad="0.75")
    paths = []
    for x_axis, y_axis in grid_pairs(spec):
        xs, ys = list(spec.axes[x_axis]), list(spec.axes[y_axis])
        others = {k: v for k, v in anchor.items() if k not in (x_axis, y_axis)}
        where = {(p.values[x_axis], p.values[y_axis]): p.point_id for p in spec.points
                 if all(p.values[k] == v for k, v in others.items())}
        panels = [(name, False) for name in classes] + [(site_name, True)]
        for estimator in estimators:
            figure, axes_grid = plt.subplots(2, len(panels), figsize=(3.6 * len(panels), 6.4), squeeze=False)
            for column, (name, site) in enumerate(panels):
                cells = [[heat_cell(table, where.get((x, y)), name, site, estimator) for x in xs] for y in ys]
                for row, (index, label) in enumerate(((0, "% valid"), (1, "false-valid, % of valid"))):
                    axes = axes_grid[row][column]
                    values = np.array([[cell[index] for cell in line] for line in cells], dtype=float)
                    image = axes.imshow(np.ma.masked_invalid(values), cmap=colours, vmin=0.0, vmax=100.0,
                                        origin="lower", aspect="auto")
                    for j, line in enumerate(cells):
                        for i, cell in enumerate(line):
                            value = values[j, i]
                            axes.text(i, j, cell[2 + index], ha="center", va="center", fontsize=7,
                                      color="white" if math.isfinite(value) and value < 60 else "black")
                    axes.set_xticks(range(len(xs)), [str(v) for v in xs], fontsize=7)
                    axes.set_yticks(range(len(ys)), [str(v) for v in ys], fontsize=7)
                    axes.set_xlabel(x_axis, fontsize=7)
                    axes.set_ylabel(y_axis, fontsize=7)
                    kind = f"{name} ellipse-weighted" if site and index == 0 else name
                    axes.set_title(f"{estimator + ': ' if estimator else ''}{kind} {label}", fontsize=8)
                    figure.colorbar(image, ax=axes, label="%", fraction=0.046)
            held = ", ".join(f"{k}={v}" for k, v in others.items())
            figure.suptitle(f"{site_name} sweep: % valid and false-valid over {x_axis} x {y_axis}"
                            + (f" ({held})" if held else ""), fontsize=9)
            figure.tight_layout()
            prefix = f"{estimator}-" if estimator is not None else ""
            path = out_dir / f"heatmap-{prefix}{x_axis}-x-{y_axis}.png"
            figure.savefig(path, dpi=80)
            plt.close(figure)
            paths.append(path)
    return paths


def _cell(table: pd.DataFrame, point_id: str, class_name: str, column: str, estimator=None) -> float:
    rows = table[(table["point_id"] == point_id) & (table["class"] == class_name)]
    if estimator is not None:
        rows = rows[rows["estimator"] == estimator]
    value = float(rows[column].iloc[0]) if len(rows) else float("nan")
    return value if math.isfinite(value) else float("nan")      # an infinite stored statistic is not drawn
