"""The indices of a designed sweep (``[sweep] mode = "sobol"`` or ``"morris"``): per site, estimator and
outcome, Sobol ``S1``/``ST`` or Morris ``mu_star``/``sigma`` of every axis with their intervals
(:mod:`campaign.analysis.design_indices`), from the sweep table's site rows in design order.

Outcomes per point: ``pct_valid`` (the site's ellipse-weighted % valid), ``false_valid`` (false-valid cases
of the site) and ``error_mps`` (the site's ellipse-weighted velocity error mean + 3 sigma).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from campaign.analysis.design_indices import DESIGN_COLUMNS, design_indices, format_design_indices
from campaign.configuration.sweep_designs import DESIGN_MODES, design_problem

OUTCOME_COLUMNS = {"pct_valid": "weighted_pct_valid", "false_valid": "false_valid", "error_mps": "weighted_error_mps"}
"""Outcome name -> the sweep table's site-row column it is read from."""
FILE_NAME = "design_indices.csv"


def design_outcomes(point_ids: list[str], site: str, table: pd.DataFrame) -> pd.DataFrame:
    """One row per point of ``point_ids`` (design order), columns ``(estimator, outcome)``: the site row of
    each point and estimator in the sweep table ``table`` (NaN where a point has no row)."""
    site_rows = table[table["class"] == site]
    columns = {}
    for estimator in dict.fromkeys(site_rows["estimator"]):
        rows = site_rows[site_rows["estimator"] == estimator].set_index("point_id")
        for outcome, column in OUTCOME_COLUMNS.items():
            columns[(estimator, outcome)] = rows[column].reindex(point_ids).to_numpy(dtype=float)
    return pd.DataFrame(columns, index=pd.Index(point_ids, name="point_id"))


def sweep_design_indices(spec, table: pd.DataFrame) -> tuple[pd.DataFrame, str]:
    """The indices of every site of a designed sweep (rows :data:`DESIGN_COLUMNS` plus ``site``) and their
    printed text; an empty frame and "" for a grid or list sweep."""
    if spec.mode not in DESIGN_MODES:
        return pd.DataFrame(columns=["site", *DESIGN_COLUMNS]), ""
    frames, parts = [], []
    for view in spec.site_views():
        problem = design_problem(view.axes, str(spec.source))
        point_ids = [point.point_id for point in view.points]
        values = np.array([[point.values[name] for name in problem["names"]] for point in view.points], dtype=float)
        outcomes = design_outcomes(point_ids, view.base.site.name, table)
        indices, notes = design_indices(spec.mode, problem, values, outcomes, seed=spec.design_seed)
        indices.insert(0, "site", view.base.site.name)
        frames.append(indices)
        what = ("first-order S1 and total ST Sobol indices" if spec.mode == "sobol"
                else "Morris mean absolute elementary effect mu_star and its spread sigma")
        parts.append(f"{view.base.site.name}: {what} of the site's outcomes over {len(point_ids)} points "
                     f"({spec.design_samples} samples, 95 % bootstrap intervals)\n" + format_design_indices(indices, notes))
    return pd.concat(frames, ignore_index=True), "\n".join(parts)


def write_design_indices(spec, table: pd.DataFrame) -> str:
    """Write ``design_indices.csv`` in the sweep directory (designed sweeps only); return the printed text."""
    indices, text = sweep_design_indices(spec, table)
    if text:
        indices.to_csv(Path(spec.output_dir) / FILE_NAME, index=False)
    return text
