"""A sweep's outputs, written after the run (``campaign sweep``): every point's case rows, the sensitivity
table and the plots.

Output directory (``[sweep] output_dir`` or ``--output``; the point stores under ``OUT/points/`` are
:mod:`campaign.run.sweep`'s)::

    OUT/sweep.json            the sweep as run (:mod:`campaign.store.sweep_directory`)
    OUT/results.parquet       every case of every point: point_id, one column per axis (named by its
                              dotted field), config_hash, then the campaign's case columns
    OUT/sensitivity.md / .csv the sensitivity table (CSV: one row per point, estimator and class, the site
                              row carrying the ellipse-weighted totals; columns of campaign.report.compare,
                              with the false-valid count)
    OUT/plots/*.png           each metric against each axis (see :mod:`campaign.report.sweep_plots`)
"""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pyarrow as pa

from campaign.configuration.sweep_file import SweepPoint, SweepSpec
from campaign.report.aggregate import format_number, render_grid
from campaign.report.compare import (
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    with_estimator_column,
)
from campaign.report.sweep_plots import write_sweep_plots
from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import atomic_write_bytes, atomic_write_table
from campaign.store.sweep_directory import value_text, write_description


def point_keys(point: SweepPoint) -> dict:
    """The columns that identify a sweep point in its rows: point_id, the axis values, config_hash."""
    return {"point_id": point.point_id, **point.values, "config_hash": point.config_hash}


def sweep_results(spec: SweepSpec) -> pd.DataFrame:
    """All case rows of the sweep's points, with point_id, the axis values and config_hash in front."""
    frames = []
    for point in spec.points:
        rows = CampaignStore(point.config.output_dir).results().reset_index(drop=True)
        if rows.empty:
            continue
        keys = point_keys(point)
        frames.append(pd.concat([pd.DataFrame({k: [v] * len(rows) for k, v in keys.items()}), rows], axis=1))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def sensitivity_table(spec: SweepSpec, results: pd.DataFrame) -> pd.DataFrame:
    """One row per point, estimator and class (campaign.report.compare columns), the site row holding the
    weighted totals."""
    fractions = {entry.name: entry.ellipse_fraction for entry in spec.base.site.classes}
    site_name = spec.base.site.name
    results = with_estimator_column(results)
    frames = []
    for point in spec.points:
        members = results[results["point_id"] == point.point_id] if not results.empty else results
        names = estimator_names(members) or point.config.estimator_names
        table = comparison_table(members, fractions, site_name, list(fractions), names,
                                 false_valid_mps=spec.base.false_valid_mps)
        keys = point_keys(point)
        for position, (key, value) in enumerate(keys.items()):
            table.insert(position, key, [value] * len(table))
        frames.append(table)
    return pd.concat(frames, ignore_index=True)


def format_sensitivity(spec: SweepSpec, table: pd.DataFrame, markdown: bool = False) -> str:
    """The table as people read it: one row per point; % valid and error per class, weighted totals,
    and the site's false-valid count and worst valid error beside them."""
    classes = [entry.name for entry in spec.base.site.classes]
    site_name = spec.base.site.name
    headers = ["point", *spec.axis_names, "estimator"]
    for name in classes:
        headers += [f"{name} % valid", f"{name} false-valid", f"{name} err m/s"]
    headers += [f"{site_name} weighted % valid", f"false-valid (>{spec.base.false_valid_mps:g} m/s)", "worst valid m/s",
                "weighted err m/s"]
    body = []
    for point in spec.points:
        point_rows = table[table["point_id"] == point.point_id]
        for estimator in dict.fromkeys(point_rows["estimator"]):
            rows = point_rows[point_rows["estimator"] == estimator].set_index("class")
            cells = [point.point_id, *(value_text(value) for value in point.values.values()), str(estimator)]
            for name in classes:
                cells += [format_number(rows.at[name, "pct_valid"], "{:.0f}"), str(int(rows.at[name, "false_valid"])),
                          format_number(rows.at[name, "error_mean_3sigma_mps"], "{:.2f}")]
            cells += [format_number(rows.at[site_name, "weighted_pct_valid"], "{:.0f}"), str(int(rows.at[site_name, "false_valid"])),
                      format_number(rows.at[site_name, "worst_valid_error_mps"], "{:.2f}"),
                      format_number(rows.at[site_name, "weighted_error_mps"], "{:.2f}")]
            body.append(cells)
    return render_grid(headers, body, markdown)


def write_outputs(spec: SweepSpec) -> tuple[pd.DataFrame, str]:
    """Write sweep.json, results.parquet, the sensitivity table and the plots; return (table, text)."""

    out = Path(spec.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = sweep_results(spec)
    if not results.empty:
        atomic_write_table(out / "results.parquet", pa.Table.from_pandas(results, preserve_index=False))
    table = sensitivity_table(spec, results)
    write_description(spec)
    cases = {name: count for name, count in spec.base.cases_per_class.items()}
    heading = (f"Sweep {spec.source} on {spec.base.site.name} ({spec.mode}, {len(spec.points)} points, "
               f"cases per point {cases}, seed {spec.base.seed})")
    if not results.empty:
        heading += f"\n{counts_line(estimator_counts(results))} (all points)"
    atomic_write_bytes(out / "sensitivity.md", f"{heading}\n\n{format_sensitivity(spec, table, markdown=True)}\n".encode())
    table.to_csv(out / "sensitivity.csv", index=False)
    write_sweep_plots(spec, table, out / "plots")
    return table, f"{heading}\n{format_sensitivity(spec, table)}"
