"""Estimators side by side: per class % valid, false-valid count and error mean + 3 sigma of every
estimator of a campaign (they ran on the same images and sensor draws, so the comparison is paired).

A *false-valid* case is one an estimator declared valid with a horizontal velocity error above
``[campaign] false_valid_mps`` (default 5 m/s, the DIMES requirement; counted by :func:`site_table`): the failure that matters, reported next to
every % valid. Result rows without an ``estimator`` column (stores written before estimators were
pluggable) count as the reference estimator ``dimes``.
"""
from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from campaign.report.aggregate import FALSE_VALID_MPS, TABLE_NOTE, format_number, render_grid, site_table

DEFAULT_ESTIMATOR = "dimes"
COMPARISON_COLUMNS = ["estimator", "class", "cases", "valid", "failed", "pct_valid", "false_valid",
                      "worst_valid_error_mps", "error_mean_3sigma_mps", "ellipse_fraction", "weighted_pct_valid", "weighted_error_mps"]


def with_estimator_column(results: pd.DataFrame) -> pd.DataFrame:
    """``results`` with an ``estimator`` column (``dimes`` when the store predates it)."""
    if results.empty or "estimator" in results.columns:
        return results
    return results.assign(estimator=DEFAULT_ESTIMATOR)


def estimator_names(results: pd.DataFrame) -> list[str]:
    """Estimator names in the order the rows first name them (the campaign's [[estimators]] order)."""
    results = with_estimator_column(results)
    return list(dict.fromkeys(results["estimator"])) if not results.empty else []


def comparison_table(results: pd.DataFrame, fractions: dict[str, float], site_name: str,
                     class_order: list[str] | None = None, estimators: list[str] | None = None,
                     false_valid_mps: float = FALSE_VALID_MPS) -> pd.DataFrame:
    """The paper's table of every estimator with false-valid counts (:data:`COMPARISON_COLUMNS`):
    per estimator one row per class, then the site row (weighted totals, summed counts)."""
    results = with_estimator_column(results)
    names = estimators if estimators is not None else estimator_names(results)
    order = class_order or list(fractions)
    frames = []
    for name in names:
        rows = results[results["estimator"] == name] if not results.empty else results
        table = site_table(rows, fractions, site_name, class_order=order, false_valid_mps=false_valid_mps)
        table.insert(0, "estimator", name)
        frames.append(table)
    if not frames:
        return pd.DataFrame(columns=COMPARISON_COLUMNS)
    table = pd.concat(frames, ignore_index=True)[COMPARISON_COLUMNS]
    table.attrs["false_valid_mps"] = float(false_valid_mps)
    return table


def format_comparison(table: pd.DataFrame, markdown: bool = False) -> str:
    """One row per class (and the site's weighted row); per estimator: % valid, false-valid, error."""
    names = list(dict.fromkeys(table["estimator"]))
    classes = list(dict.fromkeys(table["class"]))
    headers = ["Class"]
    for name in names:
        headers += [f"{name} % valid", f"{name} false-valid", f"{name} worst valid m/s", f"{name} err m/s"]
    body = []
    site = classes[-1] if classes else ""
    for class_name in classes:
        cells = [class_name if class_name != site else f"{site} (weighted)"]
        for name in names:
            row = table[(table["estimator"] == name) & (table["class"] == class_name)].iloc[0]
            if class_name == site:
                cells += [format_number(row["weighted_pct_valid"], "{:.0f}%"), f"{int(row['false_valid'])}/{int(row['valid'])}",
                          format_number(row["worst_valid_error_mps"], "{:.2f}"), format_number(row["weighted_error_mps"], "{:.2f}")]
            else:
                cells += [format_number(row["pct_valid"], "{:.0f}%"), f"{int(row['false_valid'])}/{int(row['valid'])}",
                          format_number(row["worst_valid_error_mps"], "{:.2f}"), format_number(row["error_mean_3sigma_mps"], "{:.2f}")]
        body.append(cells)
    return render_grid(headers, body, markdown)


COMPARISON_NOTE = ("false-valid: valid cases with a velocity error above [campaign] false_valid_mps "
                   f"(default {FALSE_VALID_MPS:g} m/s), of the valid cases; worst valid: the largest error of a "
                   "valid case; err: mean + 3 sigma over valid cases (site row: ellipse-weighted); " + TABLE_NOTE)


@dataclass(frozen=True)
class EstimatorCounts:
    """One estimator's result rows: valid, invalid (ran, answered not valid) and failed (status 'failed':
    the case's simulation or the estimator failed), and the first failed row as one line."""

    name: str
    rows: int
    valid: int
    invalid: int
    failed: int
    first_failure: str      # "case N (reason): error", "" when nothing failed


def estimator_counts(results: pd.DataFrame) -> list[EstimatorCounts]:
    """Per estimator (in [[estimators]] order) its valid / invalid / failed row counts, from result rows
    (a sweep's rows, with ``point_id``, name the point of the first failure)."""
    results = with_estimator_column(results)
    counts = []
    for name in estimator_names(results):
        rows = results[results["estimator"] == name]
        ok = rows["status"] == "ok"
        valid = int((ok & rows["valid"].eq(True)).sum())
        failed = rows[~ok]
        first = ""
        if len(failed):
            row = failed.iloc[0]
            text = row.get("error")
            error = " ".join(text.split()) if isinstance(text, str) else ""
            where = " ".join(f"{key.split('_')[0]} {row[key]}" for key in ("point_id", "case_id") if key in failed.columns)
            reason = row.get("reason") if isinstance(row.get("reason"), str) and row.get("reason") else "failed"
            first = f"{where} ({reason}): {error[:240] or 'no error text'}".lstrip()
        counts.append(EstimatorCounts(name, len(rows), valid, int(ok.sum()) - valid, len(failed), first))
    return counts


def counts_line(counts: list[EstimatorCounts]) -> str:
    """The headline's per-estimator counts: ``estimator rows: dimes 3 valid, 0 invalid, 0 failed; ...``."""
    return "estimator rows: " + "; ".join(f"{c.name} {c.valid} valid, {c.invalid} invalid, {c.failed} failed"
                                          for c in counts)


def failure_lines(counts: list[EstimatorCounts]) -> list[str]:
    """One stderr line per estimator with failed rows: its name, the count and the first reason."""
    return [f"estimator {c.name}: {c.failed} of {c.rows} rows failed; first: {c.first_failure}"
            for c in counts if c.failed]

