"""Plan and run campaigns: the one plan/prepare/run/compact path (:func:`run_store_points`) that
``campaign submit`` (one store) and ``campaign sweep`` (one store per point) share, and the tables."""
from __future__ import annotations

import functools
import importlib.metadata
import platform
import sys
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from campaign.configuration.campaign_file import CampaignConfig
from campaign.configuration.execution import ExecutionConfig
from campaign.plan.coverage import refusal, relief_margin_m
from campaign.plan.density import footprint_density
from campaign.plan.placement import ClassPlanInput, plan_class
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
from campaign.report.plots import footprint_map
from campaign.run.case import PlanRow
from campaign.run.cluster import connected_client, require_backend
from campaign.run.dask_runner import RunSummary, Watch, submit_cases, wait_for_cases
from campaign.run.faults import RunStopped
from campaign.run.plugin_setup import PluginSetupError, ship_plugin_code
from campaign.run.worker import CampaignContext, load_resources
from campaign.store.campaign_store import CampaignStore, StoreError
from flight_interface.tomlfields import ConfigError

FOOTPRINTS_DRAWN = 60   # outlines drawn on a footprint map; every case is in its density layer
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
                              margin_m=2.0 * terrain.metres_per_pixel
                              + relief_margin_m(terrain, resources.camera, resources.profiles))
        frames.append(plan_class(resources.camera, resources.profiles, spec, config.seed))
    plan = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return resources, plan


@functools.lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """The versions of :data:`PACKAGES` (read once per process: a sweep records them in every point's manifest)."""
    versions = {}
    for package in PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def manifest_for(config: CampaignConfig) -> dict:
    versions = dict(package_versions())
    return {
        "config_file": str(config.source), "config_hash": config.config_hash, "config": config.resolved,
        "seed": config.seed, "site": config.site.name, "cases_per_class": config.cases_per_class,
        "estimators": config.estimator_names,     # what every case file records (campaign.store.case_identity)
        "ellipse_fractions": {entry.name: entry.ellipse_fraction for entry in config.site.classes},
        "python": platform.python_version(), "packages": versions,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


@dataclass(frozen=True)
class StorePoint:
    """One campaign configuration, the store its cases go to, and what that store records of it."""

    config: CampaignConfig
    manifest: dict          # the store's manifest.json content (before sealing)
    plan: pd.DataFrame      # every planned case of the configuration

    @property
    def store_dir(self) -> Path:
        return Path(self.config.output_dir)


@dataclass(frozen=True)
class PreparedPoint:
    """A store brought up to date under its lock, and the plan rows it still has to run."""

    point: StorePoint
    store: CampaignStore
    todo: list[dict]


@dataclass(frozen=True)
class StoresRun:
    """What :func:`run_store_points` did: every point's prepared store, and the cases of this run."""

    prepared: list[PreparedPoint]
    done: int
    failed: int

    @property
    def submitted(self) -> int:
        return sum(len(entry.todo) for entry in self.prepared)


def run_store_points(points: list[StorePoint], execution: ExecutionConfig, *, fresh: bool = False,
                     progress: bool = True, wait: bool = False,
                     on_note: Callable[[str], None] = lambda line: print(line, flush=True)) -> StoresRun:
    """Run every missing case of every point's store on one cluster and compact the stores: the
    plan/prepare/run/compact path of ``campaign submit`` (one point); ``campaign sweep`` takes the same
    steps (:func:`lock_stores`, :func:`ship_estimators`, :func:`run_locked_points`) a batch of points at a
    time (:func:`campaign.run.sweep.run_sweep`).

    Order (so that a refusal changes nothing; the caller has planned and checked the cluster settings
    with :func:`~campaign.run.cluster.require_backend`): check every store read-only (StoreError: another configuration, corrupt manifest, ... unless
    ``fresh``), take every store's lock in path order (:class:`~campaign.store.lock.StoreBusy` when
    another writer holds one, unless ``wait``), check again under the locks, start or connect to the
    cluster, ship the python plug-ins' code to its workers (:mod:`campaign.run.plugin_setup`; a worker that
    cannot import one stops the run before any store changes), and only then prepare the stores (with ``fresh``: move an old store aside to
    ``DIR.previous-<UTC time>``; ``on_note`` gets one line per action), reject bad case files and run all
    missing cases together. A store is compacted when it ran cases or its results are not up to date.

    Parameters
    ----------
    points : list of StorePoint
        The configurations with their manifests and plans (distinct store directories).
    execution : ExecutionConfig
        Where the cases run (the command line's overrides applied).
    fresh, progress, wait
        As for :func:`submit`.
    on_note : callable
        Receives each line a store's preparation reports.

    Returns
    -------
    StoresRun
        Per point, its store and the plan rows that were still to run; done and failed cases of this run.

    Raises
    ------
    RunStopped
        One line, when the run could not go on: the finished cases are compacted first (a cluster that
        cannot start leaves every store untouched).
    """
    stores = [CampaignStore(point.store_dir) for point in points]
    for point, store in zip(points, stores):
        store.check(point.manifest, point.plan, fresh=fresh)
    with ExitStack() as locks:
        lock_stores(points, stores, locks, fresh=fresh, wait=wait)
        with connected_client(execution) as client:
            ship_estimators(client, [spec for point in points for spec in point.config.estimators])
            return run_locked_points(client, points, stores, execution, fresh=fresh, progress=progress,
                                     on_note=on_note)


def lock_stores(points: list[StorePoint], stores: list[CampaignStore], locks: ExitStack, *, fresh: bool = False,
                wait: bool = False) -> None:
    """Take every store's lock in path order (held until ``locks`` closes; StoreBusy when another writer
    holds one, unless ``wait``), then check every store again under its lock (StoreError)."""
    for store in sorted(stores, key=lambda store: str(store.root)):
        locks.enter_context(store.lock(wait=wait, on_wait=lambda line: print(line, file=sys.stderr, flush=True)))
    for point, store in zip(points, stores):
        store.check(point.manifest, point.plan, fresh=fresh)


def ship_estimators(client, specs: list) -> None:
    """Ship the python plug-ins' code to the workers before any store changes (RunStopped, one line, when a
    worker cannot import one: nothing changed)."""
    try:
        ship_plugin_code(client, specs)
    except PluginSetupError as problem:
        raise RunStopped(f"run stopped before any case ran: {problem}") from None


def run_locked_points(client, points: list[StorePoint], stores: list[CampaignStore], execution: ExecutionConfig, *,
                      fresh: bool = False, progress: bool = True,
                      on_note: Callable[[str], None] = lambda line: print(line, flush=True)) -> StoresRun:
    """With the stores locked (:func:`lock_stores`) and the plug-ins shipped: prepare each store and submit its
    missing cases at once (they run while the next store is prepared), wait for all of them and compact
    the stores (RunStopped: the finished cases compacted first, as :func:`run_store_points` says)."""
    prepared: list[PreparedPoint] = []
    tasks: list = []
    done = failed = 0
    try:
        for point, store in zip(points, stores):
            for line in store.prepare(point.manifest, point.plan, fresh=fresh):
                on_note(line)
            finished = store.finished_case_ids()
            todo = [row for row in store.plan().to_dict("records") if int(row["case_id"]) not in finished]
            prepared.append(PreparedPoint(point, store, todo))
            if todo:
                tasks += submit_cases(client, CampaignContext.from_config(point.config, store.root), todo, store)
        if tasks:
            done, failed = wait_for_cases(client, tasks, Watch.from_execution(execution), progress)
    except RunStopped as stop:
        problems = {compact_after_stop(entry.store) for entry in prepared} - {""}
        raise RunStopped(f"{stop}{min(problems, default='')}") from None
    for entry in prepared:
        if entry.todo or entry.store.results_problem() is not None:
            entry.store.compact()
    return StoresRun(prepared, done, failed)


def submit(config: CampaignConfig, scheduler: str | None = None, workers: int | None = None,
           fresh: bool = False, progress: bool = True, wait: bool = False) -> tuple[RunSummary, str]:
    """Run every missing case of ``config`` (:func:`run_store_points` with one point), compact the store
    and return the run's summary and the table text.

    Raises
    ------
    ConfigError
        Cluster settings or a class whose terrain cannot hold the footprints (nothing written).
    StoreError, StoreBusy, RunStopped
        As :func:`run_store_points`.
    """
    start = time.perf_counter()
    execution = config.execution.with_overrides(scheduler, workers)
    require_backend(execution, str(config.source))
    _, plan = plan_campaign(config)
    point = StorePoint(config, manifest_for(config), plan)
    run = run_store_points([point], execution, fresh=fresh, progress=progress, wait=wait)
    summary = RunSummary(run.submitted, run.done, run.failed, time.perf_counter() - start)
    return summary, write_table(point.store_dir, config.false_valid_mps)


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


def write_plan_maps(config: CampaignConfig, resources, plan: pd.DataFrame, out_dir: Path) -> list[Path]:
    """One footprint map PNG per class (paper Fig. 5)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for class_name, members in plan.groupby("class_name", sort=False):
        terrain = resources.terrain(class_name)
        drawn = members.head(FOOTPRINTS_DRAWN)      # outlines of the first cases; all cases as a density
        placed = [resources.placed_profile(PlanRow.from_record(row)) for row in drawn.to_dict("records")]
        density = footprint_density(resources.camera, resources.profiles, members, terrain.extent_m)
        path = out_dir / f"footprints-{class_name}.png"
        footprint_map(terrain, placed, resources.camera, path,
                      f"{config.site.name} {class_name}: {len(members)} cases\nfirst {len(drawn)} drawn: + lander "
                      "at each image,\nred/orange/cyan image 1/2/3 footprints;\ncolour: footprint centres of all",
                      max_cases=FOOTPRINTS_DRAWN, density=density)
        paths.append(path)
    return paths
