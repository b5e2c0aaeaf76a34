"""Plan and submit a campaign: the glue between config, planner, store, dask runner and tables."""
from __future__ import annotations

import importlib.metadata
import platform
import sys
import time
from pathlib import Path

import pandas as pd

from flight_interface.tomlfields import ConfigError

from campaign.report.aggregate import format_table, site_table
from campaign.run.worker import CampaignContext, load_resources
from campaign.report.compare import COMPARISON_NOTE, comparison_table, estimator_names, format_comparison, with_estimator_column
from campaign.configuration.campaign_file import CampaignConfig
from campaign.plan.coverage import refusal
from campaign.plan.placement import ClassPlanInput, plan_class
from campaign.report.plots import footprint_map
from campaign.run.cluster import connected_client, require_backend
from campaign.run.faults import RunStopped
from campaign.run.dask_runner import RunSummary, Watch, run_cases
from campaign.store.campaign_store import CampaignStore, StoreError

PACKAGES = ("moc2dimes", "numpy", "scipy", "dask", "distributed", "pandas", "pyarrow",
            "opencv-contrib-python-headless")


def plan_campaign(config: CampaignConfig):
    """Load what planning needs (camera, trajectories, terrain extents) and plan every class.

    Raises ConfigError (one line) for a class whose terrain cannot hold the trajectory set's footprints
    (:mod:`campaign.plan.coverage`), before anything is written."""
    resources = load_resources(config)
    frames = []
    for index, entry in enumerate(config.site.classes):
        count = config.cases_per_class[entry.name]
        if count == 0:
            continue
        terrain = resources.terrain(entry.name)
        cover = resources.coverage(terrain)
        if not cover.holds:
            raise ConfigError(f"{config.source}: {refusal(entry.name, terrain, cover)}")
        spec = ClassPlanInput(class_name=entry.name, class_index=index, ellipse_fraction=entry.ellipse_fraction,
                              cases=count, terrain_name=terrain.name, terrain_extent_m=terrain.extent_m,
                              margin_m=2.0 * terrain.metres_per_pixel)
        frames.append(plan_class(resources.camera, resources.profiles, spec, config.seed))
    plan = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return resources, plan


def manifest_for(config: CampaignConfig) -> dict:
    versions = {}
    for package in PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return {
        "config_file": str(config.source), "config_hash": config.config_hash, "config": config.resolved,
        "seed": config.seed, "site": config.site.name, "cases_per_class": config.cases_per_class,
        "ellipse_fractions": {entry.name: entry.ellipse_fraction for entry in config.site.classes},
        "python": platform.python_version(), "packages": versions,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def submit(config: CampaignConfig, scheduler: str | None = None, workers: int | None = None,
           fresh: bool = False, progress: bool = True, wait: bool = False) -> tuple[RunSummary, str]:
    """Run every missing case of ``config``, compact the store and return the table text.

    Order (so that a refusal changes nothing): check the cluster settings and plan (config errors),
    check the store read-only (StoreError: another configuration, corrupt manifest, ... unless
    ``fresh``), take the store's lock (:class:`~campaign.store.lock.StoreBusy` when another writer holds
    it, unless ``wait``), check again under the lock, start or connect to the cluster, and only then
    prepare the store (with ``fresh``: move the old store aside to ``DIR.previous-<UTC time>``), reject
    bad case files and run.

    Raises RunStopped (one line) when the run could not go on: the finished cases are compacted first
    (when the store was prepared; a cluster that cannot start leaves the store untouched)."""
    execution = config.execution.with_overrides(scheduler, workers)
    require_backend(execution, str(config.source))
    resources, plan = plan_campaign(config)
    store = CampaignStore(config.output_dir)
    manifest = manifest_for(config)
    store.check(manifest, plan, fresh=fresh)
    with store.lock(wait=wait, on_wait=lambda line: print(line, file=sys.stderr, flush=True)):
        store.check(manifest, plan, fresh=fresh)
        prepared = False
        try:
            with connected_client(execution) as client:
                for line in store.prepare(manifest, plan, fresh=fresh):
                    print(line, flush=True)
                prepared = True
                context = CampaignContext.from_config(config, store.root)
                summary = run_cases(context, store, store.plan(), client, progress=progress,
                                    watch=Watch.from_execution(execution))
        except RunStopped as stop:
            raise RunStopped(f"{stop}{compact_after_stop(store) if prepared else ''}") from None
        store.compact()
    return summary, write_table(store.root, config.false_valid_mps)


def compact_after_stop(store: CampaignStore) -> str:
    """Compact the finished cases of a stopped run; "" or the reason it could not (e.g. the disk is full)."""
    try:
        store.compact()                 # a failed write removes its own temporary file (store_files)
    except OSError as exc:
        return f" (results.parquet not rewritten: {exc.strerror or type(exc).__name__})"
    return ""


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
    results = with_estimator_column(store.results())
    fractions = manifest["ellipse_fractions"]
    threshold = false_valid_threshold(manifest) if false_valid_mps is None else false_valid_mps
    site = manifest["site"].capitalize()
    names = estimator_names(results)
    status = store.status()
    heading = (f"{site}: {status.done + status.failed} of {status.planned} cases finished"
               f" ({status.failed} failed, {status.missing} missing), seed {manifest['seed']}"
               f"{', estimators ' + ', '.join(names) if names else ''}")
    text, markdown = [heading], [heading, ""]
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
    (store.root / "table.md").write_text("\n".join(markdown) + "\n")
    comparison.to_csv(store.root / "table.csv", index=False)
    return "\n".join(text)


def write_plan_maps(config: CampaignConfig, resources, plan: pd.DataFrame, out_dir: Path) -> list[Path]:
    """One footprint map PNG per class (paper Fig. 5)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for class_name, members in plan.groupby("class_name", sort=False):
        terrain = resources.terrain(class_name)
        placed = [resources.placed_profile(row) for row in members.to_dict("records")]
        path = out_dir / f"footprints-{class_name}.png"
        footprint_map(terrain, placed, resources.camera, path,
                      f"{config.site.name} {class_name}: {len(members)} cases (first 60 shown); "
                      "+ lander at each image, red/orange/cyan image 1/2/3 footprints")
        paths.append(path)
    return paths
