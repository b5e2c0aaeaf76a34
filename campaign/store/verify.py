"""`campaign verify DIR`: check every file of a campaign store against its integrity record.

Checked: ``manifest.json`` (valid JSON whose ``manifest_sha256`` matches its content), ``plan.parquet``
(sha256 recorded in the manifest), every file in ``cases/`` (size and sha256 recorded in its name, schema,
and the identity recorded inside it against the store's: a *foreign* file is bad), and
``results.parquet`` / ``timings.parquet`` (sha256 recorded in ``results.json``, compacted from exactly the
verified case files of the plan). Each bad file is one line ``path: what is wrong``; files that are
fine but not counted (superseded copies of a case, cases outside the plan, temporary files of a killed
writer) are ``note:`` lines. Reads only: ``campaign submit`` moves bad case files to ``rejected/`` and
recomputes them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from campaign.store.campaign_store import CampaignStore, StoreError


@dataclass
class Verification:
    problems: list[tuple[Path, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    verified_cases: int = 0

    @property
    def clean(self) -> bool:
        return not self.problems


def verify_store(root: str | Path) -> Verification:
    """Check a store; StoreError (one line) when ``root`` is not a campaign store at all."""
    store = CampaignStore(root)
    if not store.root.is_dir():
        raise StoreError(f"{store.root}: not a directory; allowed: a campaign output directory")
    result = Verification()
    manifest, problem = store._manifest_state()
    scan = store.scan()
    if manifest is None and problem is None:
        if not store.cases_dir.is_dir() and not store.plan_path.exists():
            raise StoreError(f"{store.root}: no manifest.json, plan.parquet or cases/: not a campaign directory")
        problem = "missing: the store's case files cannot be attributed to a configuration"
    if problem is not None:
        result.problems.append((store.manifest_path, problem))
    planned = None
    if manifest is not None:
        plan_problem = store._plan_problem(manifest)
        if plan_problem is not None:
            result.problems.append((store.plan_path, plan_problem))
        else:
            planned = store.planned_case_ids()
    result.problems += scan.bad
    result.notes += [f"{path}: {reason} (not counted)" for path, reason in scan.superseded]
    result.notes += [f"{path}: temporary file of an interrupted writer (ignored)" for path in scan.temporary]
    result.verified_cases = len(scan.cases)
    if planned is not None:
        outside = sorted(set(scan.cases) - planned)
        if outside:
            result.notes.append(f"{store.cases_dir}: {len(outside)} verified case files of cases outside the plan "
                                f"(kept, not counted), e.g. {scan.cases[outside[0]].path.name}")
        if store.results_path.exists() or store.results_record_path.exists():
            results_problem = store.results_problem(scan, planned)
            if results_problem is not None:
                result.problems.append((store.results_path, results_problem))
    if store.rejected_dir.is_dir():
        count = sum(1 for path in store.rejected_dir.iterdir() if path.name != "rejected.log")
        result.notes.append(f"{store.rejected_dir}: {count} files rejected earlier (see rejected.log)")
    return result
