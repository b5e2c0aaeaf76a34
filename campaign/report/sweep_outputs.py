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
    OUT/plots/*.png           each metric against each axis (see :mod:`campaign.report.sweep_plots`); a sweep
                              of several sites: OUT/plots/<site>/*.png, one set per site

The printed table (:func:`format_sweep_table`, also ``campaign table OUT``) is one row per point and
estimator, split into blocks of at most 120 columns like the campaign table: the point, its axis values
and the estimator repeated in every block, then per class its % valid with its counts (valid/ran),
false-valid/valid and error mean + 3 sigma, and the site's ellipse-weighted group. A sweep of several
sites has one table per site (each with its own classes).
"""
from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd
import pyarrow as pa

from campaign.configuration.sweep_axes import SITE_AXIS
from campaign.report.aggregate import NOTE_WIDTH, format_number, render_grid
from campaign.report.compare import (
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    with_estimator_column,
)
from campaign.report.sweep_indices import write_design_indices
from campaign.report.sweep_plots import write_sweep_plots
from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import atomic_write_bytes, atomic_write_table
from campaign.store.errors import StoreError
from campaign.store.sweep_directory import read_description, value_text, write_description

if TYPE_CHECKING:      # `campaign table SWEEP_DIR` reads stores, not sweep files (no configuration models)
    from campaign.configuration.sweep_file import SweepPoint, SweepSpec

LINE_WIDTH = 120
"""No printed line of the sweep table is wider (it is split into blocks)."""
AXIS_HEADER_WIDTH = 12
"""An axis column is headed by its field's last dotted part, cut to this width (the legend names it in full)."""


@dataclass(frozen=True)
class PointSummary:
    """What the sweep table needs of one point: its id, axis values and configuration hash, its site's name,
    classes (ellipse fractions, planned cases) and false-valid threshold."""

    point_id: str
    values: dict
    config_hash: str
    site: str
    fractions: dict[str, float]
    cases_per_class: dict[str, int]
    false_valid_mps: float
    estimators: list[str]


def spec_points(spec: SweepSpec) -> list[PointSummary]:
    """The points of a sweep as the table reads them."""
    return [PointSummary(p.point_id, p.values, p.config_hash, p.config.site.name,
                         {entry.name: entry.ellipse_fraction for entry in p.config.site.classes},
                         p.config.cases_per_class, p.config.false_valid_mps, p.config.estimator_names)
            for p in spec.points]


def point_keys(point: SweepPoint | PointSummary) -> dict:
    """The columns that identify a sweep point in its rows: point_id, the axis values, config_hash."""
    return {"point_id": point.point_id, **point.values, "config_hash": point.config_hash}


def _with_keys(point, rows: pd.DataFrame) -> pd.DataFrame:
    keys = point_keys(point)
    return pd.concat([pd.DataFrame({k: [v] * len(rows) for k, v in keys.items()}), rows], axis=1)


def sweep_results(spec: SweepSpec) -> pd.DataFrame:
    """All case rows of the sweep's points, with point_id, the axis values and config_hash in front."""
    frames = []
    for point in spec.points:
        rows = CampaignStore(point.config.output_dir).results().reset_index(drop=True)
        if not rows.empty:
            frames.append(_with_keys(point, rows))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def sensitivity_table(spec: SweepSpec | list[PointSummary], results: pd.DataFrame) -> pd.DataFrame:
    """One row per point, estimator and class (campaign.report.compare columns), the site row holding the
    weighted totals."""
    points = spec if isinstance(spec, list) else spec_points(spec)
    results = with_estimator_column(results)
    frames = []
    for point in points:
        members = results[results["point_id"] == point.point_id] if not results.empty else results
        names = estimator_names(members) or point.estimators
        table = comparison_table(members, point.fractions, point.site, list(point.fractions), names,
                                 false_valid_mps=point.false_valid_mps)
        for position, (key, value) in enumerate(point_keys(point).items()):
            table.insert(position, key, [value] * len(table))
        frames.append(table)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _short(field: str) -> str:
    last = field.split(".")[-1]
    return last if len(last) <= AXIS_HEADER_WIDTH else last[:AXIS_HEADER_WIDTH - 1] + "~"


def _pct_cells(row: pd.Series, pct_column: str, valid: int, ran: int) -> str:
    return format_number(row[pct_column], "{:.1f}%") + f" ({valid}/{ran})"


def _site_groups(points: list[PointSummary], table: pd.DataFrame
                 ) -> tuple[list[list[str]], list[tuple[str, list[str], list[list[str]]]]]:
    """(classes shown, [(title, headers, per (point, estimator) row: cells)]) of one site's points."""
    site = points[0].site
    classes = [name for name in points[0].fractions if any(p.cases_per_class.get(name, 0) > 0 for p in points)]
    threshold = points[0].false_valid_mps
    rows_of = []
    for point in points:
        point_rows = table[table["point_id"] == point.point_id]
        for estimator in dict.fromkeys(point_rows["estimator"]):
            rows_of.append((point, estimator, point_rows[point_rows["estimator"] == estimator].set_index("class")))
    groups = []
    for name in classes:
        cells = []
        for _point, _estimator, rows in rows_of:
            row = rows.loc[name]
            valid, ran = int(row["valid"]), int(row["cases"]) - int(row["failed"])
            cells.append([_pct_cells(row, "pct_valid", valid, ran), f"{int(row['false_valid'])}/{valid}",
                          format_number(row["error_mean_3sigma_mps"], "{:.2f}")])
        groups.append((name, ["% valid", "f-valid", "err m/s"], cells))
    cells = []
    for point, _estimator, rows in rows_of:
        inside = [name for name in point.fractions if point.fractions[name] > 0 and name in rows.index]
        valid = sum(int(rows.at[name, "valid"]) for name in inside)
        ran = sum(int(rows.at[name, "cases"]) - int(rows.at[name, "failed"]) for name in inside)
        row = rows.loc[site]
        cells.append([_pct_cells(row, "weighted_pct_valid", valid, ran), f"{int(row['false_valid'])}/{int(row['valid'])}",
                      format_number(row["worst_valid_error_mps"], "{:.2f}"), format_number(row["weighted_error_mps"], "{:.2f}")])
    groups.append((f"{site} weighted (f-valid >{threshold:g} m/s)", ["% valid", "f-valid", "worst m/s", "err m/s"], cells))
    keys = [[point.point_id, *(value_text(point.values.get(axis)) for axis in _axes(points)), str(estimator)]
            for point, estimator, _ in rows_of]
    return keys, groups


def _axes(points: list[PointSummary]) -> list[str]:
    return [name for name in points[0].values if name != SITE_AXIS] if points else []


def format_sweep_table(points: list[PointSummary], table: pd.DataFrame, markdown: bool = False,
                       width: int = LINE_WIDTH) -> str:
    """The sweep table (module docstring): per site, one row per point and estimator; plain text in blocks
    of at most ``width`` characters (each block repeats the point, axis and estimator columns; a group's
    name is written above its columns), Markdown as one table per site with every column."""
    texts = []
    for site in dict.fromkeys(point.site for point in points):
        mine = [point for point in points if point.site == site]
        keys, groups = _site_groups(mine, table)
        axes = _axes(mine)
        key_headers = ["point", *(axis if markdown else _short(axis) for axis in axes), "estimator"]
        title = f"{site}: {len(mine)} points" if len(points) != len(mine) else ""
        if markdown:
            headers = key_headers + [f"{name} {header}" for name, headers, _ in groups for header in headers]
            body = [key + [cell for _, _, cells in groups for cell in cells[index]] for index, key in enumerate(keys)]
            texts.append((f"### {title}\n\n" if title else "") + render_grid(headers, body, markdown=True))
            continue
        legend = [f"{_short(axis)} = {axis}" for axis in axes if _short(axis) != axis]
        group_widths = [[max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(headers)]
                        for _, headers, cells in groups]
        key_widths = [max(len(h), *(len(k[i]) for k in keys)) for i, h in enumerate(key_headers)]
        overflow = sum(key_widths) + 2 * (len(key_widths) - 1) + max(sum(w + 2 for w in g) for g in group_widths) - width
        if overflow > 0 and key_widths[-1] > len("estimator"):     # long estimator names: cut with "~"
            room = max(len("estimator"), key_widths[-1] - overflow)
            full = sorted({key[-1] for key in keys if len(key[-1]) > room})
            keys = [key[:-1] + [key[-1] if len(key[-1]) <= room else key[-1][:room - 1] + "~"] for key in keys]
            key_widths[-1] = room
            legend += [f"estimator {name}" for name in full]
        key_width = sum(key_widths) + 2 * (len(key_widths) - 1)
        blocks: list[list[int]] = []
        for index, widths in enumerate(group_widths):
            size = sum(w + 2 for w in widths)
            if blocks and key_width + sum(sum(w + 2 for w in group_widths[g]) for g in blocks[-1]) + size <= width:
                blocks[-1].append(index)
            else:
                blocks.append([index])
        lines = ([title] if title else []) + (textwrap.wrap("names in full: " + "; ".join(legend), width,
                                                            subsequent_indent="  ", break_on_hyphens=False)
                                              if legend else [])
        for number, block in enumerate(blocks, start=1):
            if len(blocks) > 1:
                lines.append(f"block {number} of {len(blocks)}")
            group_line = " " * key_width
            for g in block:
                room = sum(w + 2 for w in group_widths[g]) - 2
                name = groups[g][0]
                shown = name if len(name) <= room else name[:room - 1] + "~"
                group_line += "  " + shown.ljust(room, "-")
            lines.append(group_line.rstrip())
            widths = key_widths + [w for g in block for w in group_widths[g]]
            header = key_headers + [h for g in block for h in groups[g][1]]
            for row in [header] + [keys[r] + [c for g in block for c in groups[g][2][r]] for r in range(len(keys))]:
                lines.append("  ".join(c.ljust(w) if i < len(key_widths) else c.rjust(w)
                                       for i, (c, w) in enumerate(zip(row, widths))).rstrip())
        texts.append("\n".join(lines))
    return ("\n\n" if markdown else "\n\n").join(texts) + ("" if markdown else "\n" + SWEEP_TABLE_NOTE)


SWEEP_TABLE_NOTE = textwrap.fill(
    "% valid (valid/ran): ran = cases - failed; f-valid: valid cases with an error above the false-valid threshold "
    "/ valid cases; err: velocity error mean + 3 sigma over the valid cases (m/s); site group: % valid and err "
    "ellipse-weighted, (valid/ran) summed over the classes inside the ellipse, f-valid and worst over all classes.",
    NOTE_WIDTH)


def format_sensitivity(spec: SweepSpec, table: pd.DataFrame, markdown: bool = False) -> str:
    """The sweep table of ``spec`` (:func:`format_sweep_table`)."""
    return format_sweep_table(spec_points(spec), table, markdown)


def _heading(spec: SweepSpec) -> str:
    bases = spec.all_bases
    sites = " + ".join(base.site.name for base in bases)
    cases = "; ".join(f"{base.site.name} {dict(base.cases_per_class)}" for base in bases) if len(bases) > 1 \
        else str(dict(spec.base.cases_per_class))
    return (f"Sweep {spec.source} on {sites} ({spec.mode}, {len(spec.points)} points, "
            f"cases per point {cases}, seed {spec.base.seed})")


def write_outputs(spec: SweepSpec, reused_from: dict[str, str] | None = None) -> tuple[pd.DataFrame, str]:
    """Write sweep.json, results.parquet, the sensitivity table and the plots; return (table, text)."""

    out = Path(spec.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = sweep_results(spec)
    if not results.empty:
        atomic_write_table(out / "results.parquet", pa.Table.from_pandas(results, preserve_index=False))
    table = sensitivity_table(spec, results)
    write_description(spec, reused_from)
    heading = _heading(spec)
    if not results.empty:
        heading += f"\n{counts_line(estimator_counts(results))} (all points)"
    indices = write_design_indices(spec, table)       # "" unless a designed sweep (Sobol, Morris)
    design_text = f"\n{indices}" if indices else ""
    atomic_write_bytes(out / "sensitivity.md", (f"{heading}\n\n{format_sensitivity(spec, table, markdown=True)}\n"
                                                + (f"\n```\n{indices}```\n" if indices else "")).encode())
    table.to_csv(out / "sensitivity.csv", index=False)
    views = spec.site_views()
    for view in views:
        members = table[table["point_id"].isin([p.point_id for p in view.points])]
        write_sweep_plots(view, members, out / "plots" / (view.base.site.name.lower() if len(views) > 1 else ""))
    return table, f"{heading}\n{format_sensitivity(spec, table)}{design_text}"


def directory_points(directory: str | Path) -> list[tuple[PointSummary, Path]]:
    """The points of a sweep output directory (sweep.json) with their stores, as the table reads them: each
    point's site, classes, case counts and threshold from its store's verified manifest (points without a
    store yet are left out)."""
    directory = Path(directory)
    description = read_description(directory)
    found = []
    for point in description["points"]:
        store = directory / point["store"]
        manifest = CampaignStore(store).manifest() if (store / "manifest.json").exists() else None
        if manifest is None:
            continue
        threshold = float(manifest.get("config", {}).get("campaign", {}).get("false_valid_mps",
                                                                              description.get("false_valid_mps", 5.0)))
        found.append((PointSummary(point["point_id"], point["values"], manifest["config_hash"],
                                   str(manifest.get("config", {}).get("site", {}).get("name") or manifest["site"]),
                                   dict(manifest["ellipse_fractions"]), dict(manifest["cases_per_class"]), threshold,
                                   list(manifest.get("estimators") or [])), store))
    return found


def directory_table(directory: str | Path) -> str:
    """``campaign table SWEEP_DIR``: the sweep table from the point stores (verified case files), printed as
    the sweep printed it."""
    found = directory_points(directory)
    if not found:
        raise StoreError(f"{directory}: no point of this sweep has a store yet; allowed: a sweep directory after "
                         "`campaign sweep` ran")
    frames = []
    for point, store in found:
        rows = CampaignStore(store).results().reset_index(drop=True)
        if not rows.empty:
            frames.append(_with_keys(point, rows))
    results = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    points = [point for point, _ in found]
    table = sensitivity_table(points, results)
    heading = f"Sweep {directory} ({len(points)} points with a store)"
    if not results.empty:
        heading += f"\n{counts_line(estimator_counts(results))} (all points)"
    return f"{heading}\n{format_sweep_table(points, table)}"
