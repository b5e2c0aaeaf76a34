"""Estimators side by side: per class % valid, false-valid count and error mean + 3 sigma of every
estimator of a campaign (they ran on the same images and sensor draws, so the comparison is paired).

A *false-valid* case is one an estimator declared valid with a horizontal velocity error above
``[campaign] false_valid_mps`` (default 5 m/s, the DIMES requirement; counted by :func:`site_table`): the failure that matters, reported next to
every % valid. Result rows without an ``estimator`` column (stores written before estimators were
pluggable) count as the reference estimator ``dimes``.
"""
from __future__ import annotations

import textwrap
from dataclasses import dataclass

import pandas as pd

from campaign.report.aggregate import FALSE_VALID_MPS, NOTE_WIDTH, TABLE_NOTE, format_number, render_grid, site_table

DEFAULT_ESTIMATOR = "dimes"
COMPARISON_COLUMNS = ["estimator", "class", "cases", "valid", "failed", "pct_valid", "false_valid",
                      "worst_valid_error_mps", "error_mean_3sigma_mps", "ellipse_fraction", "weighted_pct_valid", "weighted_error_mps",
                      "error_axis_mean_3sigma_mps", "floor_mean_3sigma_mps", "floor_axis_mean_3sigma_mps"]
"""The columns of ``table.csv``: the paper's table of each estimator, then the per-axis error statistic and the
attitude-knowledge floor's two statistics (:mod:`campaign.report.aggregate`; the site row's are weighted)."""


def with_estimator_column(results: pd.DataFrame) -> pd.DataFrame:
    """``results`` with an ``estimator`` column (``dimes`` when the store predates it)."""
    if results.empty or "estimator" in results.columns:
        return results
    return results.assign(estimator=DEFAULT_ESTIMATOR)


def estimator_names(results: pd.DataFrame) -> list[str]:
    """Estimator names in the order the rows first name them (the campaign's [[estimators]] order)."""
    results = with_estimator_column(results)
    return [str(name) for name in pd.unique(results["estimator"])] if not results.empty else []   # vectorised: 10^6 rows


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


LINE_WIDTH = 120
"""The side-by-side comparison is split into blocks of estimators so that no printed line is wider."""
GROUP_COLUMNS = ("% valid", "false-valid", "worst", "err")
"""Column headings of an estimator's group (worst valid error and error mean + 3 sigma in m/s)."""


def comparison_cells(table: pd.DataFrame, name: str, class_name: str, site: bool) -> list[str]:
    """One estimator's cells for one class (or the site's weighted row): % valid with its denominator
    (valid/ran), false-valid / valid, worst valid error, error mean + 3 sigma (m/s)."""
    row = table[(table["estimator"] == name) & (table["class"] == class_name)].iloc[0]
    if site:
        pct = format_number(row["weighted_pct_valid"], "{:.1f}%")
        error = format_number(row["weighted_error_mps"], "{:.2f}")
    else:
        ran = int(row["cases"]) - int(row["failed"])
        pct = format_number(row["pct_valid"], "{:.1f}%") + f" ({int(row['valid'])}/{ran})"
        error = format_number(row["error_mean_3sigma_mps"], "{:.2f}")
    return [pct, f"{int(row['false_valid'])}/{int(row['valid'])}", format_number(row["worst_valid_error_mps"], "{:.2f}"),
            error]


def format_comparison(table: pd.DataFrame, markdown: bool = False, width: int = LINE_WIDTH) -> str:
    """One row per class (and the site's weighted row); per estimator a group of columns: % valid
    (valid/ran; site: ellipse-weighted), false-valid / valid, worst valid error and error
    mean + 3 sigma (m/s). Plain text names each estimator on a line above its group and packs the
    groups into blocks each within ``width`` characters (one estimator per block when two do not fit;
    a name longer than its group is cut with "~" there and given in full on the block's title line).
    Markdown gives the same blocks, each a table whose first group column names the estimator."""
    names = list(dict.fromkeys(table["estimator"]))
    classes = list(dict.fromkeys(table["class"]))
    if not names:
        return ""
    site = classes[-1]
    labels = [c if c != site else f"{site} (weighted)" for c in classes]
    cells = {name: [comparison_cells(table, name, c, c == site) for c in classes] for name in names}
    label_width = max(len("Class"), *(len(label) for label in labels))
    widths = {name: [max(len(h), *(len(row[i]) for row in cells[name])) for i, h in enumerate(GROUP_COLUMNS)]
              for name in names}

    def group_width(name: str) -> int:      # its columns and the two spaces before each
        return sum(w + 2 for w in widths[name])

    blocks: list[list[str]] = []
    for name in names:
        if blocks and label_width + sum(group_width(n) for n in blocks[-1]) + group_width(name) <= width:
            blocks[-1].append(name)
        else:
            blocks.append([name])
    texts = []
    for number, block in enumerate(blocks, start=1):
        cut = any(len(name) > group_width(name) - 2 for name in block)
        title = (f"estimators {', '.join(block)} (block {number} of {len(blocks)})"
                 if len(blocks) > 1 or cut else "")
        body = [[label] + [cell for name in block for cell in cells[name][k]] for k, label in enumerate(labels)]
        if markdown:
            headers = ["Class"] + [h + " m/s" * (i > 1) if i else f"{name} {h}" for name in block
                                   for i, h in enumerate(GROUP_COLUMNS)]
            grid = render_grid(headers, body, markdown=True)
            texts.append((title + "\n\n" if title else "") + grid)
            continue
        column_widths = [label_width] + [w for name in block for w in widths[name]]
        group_line = " " * label_width
        for name in block:
            room = group_width(name) - 2
            shown = f"{name} (worst, err: m/s)" if len(name) + 21 <= room else name
            shown = shown if len(shown) <= room else name[:room - 1] + "~"
            group_line += "  " + shown.ljust(room, "-" if len(name) < room else " ")
        lines = [group_line.rstrip()]
        for row in [["Class", *[h for _ in block for h in GROUP_COLUMNS]], *body]:
            lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                                   for i, (c, w) in enumerate(zip(row, column_widths))).rstrip())
        texts.append("\n".join(([title] if title else []) + lines))
    return ("\n\n" if markdown else "\n").join(texts)


COMPARISON_NOTE = TABLE_NOTE + "\n" + textwrap.fill(
    "false-valid: valid cases with a velocity error above [campaign] false_valid_mps "
    f"(default {FALSE_VALID_MPS:g} m/s) / valid cases; worst valid: the largest error of a valid case; err: mean + 3 "
    "sigma over valid cases (site row: ellipse-weighted, as % valid).", NOTE_WIDTH)


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

