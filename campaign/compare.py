"""Estimators side by side: per class % valid, false-valid count and error mean + 3 sigma of every
estimator of a campaign (they ran on the same images and sensor draws, so the comparison is paired).

A *false-valid* case is one an estimator declared valid with a horizontal velocity error above
:data:`FALSE_VALID_ERROR_MPS` (the DIMES requirement): the failure that matters, reported next to
every % valid. Result rows without an ``estimator`` column (stores written before estimators were
pluggable) count as the reference estimator ``dimes``.
"""
from __future__ import annotations

import math

import pandas as pd

from .aggregate import site_table

FALSE_VALID_ERROR_MPS = 5.0
DEFAULT_ESTIMATOR = "dimes"
COMPARISON_COLUMNS = ["estimator", "class", "cases", "valid", "failed", "pct_valid", "false_valid",
                      "error_mean_3sigma_mps", "ellipse_fraction", "weighted_pct_valid", "weighted_error_mps"]


def with_estimator_column(results: pd.DataFrame) -> pd.DataFrame:
    """``results`` with an ``estimator`` column (``dimes`` when the store predates it)."""
    if results.empty or "estimator" in results.columns:
        return results
    return results.assign(estimator=DEFAULT_ESTIMATOR)


def estimator_names(results: pd.DataFrame) -> list[str]:
    """Estimator names in the order the rows first name them (the campaign's [[estimators]] order)."""
    results = with_estimator_column(results)
    return list(dict.fromkeys(results["estimator"])) if not results.empty else []


def false_valid_count(rows: pd.DataFrame, threshold_mps: float = FALSE_VALID_ERROR_MPS) -> int:
    """Rows declared valid whose velocity error exceeds ``threshold_mps``."""
    if rows.empty:
        return 0
    valid = rows["valid"].astype(bool) & (rows["status"] == "ok")
    errors = pd.to_numeric(rows["velocity_error_mps"], errors="coerce")
    return int((valid & (errors > threshold_mps)).sum())


def comparison_table(results: pd.DataFrame, fractions: dict[str, float], site_name: str,
                     class_order: list[str] | None = None, estimators: list[str] | None = None) -> pd.DataFrame:
    """The paper's table of every estimator with a false-valid column (:data:`COMPARISON_COLUMNS`):
    per estimator one row per class, then the site row (weighted totals, summed counts)."""
    results = with_estimator_column(results)
    names = estimators if estimators is not None else estimator_names(results)
    order = class_order or list(fractions)
    frames = []
    for name in names:
        rows = results[results["estimator"] == name] if not results.empty else results
        table = site_table(rows, fractions, site_name, class_order=order)
        counts = [false_valid_count(rows[rows["class_name"] == c] if not rows.empty else rows) for c in order]
        table.insert(0, "estimator", name)
        table.insert(table.columns.get_loc("pct_valid") + 1, "false_valid", counts + [sum(counts)])
        frames.append(table)
    if not frames:
        return pd.DataFrame(columns=COMPARISON_COLUMNS)
    return pd.concat(frames, ignore_index=True)[COMPARISON_COLUMNS]


def format_comparison(table: pd.DataFrame, markdown: bool = False) -> str:
    """One row per class (and the site's weighted row); per estimator: % valid, false-valid, error."""
    names = list(dict.fromkeys(table["estimator"]))
    classes = list(dict.fromkeys(table["class"]))
    headers = ["Class"]
    for name in names:
        headers += [f"{name} % valid", f"{name} false-valid", f"{name} err m/s"]
    body = []
    site = classes[-1] if classes else ""
    for class_name in classes:
        cells = [class_name if class_name != site else f"{site} (weighted)"]
        for name in names:
            row = table[(table["estimator"] == name) & (table["class"] == class_name)].iloc[0]
            if class_name == site:
                cells += [_fmt(row["weighted_pct_valid"], "{:.0f}%"), f"{int(row['false_valid'])}/{int(row['valid'])}",
                          _fmt(row["weighted_error_mps"], "{:.2f}")]
            else:
                cells += [_fmt(row["pct_valid"], "{:.0f}%"), f"{int(row['false_valid'])}/{int(row['valid'])}",
                          _fmt(row["error_mean_3sigma_mps"], "{:.2f}")]
        body.append(cells)
    if markdown:
        lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        return "\n".join(lines + ["| " + " | ".join(cells) + " |" for cells in body])
    widths = [max(len(h), *(len(cells[i]) for cells in body)) for i, h in enumerate(headers)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(headers, widths))]
    return "\n".join(lines + ["  ".join(c.rjust(w) for c, w in zip(cells, widths)) for cells in body])


COMPARISON_NOTE = (f"false-valid: valid cases with a velocity error above {FALSE_VALID_ERROR_MPS:g} m/s, "
                   "of the valid cases; err: mean + 3 sigma over valid cases (site row: ellipse-weighted)")


def _fmt(value, pattern: str) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else pattern.format(value)
