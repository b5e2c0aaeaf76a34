"""A sweep against its baseline (``campaign sweep FILE --baseline DIR``).

The baseline is a previous sweep's output directory: its ``sweep.json`` (axes, site, points with their
values and store) and, per point, the case rows of the point's campaign store (``points/<hash>/``,
verified like any store), else the point's rows of the directory's ``results.parquet``. It must sweep
the same axes on the same site and share at least one point (the same axis values); anything else is
one line naming the file and what is allowed (exit 2), read before the sweep runs, so a baseline that
is the output directory itself is judged as it was. Matched points are judged by
:mod:`campaign.report.baseline_gate` on the case rows of both sides, with this sweep's false-valid
threshold.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa

from campaign.configuration.sweep_file import SweepSpec, Tolerances
from campaign.report.aggregate import COLUMNS_READ
from campaign.report.baseline_gate import Finding, GateRules, judge_point
from campaign.report.compare import with_estimator_column
from campaign.store.campaign_store import CampaignStore, StoreError
from campaign.store.sweep_directory import ALLOWED, point_label, read_description


@dataclass(frozen=True)
class Baseline:
    """A previous sweep: its directory, its sweep.json, and the case rows of each of its points that
    match a point of this sweep (baseline point id -> rows, with an ``estimator`` column)."""

    directory: Path
    description: dict
    rows: dict[str, pd.DataFrame]


def read_baseline(directory: str | Path, spec: SweepSpec) -> Baseline:
    """The baseline for ``spec`` (StoreError, one line, when it is missing, corrupt or incompatible)."""
    directory = Path(directory)
    description = read_description(directory)
    path = directory / "sweep.json"
    if sorted(description["axes"]) != sorted(spec.axes):
        raise StoreError(f"{path}: the baseline sweeps {', '.join(sorted(description['axes'])) or 'no axes'}, this "
                         f"sweep {', '.join(sorted(spec.axes))}; allowed: a baseline of the same axes")
    if description.get("site") != spec.base.site.name:
        raise StoreError(f"{path}: the baseline is of site {description.get('site')!r}, this sweep of "
                         f"{spec.base.site.name!r}; allowed: a baseline of the same site")
    wanted = {match_key(point.values) for point in spec.points}
    matched = [point for point in description["points"] if match_key(point["values"]) in wanted]
    if not matched:
        raise StoreError(f"{path}: no point of this sweep has the axis values of a baseline point; allowed: a "
                         "baseline sharing at least one point")
    return Baseline(directory, description, {point["point_id"]: _point_rows(directory, point) for point in matched})


def _point_rows(directory: Path, point: dict) -> pd.DataFrame:
    """A baseline point's case rows: its store's (verified), else its rows of DIR/results.parquet."""
    store = directory / point["store"]
    try:
        if (store / "manifest.json").is_file():
            rows = CampaignStore(store).results()
        elif (directory / "results.parquet").is_file():
            everything = pd.read_parquet(directory / "results.parquet")
            rows = everything[everything["point_id"] == point["point_id"]] if "point_id" in everything else everything[:0]
        else:
            rows = pd.DataFrame()
    except (OSError, ValueError, KeyError, pa.ArrowException) as exc:
        raise StoreError(f"{store}: the case rows of baseline point {point['point_id']} cannot be read "
                         f"({' '.join(str(exc).split())[:200]}); {ALLOWED}") from None
    if rows.empty:
        raise StoreError(f"{store}: no case rows of baseline point {point['point_id']} (neither its store nor "
                         f"{directory / 'results.parquet'} has them); {ALLOWED}")
    missing = [name for name in COLUMNS_READ if name not in rows.columns]
    if missing:
        raise StoreError(f"{store}: the rows of baseline point {point['point_id']} lack the column {missing[0]!r}; "
                         f"{ALLOWED}")
    return with_estimator_column(rows.reset_index(drop=True))


def gate_rules(tolerances: Tolerances) -> GateRules:
    return GateRules(false_valid_increase=tolerances.false_valid_increase,
                     pct_valid_drop_points=tolerances.pct_valid_drop_points,
                     error_increase_mps=tolerances.error_increase_mps, significance=tolerances.significance)


@dataclass(frozen=True)
class GateResult:
    """The regressions found, the number of points compared, and notes on what was not compared."""

    findings: list[Finding]
    compared: int
    notes: list[str]


def compare_to_baseline(spec: SweepSpec, results: pd.DataFrame, baseline: Baseline,
                        tolerances: Tolerances) -> GateResult:
    """Regressions of this sweep's case rows (``results``, with ``point_id``) against the baseline (points
    matched by their axis values); points without a baseline point and estimators the baseline point did
    not run are named in the notes."""
    base_ids = {match_key(point["values"]): point["point_id"] for point in baseline.description["points"]}
    fractions = {entry.name: entry.ellipse_fraction for entry in spec.base.site.classes}
    results = with_estimator_column(results)
    rules = gate_rules(tolerances)
    findings: list[Finding] = []
    notes, compared = [], 0
    for point in spec.points:
        key = match_key(point.values)
        base_id = base_ids.get(key)
        where = point_label(point.point_id, point.values)
        if base_id is None or base_id not in baseline.rows:
            notes.append(f"{where}: no baseline point with these axis values: not compared")
            continue
        compared += 1
        mine = results[results["point_id"] == point.point_id] if not results.empty else results
        before = baseline.rows[base_id]
        for estimator in dict.fromkeys(mine["estimator"]) if len(mine) else []:
            if not (before["estimator"] == estimator).any():
                notes.append(f"{where}: estimator {estimator} has no rows in baseline point {base_id}: not compared")
        findings += judge_point(where, repr(key), before, mine, fractions, spec.base.site.name,
                                spec.base.false_valid_mps, rules)
    return GateResult(findings, compared, notes)


def match_key(values: dict) -> tuple:
    """Axis values as a comparable key (numbers as floats: 1 and 1.0 are the same point)."""
    return tuple(sorted((field, json.dumps(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v))
                        for field, v in values.items()))
