"""Indices of a designed sweep (``[sweep] mode = "sobol"`` or ``"morris"``, campaign/configuration/sweep_designs.py)
from its points' outcomes, with SALib:

- ``sobol``: first-order ``S1`` and total ``ST`` Sobol indices (Saltelli/Jansen estimators,
  ``SALib.analyze.sobol``) with bootstrap confidence intervals. Variance-based indices assume independent
  inputs: true of a designed sweep, whose axes are sampled independently (not of a campaign's recorded
  trajectory parameters, which ``campaign sensitivity`` analyses with a given-data method instead);
- ``morris``: elementary effects (``SALib.analyze.morris``): ``mu_star`` (mean absolute effect, with its
  bootstrap interval) and ``sigma`` (spread: interaction or non-linearity), a screening.

Outcomes per point and estimator: the site's ellipse-weighted % valid, its false-valid count and its
weighted velocity error mean + 3 sigma (the sweep table's figures).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from campaign.configuration.sweep_designs import MORRIS_LEVELS

DESIGN_COLUMNS = ["estimator", "outcome", "input", "index", "value", "low", "high", "method"]


def sobol_indices(problem: dict, outcomes: np.ndarray, seed: int = 0, resamples: int = 1000,
                  confidence: float = 0.95) -> pd.DataFrame:
    """``S1`` and ``ST`` of every axis from the outcomes of a Saltelli design (rows in design order).

    Parameters
    ----------
    problem : dict
        The design's problem (names, bounds; campaign.configuration.sweep_designs.design_problem).
    outcomes : numpy.ndarray
        One outcome per design row, shape (rows,), finite.
    seed, resamples, confidence
        The bootstrap of the intervals.

    Returns
    -------
    pandas.DataFrame
        Columns ``input, index ("S1"/"ST"), value, low, high``; the interval is value -+ SALib's half width.
    """
    from SALib.analyze import sobol

    salib_problem = {key: problem[key] for key in ("num_vars", "names", "bounds")}
    result = sobol.analyze(salib_problem, np.asarray(outcomes, dtype=float), calc_second_order=False,
                           num_resamples=resamples, conf_level=confidence, seed=seed)
    rows = []
    for position, name in enumerate(problem["names"]):
        for index in ("S1", "ST"):
            value, half = float(result[index][position]), float(result[f"{index}_conf"][position])
            rows.append({"input": name, "index": index, "value": value, "low": value - half, "high": value + half})
    return pd.DataFrame(rows)


def morris_indices(problem: dict, values: np.ndarray, outcomes: np.ndarray, seed: int = 0,
                   resamples: int = 1000, confidence: float = 0.95) -> pd.DataFrame:
    """``mu_star`` (with interval) and ``sigma`` of every axis from a Morris design's points.

    Parameters
    ----------
    problem : dict
        The design's problem.
    values : numpy.ndarray
        The points' axis values in design order, shape (rows, axes).
    outcomes : numpy.ndarray
        One outcome per row, shape (rows,), finite.
    """
    from SALib.analyze import morris

    salib_problem = {key: problem[key] for key in ("num_vars", "names", "bounds")}
    result = morris.analyze(salib_problem, np.asarray(values, dtype=float), np.asarray(outcomes, dtype=float),
                            num_resamples=resamples, conf_level=confidence, num_levels=MORRIS_LEVELS, seed=seed)
    rows = []
    for position, name in enumerate(problem["names"]):
        mu_star, half = float(result["mu_star"][position]), float(result["mu_star_conf"][position])
        rows.append({"input": name, "index": "mu_star", "value": mu_star, "low": mu_star - half, "high": mu_star + half})
        sigma = float(result["sigma"][position])
        rows.append({"input": name, "index": "sigma", "value": sigma, "low": np.nan, "high": np.nan})
    return pd.DataFrame(rows)


def design_indices(mode: str, problem: dict, values: np.ndarray, outcomes: pd.DataFrame,
                   seed: int = 0) -> tuple[pd.DataFrame, list[str]]:
    """The indices of every (estimator, outcome) column of ``outcomes`` and notes on what was not analysed.

    Parameters
    ----------
    mode : str
        ``"sobol"`` or ``"morris"``.
    problem : dict
        The design's problem.
    values : numpy.ndarray
        The points' axis values in design order, shape (rows, axes).
    outcomes : pandas.DataFrame
        One row per design row (same order), columns ``(estimator, outcome)`` (a two-level column index).

    Returns
    -------
    (pandas.DataFrame, list of str)
        Rows :data:`DESIGN_COLUMNS`; notes (e.g. an outcome undefined at some points, or constant).
    """
    tables, notes = [], []
    for estimator, outcome in outcomes.columns:
        column = outcomes[(estimator, outcome)].to_numpy(dtype=float)
        if not np.all(np.isfinite(column)):
            notes.append(f"{estimator}: {outcome}: undefined at {int(np.count_nonzero(~np.isfinite(column)))} of "
                         f"{column.size} points (no valid case there): not analysed")
            continue
        if np.ptp(column) == 0:
            notes.append(f"{estimator}: {outcome}: {column[0]:g} at every point: nothing to attribute")
            continue
        table = (sobol_indices(problem, column, seed) if mode == "sobol"
                 else morris_indices(problem, values, column, seed))
        table.insert(0, "outcome", outcome)
        table.insert(0, "estimator", estimator)
        table["method"] = f"salib_{mode}"
        tables.append(table)
    if not tables:
        return pd.DataFrame(columns=DESIGN_COLUMNS), notes
    return pd.concat(tables, ignore_index=True)[DESIGN_COLUMNS], notes


def format_design_indices(table: pd.DataFrame, notes: list[str]) -> str:
    """The printed indices: per estimator and outcome one line per input (S1 and ST, or mu* and sigma, with
    their intervals), within 100 columns."""
    lines = []
    for (estimator, outcome), rows in table.groupby(["estimator", "outcome"], sort=False):
        lines.append(f"{estimator}: {outcome}")
        for name, per_input in rows.groupby("input", sort=False):
            parts = []
            for row in per_input.itertuples():
                interval = "" if np.isnan(row.low) else f" [{row.low:.2f}, {row.high:.2f}]"
                parts.append(f"{row.index} {row.value:6.3f}{interval}")
            lines.append(f"  {name:<44} " + "   ".join(parts))
    lines.extend(f"note: {note}" for note in notes)
    return "\n".join(lines) + "\n"
