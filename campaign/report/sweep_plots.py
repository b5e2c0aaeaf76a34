"""PNG plots of a sweep's sensitivity table: each metric against each axis.

One figure per (metric, axis): ``plots/<metric>-vs-<axis field>.png`` with ``pct_valid`` (% valid)
and ``error_mean_3sigma_mps`` (velocity error mean + 3 sigma over valid cases, m/s). Each appearance
class is one line, the ellipse-weighted site total a black dashed line; with several estimators, each
estimator has its own line style and its name in the legend. The points plotted against an
axis are those whose *other* axes equal the first point's values (for a grid: the other axes held at
their first value); when that leaves fewer than two points (a list sweep whose axes vary together),
every point is plotted against the axis. Numeric axes are drawn to scale, others (booleans, strings)
as categories in sweep order.
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
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
    return paths


def _cell(table: pd.DataFrame, point_id: str, class_name: str, column: str, estimator=None) -> float:
    rows = table[(table["point_id"] == point_id) & (table["class"] == class_name)]
    if estimator is not None:
        rows = rows[rows["estimator"] == estimator]
    value = float(rows[column].iloc[0]) if len(rows) else float("nan")
    return value if math.isfinite(value) else float("nan")      # an infinite stored statistic is not drawn
