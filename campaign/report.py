"""`campaign report DIR`: a Markdown report with PNG plots from a campaign store."""
from __future__ import annotations

from pathlib import Path

from . import plots
from .aggregate import format_table, site_table
from .campaign_run import false_valid_threshold
from .flight_metrics import __doc__ as METRICS_DOC
from .flight_metrics import metrics_table
from .store import CampaignStore, StoreError


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
    table = site_table(results, fractions, site, class_order=list(fractions),
                       false_valid_mps=false_valid_threshold(manifest))
    status = store.status()
    ok = results[results["status"] == "ok"]
    lines = [
        f"# {site} DIMES campaign report", "",
        f"Configuration `{manifest['config_file']}` (hash `{manifest['config_hash'][:12]}`), seed {manifest['seed']}; "
        f"{status.planned} cases planned, {status.done} done, {status.failed} failed, {status.missing} missing.", "",
        "## Table (paper Tables 1-2)", "", format_table(table, markdown=True), "",
        f"False-valid: valid with a horizontal error above {table.attrs['false_valid_mps']:g} m/s "
        "(`[campaign] false_valid_mps`).", "",
    ]
    if not ok.empty:
        plots.error_histograms(ok, out / "error_histograms.png")
        plots.valid_fraction_bars(table, out / "valid_fraction.png")
        plots.estimate_vs_truth(ok, out / "estimate_vs_truth.png")
        lines += ["## Velocity error per class", "", "![error histograms](error_histograms.png)", "",
                  "## Valid velocities", "", "![% valid](valid_fraction.png)", "",
                  "## Estimate against truth (valid cases)", "", "![estimate vs truth](estimate_vs_truth.png)", ""]
        definitions = METRICS_DOC.split("\n\n", 1)[1].strip()
        lines += ["## DIMES correlation metrics against flight (paper Table 3)", "",
                  "Median [10th-90th percentile] over the templates of each class; the paper's three "
                  "features for MOC2DIMES and for the MER-A flight images.", "",
                  metrics_table(ok, list(fractions)), "", definitions, ""]
        reasons = ok[~ok["valid"].astype(bool)].groupby(["class_name", "reason"]).size()
        if len(reasons):
            lines += ["## Why cases were invalid", "", "| class | reason | cases |", "|---|---|---|"]
            lines += [f"| {c} | {r} | {n} |" for (c, r), n in reasons.items()] + [""]
    failed = results[results["status"] != "ok"]
    if not failed.empty:
        lines += ["## Failed cases", "", "| case | class | error |", "|---|---|---|"]
        lines += [f"| {int(r.case_id)} | {r.class_name} | {str(r.error)[:120]} |" for r in failed.itertuples()] + [""]
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
