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

Baseline check (:mod:`campaign.run.sweep_baseline`, rules in :mod:`campaign.report.baseline_gate`):
points are matched to the baseline's by their axis values and rows by estimator; per class and for the
site, more false-valid cases, a % valid drop unlikely under sampling noise (or beyond the tolerance) and
an error growth beyond the tolerance and unlikely under a permutation test are regressions. The
configuration hash covers the result code (:func:`campaign.configuration.campaign_file.code_digest`), so
after a code change every point is computed afresh; a nightly job writes into a fresh output directory
and passes the previous night's as ``--baseline``.
"""
from __future__ import annotations

import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa

from campaign.configuration.sweep_file import SweepSpec
from campaign.report.aggregate import format_number, render_grid
from campaign.report.compare import (
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    with_estimator_column,
)
from campaign.report.sweep_plots import write_sweep_plots
from campaign.run.cluster import connected_client, require_backend
from campaign.run.orchestrate import (
    StorePoint,
    lock_stores,
    manifest_for,
    plan_campaign,
    run_locked_points,
    ship_estimators,
)
from campaign.run.sweep_baseline import value_text
from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import atomic_write_bytes, atomic_write_table

BATCH_CASES = 64       # planned cases of the points run together: prepared, locked, waited for and compacted
BATCH_POINTS = 64      # at most this many point stores locked at once (two descriptors each)
FIRST_BATCH_POINTS = 4


@dataclass(frozen=True)
class SweepRun:
    points: int
    reused_points: int
    submitted: int
    done: int
    failed: int
    wall_time_s: float
    unfinished: int = 0       # cases of all points failed or missing after the run (exit 1 when > 0)


class PointStores:
    """Each point's :class:`~campaign.run.orchestrate.StorePoint`, made when the sweep reaches the point: its
    manifest (the campaign's, plus the sweep file and the point's axis values) and its plan, planned once
    per distinct (campaign file, seed, case counts) and kept."""

    def __init__(self, spec: SweepSpec):
        self.spec = spec
        self.plans: dict[tuple, pd.DataFrame] = {}

    def __call__(self, point) -> StorePoint:
        config = point.config
        key = (str(config.source), config.seed, tuple(sorted(config.cases_per_class.items())))
        if key not in self.plans:
            self.plans[key] = plan_campaign(config)[1]
        return StorePoint(config, {**manifest_for(config), "sweep_file": str(self.spec.source),
                                   "sweep_point": point.values}, self.plans[key])


def point_batches(spec: SweepSpec, planned_cases: int):
    """The sweep's points in order, in runs of consecutive points holding about :data:`BATCH_CASES` planned
    cases (at most :data:`BATCH_POINTS` points; a larger point alone); the first run is at most
    :data:`FIRST_BATCH_POINTS` long, so the first cases are submitted as soon as the cluster is up."""
    size = max(1, min(BATCH_POINTS, BATCH_CASES // max(1, planned_cases)))
    first, total = 0, len(spec.points)
    while first < total:
        count = min(size, FIRST_BATCH_POINTS) if first == 0 else size
        yield first, spec.points[first:first + count]
        first += count


def run_sweep(spec: SweepSpec, scheduler: str | None = None, workers: int | None = None,
              progress: bool = True, wait: bool = False) -> SweepRun:
    """Run every point's missing cases on one cluster, a batch of points at a time (:func:`point_batches`):
    a batch's points are validated, planned and their stores checked and locked only when the sweep reaches
    them; each store is prepared and its cases submitted at once (workers compute while the next store is
    prepared); the batch's cases are waited for, its stores compacted and unlocked before the next batch.
    A sweep of 10^4 points starts computing within seconds, and a sweep stopped at any time keeps every
    finished case (the next run reuses finished points and runs the rest). With ``progress``, one line on
    stderr when the cluster starts and per batch (points reached, cases done, failed, reused points).

    Raises StoreBusy (a point store locked by another writer), StoreError, ConfigError (a point that
    does not validate) or RunStopped, each after the batches before it were completed and compacted."""
    start = time.perf_counter()
    execution = spec.base.execution.with_overrides(scheduler, workers)
    require_backend(execution, str(spec.source))
    total = len(spec.points)
    planned_each = sum(spec.base.cases_per_class.values())

    def say(line: str) -> None:
        if progress:
            print(f"sweep: {line}", file=sys.stderr, flush=True)

    say(f"{total} points of {planned_each} cases; starting the cluster")
    stores_of = PointStores(spec)
    reached = reused = submitted = done = failed = unfinished = 0
    with ThreadPoolExecutor(max_workers=1) as planner, ExitStack() as cluster:
        first_plan = planner.submit(stores_of, spec.points[0])      # planned while the cluster starts
        client = cluster.enter_context(connected_client(execution))
        first_plan.result()
        ship_estimators(client, list(spec.base.estimators))
        for first, batch in point_batches(spec, planned_each):
            points = [stores_of(point) for point in batch]
            stores = [CampaignStore(point.store_dir) for point in points]     # checked under their locks
            say(f"points {batch[0].point_id}-{batch[-1].point_id} ({first + len(batch)} of {total}): "
                f"{done} cases done, {failed} failed, {reused} points reused so far, "
                f"{time.perf_counter() - start:.0f} s")
            with ExitStack() as locks:
                lock_stores(points, stores, locks, wait=wait)
                run = run_locked_points(client, points, stores, execution, progress=progress, on_note=lambda line: None)
                statuses = [entry.store.status() for entry in run.prepared]
            reached += len(batch)
            reused += sum(1 for entry in run.prepared if not entry.todo)
            submitted += run.submitted
            done += run.done
            failed += run.failed
            unfinished += sum(status.failed + status.missing for status in statuses)
    say(f"all {reached} points: {done} cases done, {failed} failed this run, {reused} points reused, "
        f"{time.perf_counter() - start:.0f} s; now the tables and plots (every point's store is read)")
    return SweepRun(reached, reused, submitted, done, failed, time.perf_counter() - start, unfinished=unfinished)


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


def write_description(spec: SweepSpec) -> None:
    """Write OUT/sweep.json (also when a sweep stops, so `campaign status OUT` knows all its points)."""
    Path(spec.output_dir).mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(Path(spec.output_dir) / "sweep.json", json.dumps(sweep_description(spec), indent=2).encode())


def sweep_description(spec: SweepSpec) -> dict:
    return {
        "sweep_file": str(spec.source), "base": str(spec.base_path), "mode": spec.mode, "axes": spec.axes,
        "site": spec.base.site.name, "seed": spec.base.seed, "cases_per_class": spec.base.cases_per_class,
        "cases_scale": spec.base.cases_scale, "false_valid_mps": spec.base.false_valid_mps,
        "tolerances": spec.tolerances.model_dump(),
        "points": [{"point_id": p.point_id, "values": p.values, "config_hash": p.config_hash,
                    "store": str(Path("points") / p.config.output_dir.name)} for p in spec.points],
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
