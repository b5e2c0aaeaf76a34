"""``campaign table DIR`` (and the table ``campaign submit`` prints after its run): the paper's table of each
estimator and the estimators side by side, from a store; written as ``table.md`` and ``table.csv`` beside it."""
from __future__ import annotations

from pathlib import Path

from campaign.configuration.execution import no_op_banner
from campaign.report.aggregate import format_table, site_table
from campaign.report.compare import (
    COMPARISON_NOTE,
    comparison_table,
    counts_line,
    estimator_counts,
    estimator_names,
    format_comparison,
    with_estimator_column,
)
from campaign.store.campaign_store import CampaignStore
from campaign.store.errors import StoreError

TABLE_COLUMNS = ("case_id", "class_name", "estimator", "status", "error", "reason", "valid", "velocity_error_mps",
                 "estimate_velocity_east_mps", "estimate_velocity_north_mps", "truth_velocity_east_mps",
                 "truth_velocity_north_mps", "attitude_floor_mps", "sensor_attitude_bias_east_rad",
                 "sensor_attitude_bias_north_rad")
"""The result columns the tables read (a store of 10^6 cases is loaded in a second, not all its columns)."""


def false_valid_threshold(manifest: dict) -> float:
    """The campaign's ``[campaign] false_valid_mps`` as recorded in its manifest (default 5 m/s)."""
    return float(manifest.get("config", {}).get("campaign", {}).get("false_valid_mps", 5.0))


def write_table(root: Path, false_valid_mps: float | None = None) -> str:
    """The paper's table of each estimator and the estimators side by side (with false-valid counts),
    from a store; write table.md and table.csv (the side-by-side rows) beside it; return the text.
    ``false_valid_mps``: the false-valid threshold (default: the one in the store's manifest)."""
    store = CampaignStore(root)
    manifest = store.manifest()
    if manifest is None:
        raise StoreError(f"{root}: no manifest.json: not a campaign directory")
    results = with_estimator_column(store.results(columns=list(TABLE_COLUMNS)))
    fractions = manifest["ellipse_fractions"]
    threshold = false_valid_threshold(manifest) if false_valid_mps is None else false_valid_mps
    site = manifest["site"].capitalize()
    names = estimator_names(results)
    status = store.status()
    heading = (f"{site}: {status.done + status.failed} of {status.planned} cases finished"
               f" ({status.failed} failed, {status.missing} missing), seed {manifest['seed']}"
               f"{', estimators ' + ', '.join(names) if names else ''}")
    banner = no_op_banner(manifest)
    if banner:                                   # an orchestration test: never mistaken for results
        heading = f"{banner}\n{heading}"
    counts = estimator_counts(results)
    text, markdown = [heading], [heading, ""]
    if counts:
        text.append(counts_line(counts))
        markdown[1:1] = ["", counts_line(counts)]
    for name in names:
        table = site_table(results[results["estimator"] == name], fractions, site, class_order=list(fractions),
                           false_valid_mps=threshold)
        text += [f"estimator {name}:", format_table(table)]
        markdown += [f"### Estimator `{name}`", "", format_table(table, markdown=True), ""]
    comparison = comparison_table(results, fractions, site, list(fractions), names, false_valid_mps=threshold)
    if names:
        text += ["estimators side by side:", format_comparison(comparison), COMPARISON_NOTE]
        markdown += ["### Estimators side by side", "", format_comparison(comparison, markdown=True), "",
                     COMPARISON_NOTE, ""]
    try:
        (store.root / "table.md").write_text("\n".join(markdown) + "\n")
        comparison.to_csv(store.root / "table.csv", index=False)
    except OSError as exc:      # a read-only store (an archive, a read-only mount): printed, not written
        text.append(f"note: table.md and table.csv not written in {store.root}: {exc.strerror or exc}")
    return "\n".join(text)
