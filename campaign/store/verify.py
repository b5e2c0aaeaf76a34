"""`campaign verify DIR`: check every file of a campaign store against its integrity record.

Checked: ``manifest.json`` (valid JSON whose ``manifest_sha256`` matches its content), ``plan.parquet``
(sha256 recorded in the manifest), every file in ``cases/`` re-hashed and re-read whatever the index says
(size and sha256 recorded in its name, schema, and the identity recorded inside it against the store's:
a *foreign* file is bad; :func:`~campaign.store.case_index.verify_case_file`, on every core, with a
progress line on a terminal), the index segments (a bad one is a note: its files are verified again),
and ``results.parquet`` / ``timings.parquet`` (the sha256 of each part recorded in ``results.json``,
compacted from exactly the counted case files of the plan). Each bad file is one line ``path: what is
wrong``; files that are fine but not counted (superseded copies of a case, cases outside the plan,
temporary files of a killed writer) are ``note:`` lines. Reads only: ``campaign submit`` moves bad case
files to ``rejected/`` and recomputes them.
"""
from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from campaign.store.campaign_store import CampaignStore, StoreError
from campaign.store.case_index import list_case_files, verify_case_file

PROGRESS_EVERY_S = 2.0


@dataclass
class Verification:
    problems: list[tuple[Path, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    verified_cases: int = 0

    @property
    def clean(self) -> bool:
        return not self.problems


def _terminal_progress(done: int, total: int) -> None:
    print(f"\rverify: {done} of {total} case files re-hashed", end="" if done < total else "\n",
          file=sys.stderr, flush=True)


def verify_store(root: str | Path, progress: Callable[[int, int], None] | None | str = "terminal",
                 workers: int | None = None) -> Verification:
    """Check a store; StoreError (one line) when ``root`` is not a campaign store at all.

    ``progress``: called with (files done, files) every few seconds ("terminal": a line on stderr when it
    is a terminal; None: silent); ``workers``: threads re-hashing files (default: the cores)."""
    store = CampaignStore(root)
    if not store.root.is_dir():
        raise StoreError(f"{store.root}: not a directory; allowed: a campaign output directory")
    report: Callable[[int, int], None] | None = (
        (_terminal_progress if sys.stderr.isatty() else None) if progress == "terminal"
        else progress if callable(progress) else None)
    result = Verification()
    manifest, problem = store._manifest_state()
    if manifest is None and problem is None:
        if not store.cases_dir.is_dir() and not store.plan_path.exists():
            raise StoreError(f"{store.root}: no manifest.json, plan.parquet or cases/: not a campaign directory")
        problem = "missing: the store's case files cannot be attributed to a configuration"
    if problem is not None:
        result.problems.append((store.manifest_path, problem))
    expected = store.identity()
    listing = list_case_files(store.cases_dir)
    result.problems += listing.bad
    result.notes += [f"{path}: temporary file of an interrupted writer (ignored)" for path in listing.temporary]
    names = [relative for relative, _, _ in listing.files]
    done, last = 0, time.monotonic()
    with ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:   # hashing and Parquet release the GIL
        for relative, (_, file_problem) in zip(names, pool.map(
                lambda relative: verify_case_file(store.cases_dir / relative, relative, expected), names)):
            if file_problem is not None:
                result.problems.append((store.cases_dir / relative, file_problem))
            done += 1
            if report is not None and (time.monotonic() - last >= PROGRESS_EVERY_S or done == len(names)):
                report(done, len(names))
                last = time.monotonic()
    scan = store.scan(record=False)        # the counted case of each file (every file was just re-hashed)
    bad_paths = {path for path, _ in result.problems}
    result.notes += [f"{path}: {reason} (not counted)" for path, reason in scan.superseded if path not in bad_paths]
    result.notes += [f"{path}: bad index segment, {reason}" for path, reason in store._index.bad]
    bad_names = {str(path.relative_to(store.cases_dir)) for path in bad_paths if store.cases_dir in path.parents}
    counted_names = scan.counted.file_names().tolist() if bad_names else []
    result.verified_cases = int(len(scan.case_ids)) - sum(name in bad_names for name in counted_names)
    planned = None
    if manifest is not None:
        plan_problem = store._plan_problem(manifest)
        if plan_problem is not None:
            result.problems.append((store.plan_path, plan_problem))
        else:
            planned = store.planned_case_array()
    if planned is not None:
        outside = scan.case_ids[~scan.in_plan(planned)]
        if len(outside):
            result.notes.append(f"{store.cases_dir}: {len(outside)} verified cases outside the plan (kept, not "
                                f"counted), e.g. case {int(outside[0])} in {scan.path_of(int(outside[0])).name}")
        if store.results_path.exists() or store.results_record_path.exists():
            results_problem = store.results_problem(scan, planned, deep=True)
            if results_problem is not None:
                result.problems.append((store.results_path, results_problem))
    if store.rejected_dir.is_dir():
        count = sum(1 for path in store.rejected_dir.iterdir() if path.name != "rejected.log")
        result.notes.append(f"{store.rejected_dir}: {count} files rejected earlier (see rejected.log)")
    return result
