"""Running a sensitivity sweep: every point of a sweep (base campaign x parameter axes) on one dask cluster,
a batch of points at a time, reusing points by configuration hash.

Output directory (``[sweep] output_dir`` or ``--output``)::

    OUT/points/<hash[:16]>/   one campaign store per point configuration (manifest, plan, cases/...,
                              results.parquet, examples/); kept across runs, so a point whose
                              configuration hash is unchanged is reused and a killed sweep resumes
                              with only its missing cases

The rest of the directory (sweep.json, results.parquet, the sensitivity table and plots) is written after
the run by :mod:`campaign.report.sweep_outputs` (``campaign.cli``); the baseline check is
:mod:`campaign.report.gate`. The configuration hash covers the result code
(:func:`campaign.configuration.campaign_file.code_digest`), so after a code change every point is computed
afresh.

Reuse from a previous directory (``campaign sweep FILE --output NEW --reuse PREVIOUS``,
:func:`reuse_points`): a point whose store is not yet in NEW is copied from ``PREVIOUS/points/<hash[:16]>``
when, and only when,

* the previous store's sealed manifest records the point's full configuration hash. The hash covers every
  resolved table (sensors, estimator and plug-in parameters, scene, site content), the bytes of the
  camera, trajectory and terrain files, the digest of the case computation's code (the import closure
  of :data:`campaign.configuration.code_identity.CASE_MODULES`, plug-in modules included) and of every
  plug-in's own files (:func:`campaign.configuration.estimators.estimator_code_digests`): an equal hash
  means the same configuration computed by the same code;
* the manifest records the same Python version and versions of the numerical packages
  (:func:`campaign.run.orchestrate.package_versions`) as this process (a numpy upgrade recomputes);
* the copy passes ``campaign verify`` (:func:`campaign.store.verify.verify_store`): manifest seal, plan
  sha256, every case file's size, sha256, schema and recorded identity (configuration hash, case id,
  seed, estimators), and the compacted results against their record.

The previous store is copied under its writer lock (a store being written is not reused; a read-only
one is copied without it), into a
temporary directory beside the new store and renamed into place only when verified; anything else is
computed as usual, with one note saying why. The copy then enters the run like any existing store: its
missing cases (a larger ``cases_scale``) are computed, the others kept.
"""
from __future__ import annotations

import os
import platform
import shutil
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from campaign.configuration.sweep_designs import DESIGN_MODES
from campaign.configuration.sweep_file import SweepPoint, SweepSpec
from campaign.run.cluster import require_backend
from campaign.run.orchestrate import StorePoint, cluster_session, manifest_for, package_versions, run_store_points
from campaign.run.planning import plan_campaign
from campaign.run.security import require_secure_transport
from campaign.store.campaign_store import CampaignStore
from campaign.store.errors import StoreError
from campaign.store.lock import StoreBusy
from campaign.store.verify import verify_store

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


def _ignore_note(line: str) -> None:
    """A point store's preparation lines are not shown (the sweep's progress lines say enough)."""


class PointStores:
    """Each point's :class:`~campaign.run.orchestrate.StorePoint`, made when the sweep reaches the point: its
    manifest (the campaign's, plus the sweep file and the point's axis values) and its plan, planned once
    per distinct (campaign file, seed, case counts) and kept."""

    def __init__(self, spec: SweepSpec):
        self.spec = spec
        self.plans: dict[tuple, pd.DataFrame] = {}

    def __call__(self, point: SweepPoint) -> StorePoint:
        config = point.config
        key = (str(config.source), config.seed, tuple(sorted(config.cases_per_class.items())))
        if key not in self.plans:
            self.plans[key] = plan_campaign(config)[1]
        return StorePoint(config, {**manifest_for(config), "sweep_file": str(self.spec.source),
                                   "sweep_point": point.values}, self.plans[key])


def distinct_points(spec: SweepSpec) -> list[SweepPoint]:
    """The points to run: every point, except that of the rows of a designed sweep (Sobol, Morris) that repeat
    a configuration only the first is run (they share its store)."""
    if spec.mode not in DESIGN_MODES:
        return list(spec.points)
    first_of_store: dict[Path, SweepPoint] = {}
    for point in spec.points:
        first_of_store.setdefault(Path(point.config.output_dir), point)
    return list(first_of_store.values())


def point_batches(spec: SweepSpec, planned_cases: int):
    """The sweep's distinct points (:func:`distinct_points`) in order, in runs of consecutive points holding
    about :data:`BATCH_CASES` planned cases (at most :data:`BATCH_POINTS` points; a larger point alone); the
    first run is at most :data:`FIRST_BATCH_POINTS` long, so the first cases are submitted as soon as the
    cluster is up."""
    size = max(1, min(BATCH_POINTS, BATCH_CASES // max(1, planned_cases)))
    points = distinct_points(spec)
    first, total = 0, len(points)
    while first < total:
        count = min(size, FIRST_BATCH_POINTS) if first == 0 else size
        yield first, points[first:first + count]
        first += count


def run_sweep(spec: SweepSpec, scheduler: str | None = None, workers: int | None = None,
              progress: bool = True, wait: bool = False) -> SweepRun:
    """Run every point's missing cases on one cluster, a batch of points at a time (:func:`point_batches`):
    a batch's points are validated, planned and their stores checked and locked only when the sweep reaches
    them; each store is prepared and its cases submitted at once (workers compute while the next store is
    prepared); the batch's cases are waited for, its stores compacted and unlocked before the next batch.
    A sweep of 10^4 points starts computing within seconds, and a sweep stopped at any time keeps every
    finished case (the next run reuses finished points and runs the rest). A new sweep starts the cluster at
    once (while its first point is planned); a sweep run before (``points/`` exists) starts it at the first
    batch with a case to run (:meth:`CampaignStore.has_every_case`), so a finished sweep run again starts none.
    With ``progress``, one line on stderr when the cluster starts and per batch (points reached, cases done,
    failed, reused points).

    Raises StoreBusy (a point store locked by another writer), StoreError, ConfigError (a point that
    does not validate) or RunStopped, each after the batches before it were completed and compacted."""
    start = time.perf_counter()
    execution = spec.base.execution.with_overrides(scheduler, workers)
    require_backend(execution, str(spec.source))
    require_secure_transport(execution, str(spec.source))
    total = len(distinct_points(spec))
    planned_each = max(sum(base.cases_per_class.values()) for base in spec.all_bases)

    def say(line: str) -> None:
        if progress:
            print(f"sweep: {line}", file=sys.stderr, flush=True)

    # a sweep run before (its point stores exist) starts the cluster at its first point with a case to run: a
    # finished sweep run again starts none (no batch job queued); a new one starts it at once, while the first
    # point is planned
    rerun = (Path(spec.output_dir) / "points").is_dir()
    say(f"{total} points of {planned_each} cases; "
        + ("the cluster starts at the first point with a case to run" if rerun else "starting the cluster"))
    stores_of = PointStores(spec)
    reached = reused = submitted = done = failed = unfinished = 0
    with ThreadPoolExecutor(max_workers=1) as planner, ExitStack() as cluster:
        first_plan = planner.submit(stores_of, spec.points[0])      # planned while the cluster starts
        client = None if rerun else cluster.enter_context(cluster_session(execution, spec.estimators))
        first_plan.result()
        for first, batch in point_batches(spec, planned_each):
            points = [stores_of(point) for point in batch]
            if client is None and not all(CampaignStore(point.store_dir).has_every_case(point.manifest, point.plan)
                                          for point in points):
                say("starting the cluster")
                client = cluster.enter_context(cluster_session(execution, spec.estimators))
            say(f"points {batch[0].point_id}-{batch[-1].point_id} ({first + len(batch)} of {total}): "
                f"{done} cases done, {failed} failed, {reused} points reused so far, "
                f"{time.perf_counter() - start:.0f} s")
            run = run_store_points(points, execution, client=client, wait=wait, progress=progress,
                                   on_note=_ignore_note)
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


@dataclass
class Reuse:
    """What :func:`reuse_points` did: point id -> the directory its store was copied from, and one note
    per point of the previous directory that was not reused (why)."""

    reused: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def reuse_points(spec: SweepSpec, previous: str | Path, progress: bool = True) -> Reuse:
    """Copy into the sweep's output directory every point store of ``previous`` (an earlier sweep's output
    directory) whose configuration and code are unchanged and which verifies (module docstring). Points
    already in the output directory are left alone. StoreError (one line) when ``previous`` is not a
    sweep directory."""
    previous = Path(previous)
    if not (previous / "points").is_dir():
        raise StoreError(f"--reuse {previous}: no points/ directory: not a sweep output directory; allowed: the "
                         "output directory of an earlier `campaign sweep`")
    if Path(os.path.abspath(previous)) == Path(os.path.abspath(spec.output_dir)):
        return Reuse()          # the output directory's own points are reused anyway
    outcome = Reuse()
    versions = {"python": platform.python_version(), **package_versions()}
    changed: list[str] = []         # points without a store of their configuration hash in ``previous``
    for point in spec.points:
        target = Path(point.config.output_dir)
        source = previous / "points" / target.name
        if (target / "manifest.json").exists():
            continue
        if not source.is_dir():
            changed.append(point.point_id)
            continue
        problem = _copy_verified(source, target, point.config_hash, versions)
        where = f"{point.point_id} ({source})"
        if problem is None:
            outcome.reused[point.point_id] = str(previous)
        else:
            outcome.notes.append(f"{where}: not reused, computed: {problem}")
    if changed:
        shown = ", ".join(changed[:5]) + (f" and {len(changed) - 5} more" if len(changed) > 5 else "")
        outcome.notes.append(f"{shown}: no store of the same configuration hash in {previous} (a changed "
                             "configuration, input file or code since; the hash covers all three): computed")
    if progress:
        print(f"sweep: --reuse {previous}: {len(outcome.reused)} point stores copied and verified"
              + (f", {len(outcome.notes)} not reused" if outcome.notes else ""), file=sys.stderr, flush=True)
    return outcome


def _copy_verified(source: Path, target: Path, config_hash: str, versions: dict[str, str]) -> str | None:
    """Copy the store ``source`` to ``target`` if its manifest records ``config_hash`` and ``versions`` and the
    copy verifies; None when copied, else why not (nothing left behind)."""
    try:
        manifest = CampaignStore(source).manifest()
    except StoreError as exc:
        return str(exc)
    if manifest is None:
        return "no manifest.json"
    if manifest.get("config_hash") != config_hash:
        return f"configuration hash {str(manifest.get('config_hash'))[:12]} != {config_hash[:12]}"
    recorded = {"python": manifest.get("python"), **(manifest.get("packages") or {})}
    changed = [f"{name} {recorded.get(name)} -> {version}" for name, version in versions.items()
               if recorded.get(name) != version]
    if changed:
        return "computed with other package versions (" + ", ".join(changed) + ")"
    staging = target.with_name(f".reuse-{target.name}-{os.getpid()}")
    try:
        with ExitStack() as locks:
            try:
                locks.enter_context(CampaignStore(source).lock())
            except PermissionError:     # a read-only archive: nobody writes it; the copy is verified anyway
                pass
            locks.enter_context(CampaignStore(target).lock())
            shutil.rmtree(staging, ignore_errors=True)
            shutil.copytree(source, staging, symlinks=True, ignore=shutil.ignore_patterns(".tmp-*", "rejected"))
            check = verify_store(staging)
            if check.problems:
                path, what = check.problems[0]
                return f"the copy does not verify ({len(check.problems)} bad files, e.g. {Path(path).name}: {what})"
            if (target / "manifest.json").exists():
                return "its store appeared in the output directory meanwhile"
            os.rename(staging, target)
    except StoreBusy as exc:
        return f"its store is being written ({exc})"
    except (OSError, StoreError) as exc:
        return f"cannot be copied ({exc})"
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return None
