"""`campaign report DIR`: a Markdown report with PNG plots from a campaign store."""
from __future__ import annotations

import math
from pathlib import Path

from campaign.configuration.execution import no_op_banner
from campaign.realism.flight_metrics import __doc__ as METRICS_DOC
from campaign.realism.flight_metrics import metrics_table
from campaign.report import compare_plots, plots
from campaign.report.aggregate import format_number, format_table, site_table
from campaign.report.compare import (
    COMPARISON_NOTE,
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    format_comparison,
    with_estimator_column,
)
from campaign.report.failures import abbreviate_error, failure_summary, markdown_cell
from campaign.report.gallery import INVALID_PER_REASON, draw_gallery
from campaign.report.table import false_valid_threshold
from campaign.store.campaign_store import CampaignStore, StoreError


def write_report(root: Path) -> Path:
    """Write ``DIR/report/report.md`` with error histograms, % valid, estimate vs truth, example
    descent images (written by the workers for the first case of each class) and footprint maps
    (from ``campaign plan``, when present)."""
    store = CampaignStore(root)
    manifest = store.manifest()
    if manifest is None:
        raise StoreError(f"{root}: no manifest.json: not a campaign directory")
    results = store.results()
    if results.empty:
        raise StoreError(f"{root}: no finished cases yet; run `campaign submit` first")
    out = store.root / "report"
    out.mkdir(exist_ok=True)
    fractions = manifest["ellipse_fractions"]
    site = manifest["site"].capitalize()
    threshold = false_valid_threshold(manifest)
    results = with_estimator_column(results)
    names = estimator_names(results)
    status = store.status()
    comparison = comparison_table(results, fractions, site, list(fractions), names, false_valid_mps=threshold)
    lines = [
        f"# {site} DIMES campaign report", "",
        *([f"**{no_op_banner(manifest)}**", ""] if no_op_banner(manifest) else []),
        f"Configuration `{manifest['config_file']}` (hash `{manifest['config_hash'][:12]}`), seed {manifest['seed']}; "
        f"{status.planned} cases planned, {status.done} done, {status.failed} failed, {status.missing} missing; "
        f"estimators: {', '.join(f'`{name}`' for name in names)} (each ran on the same images and sensor draws).", "",
        counts_line(estimator_counts(results)), "",
        *_failure_bullets(results), "",
        "## Estimators side by side", "", format_comparison(comparison, markdown=True), "", COMPARISON_NOTE, "",
    ]
    compare_plots.error_cdf(results, list(fractions), site, names, out / "error_cdf.png", threshold)
    compare_plots.valid_false_valid_bars(comparison, out / "valid_false_valid.png")
    gallery_lines = draw_gallery(store, results, out, threshold)
    (out / "gallery.md").write_text("\n".join(gallery_lines))
    shown = sum(line.startswith("![case ") for line in gallery_lines)
    lines += ["## Estimators compared on shared axes", "",
              "Error CDF of the valid cases, one line per estimator; every panel on the same axes:", "",
              "![error CDF](error_cdf.png)", "",
              "% valid (valid/ran; the site's ellipse-weighted) and false-valid (of the valid cases) per class, "
              "one bar per estimator, both panels on the same 0-100 % scale:", "",
              "![% valid and false-valid](valid_false_valid.png)", "",
              f"The [failure gallery](gallery.md) shows {shown} cases: each false-valid case and up to "
              f"{INVALID_PER_REASON} invalid cases per reason and estimator, with their images, templates and "
              "matches, error and attitude-knowledge floor.", ""]
    for name in names:
        rows = results[results["estimator"] == name]
        suffix = f"-{name}" if len(names) > 1 else ""
        lines += _estimator_section(name, rows, fractions, site, out, suffix, len(names) > 1, threshold)
    examples = sorted((store.root / "examples").glob("*.png")) if (store.root / "examples").exists() else []
    if examples:
        lines += ["## Example descent images", ""]
        lines += [f"![{p.stem}](../examples/{p.name})" for p in examples] + [""]
    maps = sorted((store.root / "plan").glob("footprints-*.png")) if (store.root / "plan").exists() else []
    if maps:
        lines += ["## Footprint maps (paper Fig. 5)", ""] + [f"![{p.stem}](../plan/{p.name})" for p in maps] + [""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def _estimator_section(name: str, rows, fractions: dict, site: str, out: Path, suffix: str, titled: bool,
                       false_valid_mps: float) -> list[str]:
    """The paper's table, plots, Table-3 metrics against flight, invalid reasons and failed rows of one
    estimator."""
    level = "###" if titled else "##"
    table = site_table(rows, fractions, site, class_order=list(fractions), false_valid_mps=false_valid_mps)
    ok = rows[rows["status"] == "ok"]
    lines = ([f"## Estimator `{name}`", ""] if titled else []) + [
        f"{level} Table (paper Tables 1-2)", "", format_table(table, markdown=True), "",
        f"False-valid: valid with a horizontal error above {false_valid_mps:g} m/s (`[campaign] false_valid_mps`).", ""]
    lines += _false_valid_section(rows, level, false_valid_mps)
    plots.valid_fraction_bars(table, out / f"valid_fraction{suffix}.png", name)     # failed rows counted there too
    lines += [f"{level} Valid velocities", "", f"![% valid](valid_fraction{suffix}.png)", ""]
    if not ok.empty:
        plots.error_histograms(ok, out / f"error_histograms{suffix}.png", name, false_valid_mps, list(fractions))
        plots.estimate_vs_truth(ok, out / f"estimate_vs_truth{suffix}.png", name)
        lines += [f"{level} Velocity error per class", "", f"![error histograms](error_histograms{suffix}.png)", "",
                  f"{level} Estimate against truth (valid cases)", "", f"![estimate vs truth](estimate_vs_truth{suffix}.png)", ""]
        definitions = METRICS_DOC.split("\n\n", 1)[1].strip()
        lines += [f"{level} DIMES correlation metrics against flight (paper Table 3)", "",
                  "Median [10th-90th percentile] over the templates of each class; the paper's three "
                  "features for MOC2DIMES and for the MER-A flight images.", "",
                  metrics_table(ok, list(fractions)), "", definitions, ""]
        reasons = ok[~ok["valid"].astype(bool)].groupby(["class_name", "reason"]).size()
        if len(reasons):
            lines += [f"{level} Why cases were invalid", "", "| class | reason | cases |", "|---|---|---|"]
            lines += [f"| {markdown_cell(c)} | {markdown_cell(r)} | {n} |" for (c, r), n in reasons.items()] + [""]
    failed = rows[rows["status"] != "ok"]
    if not failed.empty:
        lines += [f"{level} Failed cases", "", "Each failed row's full error text, as stored (a Python plug-in's "
                  "ends with the file and line where it raised).", "", "| case | class | reason | error |",
                  "|---|---|---|---|"]
        lines += [f"| {int(r.case_id)} | {markdown_cell(r.class_name)} | {markdown_cell(getattr(r, 'reason', ''))} | "
                  f"{markdown_cell(r.error)} |" for r in failed.itertuples()] + [""]
    return lines


def _failure_bullets(results) -> list[str]:
    """One bullet per estimator with failed rows and one sub-bullet per kind of failure: its count and the
    first row's error (:mod:`campaign.report.failures`; the full texts are in the Failed cases tables)."""
    lines = []
    for summary in failure_summary(results):
        lines.append(f"- **failed:** estimator `{summary.estimator}`: {summary.failed} of {summary.rows} rows, "
                     f"{len(summary.kinds)} kind{'s' if len(summary.kinds) > 1 else ''}:")
        lines += [f"  - {kind.rows} x {markdown_cell(kind.kind)}, e.g. {kind.example_where}: "
                  f"{markdown_cell(abbreviate_error(kind.example_error))}" for kind in summary.kinds]
    return lines


def _false_valid_section(rows, level: str, false_valid_mps: float) -> list[str]:
    """Every false-valid case beside its attitude-knowledge floor (:mod:`campaign.case.error_budget`): an error
    near the floor comes from the attitude bias common to the images, one far above it from the images."""
    valid = rows[rows["valid"].astype(bool)]
    wrong = valid[valid["velocity_error_mps"] > false_valid_mps]
    if wrong.empty:
        return []
    lines = [f"{level} False-valid cases and the attitude-knowledge floor", "",
             "floor = abs(tan(tilt bias)) x altitude drop / time between images 1 and 3: the error an attitude "
             "bias common to the images causes whatever the matching (campaign/case/error_budget.py).", "",
             "| case | class | error m/s | stated uncertainty m/s | attitude bias deg | floor m/s | error - floor m/s |",
             "|---|---|---|---|---|---|---|"]
    for row in wrong.sort_values("velocity_error_mps", ascending=False).itertuples():
        floor = getattr(row, "attitude_floor_mps", float("nan"))
        tilt_deg = math.degrees(math.hypot(getattr(row, "sensor_attitude_bias_east_rad", float("nan")),
                                           getattr(row, "sensor_attitude_bias_north_rad", float("nan"))))
        cells = (row.velocity_error_mps, row.velocity_uncertainty_mps, tilt_deg, floor, row.velocity_error_mps - floor)
        lines.append(f"| {int(row.case_id)} | {row.class_name} | "
                     + " | ".join(format_number(_number(value), "{:.2f}") for value in cells) + " |")
    return lines + [""]


def _number(value) -> float:
    """A stored cell as a float (NaN for a null or non-numeric value)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
