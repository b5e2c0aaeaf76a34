"""Sensitivity sweeps: run every point of a sweep on one dask cluster, reuse points by config hash,
tabulate % valid and velocity error per point and class, compare with a baseline sweep.

Output directory (``[sweep] output_dir`` or ``--output``)::

    OUT/points/<hash[:16]>/   one campaign store per point configuration (manifest, plan, cases/...,
                              results.parquet, examples/); kept across runs, so a point whose
                              configuration hash is unchanged is reused and a killed sweep resumes
                              with only its missing cases
    OUT/sweep.json            the sweep as run: file, base, mode, axes, tolerances, points (id, values, hash)
    OUT/results.parquet       every case of every point: point_id, one column per axis (named by its
                              dotted field), config_hash, then the campaign's case columns
    OUT/sensitivity.md / .csv the sensitivity table (CSV: one row per point, estimator and class, the site
                              row carrying the ellipse-weighted totals; columns of campaign.report.compare,
                              with the false-valid count)
    OUT/plots/*.png           each metric against each axis (see :mod:`campaign.report.sweep_plots`)

Baseline check: points are matched to the baseline's by their axis values (and rows by estimator;
a baseline without an ``estimator`` column is the reference ``dimes``); for every class and for
the weighted site totals, % valid may fall by at most ``pct_valid_drop_points`` and the error
(mean + 3 sigma) may grow by at most ``error_increase_mps``. The configuration hash covers the result
code (:func:`campaign.configuration.campaign_file.code_digest`), so after a code change every point is computed afresh; a
nightly job writes into a fresh output directory and passes the previous night's as ``--baseline``.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa

from campaign.configuration.sweep_file import SweepSpec, Tolerances
from campaign.report.aggregate import format_number, render_grid
from campaign.report.compare import (
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    with_estimator_column,
)
from campaign.report.sweep_plots import write_sweep_plots
from campaign.run.cluster import require_backend
from campaign.run.orchestrate import StorePoint, manifest_for, plan_points, run_store_points
from campaign.store.campaign_store import CampaignStore, StoreError
from campaign.store.case_files import atomic_write_bytes, atomic_write_table


@dataclass(frozen=True)
class SweepRun:
    points: int
    reused_points: int
    submitted: int
    done: int
    failed: int
    wall_time_s: float
    unfinished: int = 0       # cases of all points failed or missing after the run (exit 1 when > 0)


def sweep_store_points(spec: SweepSpec) -> list[StorePoint]:
    """Each point's configuration with its store's manifest (the campaign's, plus the sweep file and the
    point's axis values) and plan (planned once per distinct seed and case counts)."""
    configs = [point.config for point in spec.points]
    return [StorePoint(point.config, {**manifest_for(point.config), "sweep_file": str(spec.source),
                                      "sweep_point": point.values}, plan)
            for point, plan in zip(spec.points, plan_points(configs))]


def run_sweep(spec: SweepSpec, scheduler: str | None = None, workers: int | None = None,
              progress: bool = True, wait: bool = False) -> SweepRun:
    """Run every point's missing cases together on one cluster, then compact each point's store
    (:func:`~campaign.run.orchestrate.run_store_points`, the path ``campaign submit`` takes with one
    point); the point stores' locks are held throughout (:class:`~campaign.store.lock.StoreBusy` if one
    is taken)."""
    start = time.perf_counter()
    execution = spec.base.execution.with_overrides(scheduler, workers)
    require_backend(execution, str(spec.source))
    run = run_store_points(sweep_store_points(spec), execution, progress=progress, wait=wait,
                           on_note=lambda line: None)
    reused = sum(1 for entry in run.prepared if not entry.todo)
    statuses = [entry.store.status() for entry in run.prepared]
    return SweepRun(len(run.prepared), reused, run.submitted, run.done, run.failed, time.perf_counter() - start,
                    unfinished=sum(status.failed + status.missing for status in statuses))


def point_keys(point) -> dict:
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
            cells = [point.point_id, *(_value_text(value) for value in point.values.values()), str(estimator)]
            for name in classes:
                cells += [format_number(rows.at[name, "pct_valid"], "{:.0f}"), str(int(rows.at[name, "false_valid"])),
                          format_number(rows.at[name, "error_mean_3sigma_mps"], "{:.2f}")]
            cells += [format_number(rows.at[site_name, "weighted_pct_valid"], "{:.0f}"), str(int(rows.at[site_name, "false_valid"])),
                      format_number(rows.at[site_name, "worst_valid_error_mps"], "{:.2f}"),
                      format_number(rows.at[site_name, "weighted_error_mps"], "{:.2f}")]
            body.append(cells)
    return render_grid(headers, body, markdown)


def _value_text(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def write_outputs(spec: SweepSpec) -> tuple[pd.DataFrame, str]:
    """Write sweep.json, results.parquet, the sensitivity table and the plots; return (table, text)."""

    out = Path(spec.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = sweep_results(spec)
    if not results.empty:
        atomic_write_table(out / "results.parquet", pa.Table.from_pandas(results, preserve_index=False))
    table = sensitivity_table(spec, results)
    description = sweep_description(spec)
    atomic_write_bytes(out / "sweep.json", json.dumps(description, indent=2).encode())
    cases = {name: count for name, count in spec.base.cases_per_class.items()}
    heading = (f"Sweep {spec.source} on {spec.base.site.name} ({spec.mode}, {len(spec.points)} points, "
               f"cases per point {cases}, seed {spec.base.seed})")
    if not results.empty:
        heading += f"\n{counts_line(estimator_counts(results))} (all points)"
    atomic_write_bytes(out / "sensitivity.md", f"{heading}\n\n{format_sensitivity(spec, table, markdown=True)}\n".encode())
    table.to_csv(out / "sensitivity.csv", index=False)
    write_sweep_plots(spec, table, out / "plots")
    return table, f"{heading}\n{format_sensitivity(spec, table)}"


def sweep_description(spec: SweepSpec) -> dict:
    return {
        "sweep_file": str(spec.source), "base": str(spec.base_path), "mode": spec.mode, "axes": spec.axes,
        "site": spec.base.site.name, "seed": spec.base.seed, "cases_per_class": spec.base.cases_per_class,
        "tolerances": {"pct_valid_drop_points": spec.tolerances.pct_valid_drop_points,
                       "error_increase_mps": spec.tolerances.error_increase_mps},
        "points": [{"point_id": p.point_id, "values": p.values, "config_hash": p.config_hash,
                    "store": str(Path("points") / p.config.output_dir.name)} for p in spec.points],
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def read_baseline(directory: str | Path) -> tuple[dict, pd.DataFrame]:
    """A previous sweep's sweep.json and sensitivity.csv (StoreError when it is not a sweep directory)."""
    directory = Path(directory)
    description_path, table_path = directory / "sweep.json", directory / "sensitivity.csv"
    if not description_path.is_file() or not table_path.is_file():
        raise StoreError(f"{directory}: no sweep.json and sensitivity.csv: not a sweep output directory "
                         "(allowed: the output directory of an earlier `campaign sweep`)")
    return json.loads(description_path.read_text()), pd.read_csv(table_path, keep_default_na=True)


def compare_to_baseline(spec: SweepSpec, table: pd.DataFrame, baseline: tuple[dict, pd.DataFrame],
                        tolerances: Tolerances) -> tuple[list[str], int]:
    """Regressions of ``table`` against a baseline sweep: one line each; and the number of points compared.

    Points are matched by axis values (the same fields, equal values); per class % valid and error,
    for the site row the weighted % valid and weighted error.
    """
    description, base_table = baseline
    base_points = {_match_key(point["values"]): point["point_id"] for point in description.get("points", [])}
    site_name = spec.base.site.name
    regressions, compared = [], 0
    for point in spec.points:
        base_id = base_points.get(_match_key(point.values))
        if base_id is None:
            continue
        compared += 1
        point_rows = table[table["point_id"] == point.point_id]
        base_rows = with_estimator_column(base_table[base_table["point_id"] == base_id])
        for estimator in dict.fromkeys(point_rows["estimator"]):
            now = point_rows[point_rows["estimator"] == estimator].set_index("class")
            before = base_rows[base_rows["estimator"] == estimator].set_index("class")
            where = f"{point.point_id} ({', '.join(f'{k}={_value_text(v)}' for k, v in point.values.items())})"
            if len(point_rows["estimator"].unique()) > 1 or estimator != "dimes":
                where += f" estimator {estimator}"
            regressions += _regressions(now, before, where, site_name, tolerances)
    return regressions, compared


def _regressions(now: pd.DataFrame, before: pd.DataFrame, where: str, site_name: str, tolerances: Tolerances) -> list[str]:
    """Regressions of one point and estimator (rows indexed by class) against its baseline rows."""
    regressions = []
    for name in now.index:
        if name not in before.index or int(now.at[name, "cases"]) == 0 or int(before.at[name, "cases"]) == 0:
            continue
        valid_column, error_column = (("weighted_pct_valid", "weighted_error_mps") if name == site_name
                                      else ("pct_valid", "error_mean_3sigma_mps"))
        label = f"{name} weighted" if name == site_name else name
        valid_now, valid_before = float(now.at[name, valid_column]), float(before.at[name, valid_column])
        if valid_before - valid_now > tolerances.pct_valid_drop_points:
            regressions.append(f"{where}: {label} % valid {valid_before:.1f} -> {valid_now:.1f} (drop "
                               f"{valid_before - valid_now:.1f} points > {tolerances.pct_valid_drop_points:g})")
        error_now, error_before = float(now.at[name, error_column]), float(before.at[name, error_column])
        if math.isfinite(error_before) and not math.isfinite(error_now):
            regressions.append(f"{where}: {label} error {error_before:.2f} m/s -> n/a (no valid cases)")
        elif math.isfinite(error_before) and error_now - error_before > tolerances.error_increase_mps:
            regressions.append(f"{where}: {label} error mean+3 sigma {error_before:.2f} -> {error_now:.2f} m/s "
                               f"(+{error_now - error_before:.2f} > {tolerances.error_increase_mps:g})")
    return regressions


def _match_key(values: dict) -> tuple:
    return tuple(sorted((field, json.dumps(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v))
                        for field, v in values.items()))
