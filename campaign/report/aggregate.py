"""The paper's Tables 1 and 2: per appearance class cases, valid cases, % valid and velocity error
(mean + 3 sigma over valid cases), then ellipse-fraction weighted % valid and error for the site.

Weighted figures follow the paper: the site's ellipse-weighted % valid and error are
``sum(fraction * class value) / sum(fraction)`` over the classes with a positive fraction (Gusev:
0.59 * 3.90 + 0.41 * 3.48 + 0 * 3.29 = 3.73 m/s). A class's ``weighted_*`` columns in the data frame
are its contribution ``fraction * value``; the printed table never shows a contribution as a class's %
valid: a class row shows the class's own % valid (valid/ran), the site row the weighted figures.

Two error statistics (docs/estimators.md, "The error statistic"): the mean + 3 sigma of the horizontal
error magnitude (``error_mean_3sigma_mps``, the weighted figure's) and of the signed per-axis errors, east
and north pooled (``error_axis_mean_3sigma_mps``); beside them the attitude-knowledge floor, the same two
statistics of the error the attitude bias alone causes (``floor_mean_3sigma_mps``,
``floor_axis_mean_3sigma_mps``; :mod:`campaign.case.error_budget`).

Beside every % valid the table counts the false-valid cases (valid, horizontal error above
``[campaign] false_valid_mps``, default 5 m/s, the DIMES requirement) and gives the worst error
of a valid case: a velocity flagged valid but wrong is what the lander must never get.
"""
from __future__ import annotations

import math
import textwrap

import numpy as np
import pandas as pd

from campaign.store.result_schema import RESULTS_SCHEMA, ResultSchemaError

TABLE_COLUMNS = ["class", "cases", "valid", "failed", "pct_valid", "error_mean_3sigma_mps", "false_valid",
                 "worst_valid_error_mps", "ellipse_fraction", "weighted_pct_valid", "weighted_error_mps",
                 "error_axis_mean_3sigma_mps", "floor_mean_3sigma_mps", "floor_axis_mean_3sigma_mps"]
AXIS_STATISTIC_COLUMNS = TABLE_COLUMNS[-3:]
FALSE_VALID_MPS = 5.0
COLUMNS_READ = ("class_name", "status", "valid", "velocity_error_mps")
"""The result columns the tables are computed from (declared in :mod:`campaign.store.result_schema`)."""
AXIS_COLUMNS_READ = ("estimate_velocity_east_mps", "estimate_velocity_north_mps", "truth_velocity_east_mps",
                     "truth_velocity_north_mps", "attitude_floor_mps", "sensor_attitude_bias_east_rad",
                     "sensor_attitude_bias_north_rad")
"""Read when present (a table without them has NaN per-axis and floor statistics)."""
assert set(COLUMNS_READ + AXIS_COLUMNS_READ) <= set(RESULTS_SCHEMA.names), "aggregate.py reads an undeclared result column"


def mean_plus_3_sigma(errors_mps: np.ndarray) -> float:
    """Mean + 3 sample standard deviations (ddof=1; ddof=0 for a single value); NaN when empty."""
    errors_mps = np.asarray(errors_mps, dtype=float)
    errors_mps = errors_mps[np.isfinite(errors_mps)]
    if errors_mps.size == 0:
        return math.nan
    with np.errstate(over="ignore", invalid="ignore"):    # 1e200 m/s errors: an infinite statistic, no warning
        spread = errors_mps.std(ddof=1) if errors_mps.size > 1 else 0.0
        return float(errors_mps.mean() + 3.0 * spread)


def site_table(results: pd.DataFrame, fractions: dict[str, float], site_name: str,
               class_order: list[str] | None = None, false_valid_mps: float = FALSE_VALID_MPS) -> pd.DataFrame:
    """One row per class plus a final site row (columns :data:`TABLE_COLUMNS`).

    Parameters
    ----------
    results : DataFrame
        Result rows (:data:`~campaign.store.result_schema.RESULTS_SCHEMA`); the tables read ``class_name``,
        ``status`` ('ok' or 'failed'), ``valid`` and ``velocity_error_mps`` (m/s).
    fractions : dict
        Ellipse fraction of each class (summing to 1).
    false_valid_mps : float
        A valid case with a larger horizontal error is counted as false-valid (kept in
        ``table.attrs["false_valid_mps"]`` for the column heading).
    """
    missing = [name for name in COLUMNS_READ if not results.empty and name not in results.columns]
    if missing:
        raise ResultSchemaError(f"results lack the declared column {missing[0]!r}")
    order = class_order or list(fractions)
    rows = []
    for class_name in order:
        members = results[results["class_name"] == class_name] if not results.empty else results
        cases = int(len(members))
        ok = members[members["status"] == "ok"] if cases else members
        valid_mask = ok["valid"].astype(bool) if cases else pd.Series(dtype=bool)
        valid = int(valid_mask.sum()) if cases else 0
        pct_valid = 100.0 * valid / len(ok) if len(ok) else math.nan      # failed rows are left out (TABLE_NOTE)
        valid_errors = ok.loc[valid_mask, "velocity_error_mps"].to_numpy(dtype=float) if valid else np.zeros(0)
        error = mean_plus_3_sigma(valid_errors) if valid else math.nan
        fraction = float(fractions[class_name])
        rows.append({
            "class": class_name, "cases": cases, "valid": valid, "failed": int(cases - len(ok)),
            "pct_valid": pct_valid, "error_mean_3sigma_mps": error,
            "false_valid": int(np.count_nonzero(valid_errors > false_valid_mps)),
            "worst_valid_error_mps": float(np.nanmax(valid_errors)) if np.isfinite(valid_errors).any() else math.nan,
            "ellipse_fraction": fraction,
            "weighted_pct_valid": _weighted(fraction, pct_valid), "weighted_error_mps": _weighted(fraction, error),
            **axis_statistics(ok.loc[valid_mask] if valid else ok.iloc[0:0]),
        })
    table = pd.DataFrame(rows, columns=TABLE_COLUMNS)
    total = {
        "class": site_name, "cases": int(table["cases"].sum()), "valid": int(table["valid"].sum()),
        "failed": int(table["failed"].sum()), "pct_valid": math.nan, "error_mean_3sigma_mps": math.nan,
        "false_valid": int(table["false_valid"].sum()),
        "worst_valid_error_mps": float(table["worst_valid_error_mps"].max()) if table["worst_valid_error_mps"].notna().any() else math.nan,
        "ellipse_fraction": float(table["ellipse_fraction"].sum()),
        "weighted_pct_valid": weighted_mean(table["ellipse_fraction"], table["pct_valid"]),
        "weighted_error_mps": weighted_mean(table["ellipse_fraction"], table["error_mean_3sigma_mps"]),
        **{name: weighted_mean(table["ellipse_fraction"], table[name]) for name in AXIS_STATISTIC_COLUMNS},
    }
    table = pd.concat([table, pd.DataFrame([total])], ignore_index=True)
    table.attrs["false_valid_mps"] = float(false_valid_mps)
    return table


def axis_statistics(valid: pd.DataFrame) -> dict[str, float]:
    """Mean + 3 sigma of the valid cases' signed east and north errors pooled, and of the attitude floor
    (its magnitude ``attitude_floor_mps``; per axis, its components ``floor * (-b_north, b_east) / tilt``,
    the directions of ``V (-tan b_north, tan b_east)``); NaN where the columns are missing."""
    answer = dict.fromkeys(AXIS_STATISTIC_COLUMNS, math.nan)
    if valid.empty or any(name not in valid.columns for name in AXIS_COLUMNS_READ):
        return answer
    def column(name: str) -> np.ndarray:
        return valid[name].to_numpy(dtype=float)
    east = column("estimate_velocity_east_mps") - column("truth_velocity_east_mps")
    north = column("estimate_velocity_north_mps") - column("truth_velocity_north_mps")
    floor, bias_east, bias_north = column("attitude_floor_mps"), column("sensor_attitude_bias_east_rad"), column("sensor_attitude_bias_north_rad")
    tilt = np.hypot(bias_east, bias_north)
    with np.errstate(invalid="ignore", divide="ignore"):
        floor_east, floor_north = np.where(tilt > 0, -floor * bias_north / tilt, 0.0), np.where(tilt > 0, floor * bias_east / tilt, 0.0)
    answer.update(error_axis_mean_3sigma_mps=mean_plus_3_sigma(np.concatenate([east, north])),
                  floor_mean_3sigma_mps=mean_plus_3_sigma(floor),
                  floor_axis_mean_3sigma_mps=mean_plus_3_sigma(np.concatenate([floor_east, floor_north])))
    return answer


def weighted_mean(fractions: pd.Series, values: pd.Series) -> float:
    """``sum(fraction * value) / sum(fraction)`` over the classes with a positive ellipse fraction (NaN when
    one of them has no value, e.g. no case ran, or when no class has a positive fraction)."""
    weights = fractions.to_numpy(dtype=float)
    numbers = values.to_numpy(dtype=float)
    inside = weights > 0.0
    if not inside.any() or np.isnan(numbers[inside]).any():
        return math.nan
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.sum(weights[inside] * numbers[inside]) / np.sum(weights[inside]))


def _weighted(fraction: float, value: float) -> float:
    if fraction == 0.0:
        return 0.0  # a class outside the ellipse contributes nothing, even with no valid cases
    return fraction * value


def format_table(table: pd.DataFrame, markdown: bool = False) -> str:
    """Human-readable table (plain text, or GitHub Markdown); its footer is :data:`TABLE_NOTE`.

    A class row gives the class's own % valid with its denominator, ``valid/ran`` (ran = cases - failed);
    the last (site) row gives the ellipse-weighted % valid and error (:func:`weighted_mean`) and the
    summed counts. False-valid stands next to every % valid. A second grid gives both error statistics
    and the attitude floor's (:func:`axis_statistics`) per class."""
    threshold = table.attrs.get("false_valid_mps", FALSE_VALID_MPS)
    headers = ["Class", "Cases", "Valid", "Failed", "% valid (valid/ran)", f"False-valid (>{threshold:g} m/s)",
               "Error m/s mean+3s", "Worst valid m/s", "% ellipse"]
    body, statistics = [], []
    last = len(table) - 1
    for position, (_, row) in enumerate(table.iterrows()):
        site = position == last
        if site:
            pct = format_number(row["weighted_pct_valid"], "{:.1f}%") + " weighted"
            error = format_number(row["weighted_error_mps"], "{:.2f}") + " weighted"
        else:
            ran = int(row["cases"]) - int(row["failed"])
            pct = format_number(row["pct_valid"], "{:.1f}%") + f" ({int(row['valid'])}/{ran})"
            error = format_number(row["error_mean_3sigma_mps"], "{:.2f}")
        magnitude = row["weighted_error_mps"] if site else row["error_mean_3sigma_mps"]
        statistics.append([format_number(value, "{:.2f}") for value in (magnitude, *row[AXIS_STATISTIC_COLUMNS])])
        body.append([
            str(row["class"]), str(int(row["cases"])), str(int(row["valid"])), str(int(row["failed"])), pct,
            f"{int(row['false_valid'])}/{int(row['valid'])}", error, format_number(row["worst_valid_error_mps"], "{:.2f}"),
            format_number(100 * row["ellipse_fraction"], "{:.0f}%"),
        ])
    # both statistics and the floor's, one row each (classes as columns: no row starts with a class name)
    statistics_rows = [[label] + [cells[index] for cells in statistics] for index, label in
                       enumerate(("error |v|", "error per axis", "floor |v|", "floor per axis"))]
    statistics_headers = ["m/s mean+3s"] + [str(name) for name in table["class"]]
    return (render_grid(headers, body, markdown) + "\n" + ("\n" if markdown else "")
            + render_grid(statistics_headers, statistics_rows, markdown))


NOTE_WIDTH = 118
"""Footers are wrapped to this many characters (every printed line within 120 columns)."""
SIGMA_NOTE = ("error = mean + 3 sigma of the horizontal velocity error over the valid cases with a finite error "
              "(its magnitude; in the grid below the table also per axis, of the signed east and north errors pooled, "
              "and the floor: both statistics of the error the attitude-knowledge bias alone causes), "
              "sigma the sample standard deviation (ddof=1, n-1 in the denominator; 0 for a single case), not "
              "the population one (ddof=0)")
TABLE_NOTE = textwrap.fill("denominators: % valid = valid / (cases - failed) (shown as valid/ran); false-valid = valid cases with an error "
              "above the threshold / valid cases; worst valid over the valid cases; " + SIGMA_NOTE + "; site row: "
              "% valid and error ellipse-weighted, sum(fraction * class value) / sum(fraction) over the classes "
              "with a positive ellipse fraction, counts summed; failed rows (the case's simulation or the "
              "estimator failed) enter none of them, only Failed", NOTE_WIDTH)


def render_grid(headers: list[str], body: list[list[str]], markdown: bool = False) -> str:
    """Rows of cell texts under ``headers``: right-aligned plain-text columns, or a GitHub Markdown table."""
    if markdown:        # a quoted name holding |, ` or a newline must not break the table (one line, escaped)
        def cell(text: str) -> str:
            return "<br>".join(str(text).replace("|", "\\|").replace("`", "\\`").splitlines() or [""])
        lines = ["| " + " | ".join(map(cell, headers)) + " |", "|" + "---|" * len(headers)]
        return "\n".join(lines + ["| " + " | ".join(map(cell, cells)) + " |" for cells in body])
    widths = [max(len(h), *(len(cells[i]) for cells in body)) for i, h in enumerate(headers)]

    def line(cells: list[str]) -> str:     # first column (the class) left-aligned, numbers right-aligned
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return "\n".join([line(headers)] + [line(cells) for cells in body])


def format_number(value, pattern: str) -> str:
    """``pattern.format(value)``, "n/a" for a missing or NaN value, ``inf``/``-inf`` for an infinite one and
    three significant digits for a magnitude of 1e7 or more (a stored 1e30 m/s stays one short cell)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if isinstance(value, (float, np.floating)) and (math.isinf(value) or abs(float(value)) >= 1e7):
        return f"{float(value):.3g}" + ("%" if pattern.endswith("%") else "")
    return pattern.format(value)
