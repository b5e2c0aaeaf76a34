"""The campaign store: one directory per campaign, durable per-case results, a compacted dataset.

Layout::

    OUT/manifest.json          config (as resolved), its hash, input file digests, package versions, the
                               plan's sha256 and case count, and its own sha256 (``manifest_sha256``)
    OUT/plan.parquet           every planned case (ids, class, terrain, trajectory, placement, seeds)
    OUT/cases/case-<id>.<ok|failed>.<bytes>.<sha256>.parquet
                               the rows of one finished case, one per estimator (``estimator`` column, in
                               [[estimators]] order), written by the worker that computed it; the name
                               records size and sha256 (:mod:`campaign.store.case_files`); ``failed``: the
                               simulation failed after its retries (with its error)
    OUT/results.parquet        the verified rows of the planned cases, sorted by case_id (same seed -> same bits)
    OUT/timings.parquet        per-case stage timings and worker names (vary from run to run)
    OUT/results.json           what results.parquet and timings.parquet were compacted from (a fingerprint of
                               the case files) and their sha256: they are trusted only when both match
    OUT/rejected/              bad files moved out of the way (never deleted), ``rejected.log`` says why
    OUT.lock                   beside the store: one writer at a time (:mod:`campaign.store.lock`)

Integrity: every file is checked before it is trusted. A case file that is truncated, corrupted, has no
record, does not fit the result schema or is *foreign* (the identity recorded inside it - configuration
hash, case id, seed, estimators, schema version: :mod:`campaign.store.case_identity` - is not this
store's) is not counted by ``status``, never read by ``table`` or compaction, and is moved to
``rejected/`` and recomputed by the next ``submit``. Case files of cases that are not in the plan are
kept but not counted. A corrupt ``manifest.json`` or ``plan.parquet`` is a one-line error; ``campaign
verify DIR`` lists every bad file.
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from campaign.configuration.differences import describe_change
from campaign.configuration.paths import special_kind
from campaign.store.case_files import (
    CaseScan,
    atomic_write_bytes,
    atomic_write_table,
    fsync_directory,
    read_case_table,
    scan_case_files,
    sha256_bytes,
    sha256_file,
)
from campaign.store.case_identity import FOREIGN, StoreIdentity
from campaign.store.errors import StoreError
from campaign.store.lock import StoreLock, lock_path_for
from campaign.store.result_schema import CASE_FILE_SCHEMA, RESULTS_SCHEMA, TIMINGS_SCHEMA

if TYPE_CHECKING:
    import pandas as pd

# pandas is imported by the methods that make a DataFrame, when they run: `campaign status` and `verify` read a
# store with pyarrow alone (pandas is half of their start-up time).

FRESH_HINT = "`campaign submit --fresh` moves this store aside (DIR.previous-<UTC time>) and starts afresh"


@dataclass(frozen=True)
class CaseStatus:
    """Counts of the planned cases (``done``/``failed``: verified case files) and of the files not counted."""
    planned: int
    done: int
    failed: int
    bad: int = 0                 # case files that fail verification (their cases are missing)
    outside_plan: int = 0        # verified case files of cases not in the plan (kept, not counted)
    foreign: int = 0             # of ``bad``: files of another campaign, schema version, or without identity
    rejected: int = 0            # files moved to rejected/ earlier (see rejected/rejected.log)

    @property
    def missing(self) -> int:
        return self.planned - self.done - self.failed


def seal_manifest(manifest: dict) -> dict:
    """``manifest`` with ``manifest_sha256``: the sha256 of its canonical JSON without that key."""
    body = json.loads(json.dumps({k: v for k, v in manifest.items() if k != "manifest_sha256"}, sort_keys=True))
    return {**body, "manifest_sha256": sha256_bytes(json.dumps(body, sort_keys=True).encode())}


def manifest_problem(text: bytes) -> tuple[dict | None, str | None]:
    """Parse and verify a manifest's bytes: (manifest, None) or (None, what is wrong)."""
    try:
        manifest = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        return None, f"corrupt: not valid JSON ({str(exc).splitlines()[0]})"
    if not isinstance(manifest, dict):
        return None, "corrupt: not a JSON object"
    if "manifest_sha256" not in manifest:
        return None, "unrecorded: no manifest_sha256 (written by an older version or by hand), so it cannot be verified"
    if seal_manifest(manifest)["manifest_sha256"] != manifest["manifest_sha256"]:
        return None, "corrupted or edited: its content does not match the manifest_sha256 it records"
    for key in ("config_hash", "plan_sha256"):
        if not isinstance(manifest.get(key), str):
            return None, f"corrupt: no {key}"
    return manifest, None


def _first_difference(old: pd.DataFrame, new: pd.DataFrame) -> str | None:
    """The first case planned differently in two plans (over the case_ids in both), or None."""
    if set(old.columns) != set(new.columns):
        return f"the plan columns differ ({', '.join(sorted(set(old.columns) ^ set(new.columns)))})"
    common = sorted(set(old["case_id"].astype(int)) & set(new["case_id"].astype(int)))
    left = old.set_index(old["case_id"].astype(int)).loc[common, sorted(old.columns)]
    right = new.set_index(new["case_id"].astype(int)).loc[common, sorted(old.columns)]
    for column in left.columns:
        a, b = left[column].to_numpy(), right[column].to_numpy()
        for case_id, x, y in zip(common, a, b):
            if not (x == y or (isinstance(x, float) and isinstance(y, float) and x != x and y != y)):
                return f"case {case_id} has {column} = {x!r} in the stored plan and {y!r} in the new one"
    return None


class CampaignStore:
    """A campaign's output directory."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.cases_dir = self.root / "cases"
        self.manifest_path = self.root / "manifest.json"
        self.plan_path = self.root / "plan.parquet"
        self.results_path = self.root / "results.parquet"
        self.timings_path = self.root / "timings.parquet"
        self.results_record_path = self.root / "results.json"
        self.rejected_dir = self.root / "rejected"
        self.lock_path = lock_path_for(self.root)
        self._verified: dict[str, tuple] = {}   # case files this object has verified
        self._lock: StoreLock | None = None

    def lock(self, wait: bool = False, on_wait=None) -> StoreLock:
        """The store's writer lock (a context manager; :class:`~campaign.store.lock.StoreBusy` when held
        elsewhere and not ``wait``). :meth:`prepare` extends it to the store directory it creates."""
        self._lock = StoreLock(self.root, wait=wait, on_wait=on_wait)
        return self._lock

    def _hold_directory(self) -> None:
        """Lock the store directory itself (created if needed) when this object holds the writer lock."""
        self.root.mkdir(parents=True, exist_ok=True)
        if self._lock is not None and self._lock.held:
            self._lock.hold_store_directory()

    def identity(self) -> StoreIdentity | None:
        """What the store's case files must record (from the verified manifest; None without one)."""
        manifest, _ = self._manifest_state()
        return StoreIdentity.of_manifest(manifest) if manifest is not None else None

    # --- identity: manifest and plan ----------------------------------------------------------
    def manifest(self) -> dict | None:
        """The verified manifest, None when there is none; StoreError (one line) when it is corrupt."""
        manifest, problem = self._manifest_state()
        if problem is not None:
            raise StoreError(f"{self.manifest_path}: {problem}; {FRESH_HINT}")
        return manifest

    def _manifest_state(self) -> tuple[dict | None, str | None]:
        kind = special_kind(self.manifest_path)     # stat only: reading a FIFO would block
        if kind is not None:
            return None, f"unreadable: it is {kind}, not a file"
        try:
            text = self.manifest_path.read_bytes()
        except FileNotFoundError:
            return None, None
        except OSError as exc:
            return None, f"unreadable: {exc.strerror or exc}"
        return manifest_problem(text)

    def _plan_problem(self, manifest: dict) -> str | None:
        if not self.plan_path.is_file():
            return "missing"
        try:
            digest = sha256_file(self.plan_path)
        except OSError as exc:
            return f"unreadable: {exc.strerror or exc}"
        if digest != manifest["plan_sha256"]:
            return "corrupted or replaced: its sha256 differs from the plan_sha256 recorded in manifest.json"
        return None

    def plan(self) -> pd.DataFrame:
        """The verified plan (StoreError, one line, when there is no campaign here or the plan is corrupt)."""
        import pandas as pd

        return pd.read_parquet(self._verified_plan_path())

    def _verified_plan_path(self) -> Path:
        """plan.parquet, checked against the manifest's record (StoreError, one line, as :meth:`plan`)."""
        manifest = self.manifest()
        if manifest is None:
            if self.cases_dir.is_dir():
                raise StoreError(f"{self.root}: no manifest.json: its case files cannot be attributed to a "
                                 f"configuration; {FRESH_HINT}")
            raise StoreError(f"{self.root}: no manifest.json: not a campaign directory (run `campaign submit` first)")
        problem = self._plan_problem(manifest)
        if problem is not None:
            raise StoreError(f"{self.plan_path}: {problem}; the next `campaign submit` of this configuration "
                             "writes it again")
        return self.plan_path

    def _has_case_files(self) -> bool:
        return self.cases_dir.is_dir() and any(not entry.name.startswith(".tmp-") for entry in os.scandir(self.cases_dir))

    def check(self, manifest: dict, plan: pd.DataFrame, fresh: bool = False) -> None:
        """Refuse (StoreError, one line) a store that :meth:`prepare` would refuse; changes nothing.

        Refused without ``fresh``: a corrupt manifest, another configuration hash, case files without a
        manifest (they cannot be attributed to a configuration: never reused), or a plan that places a
        case of the same configuration differently."""
        import pandas as pd

        if fresh:
            return
        existing, problem = self._manifest_state()
        if problem is not None:
            raise StoreError(f"{self.manifest_path}: {problem}; {FRESH_HINT}, or choose another output directory")
        if existing is None:
            if self._has_case_files():
                raise StoreError(f"{self.root}: has case files but no manifest.json, so they cannot be attributed to "
                                 f"a configuration and are never reused; {FRESH_HINT}, or choose another output directory")
            return
        if existing["config_hash"] != manifest["config_hash"]:
            raise StoreError(f"{self.root}: holds a campaign with another configuration: {describe_change(existing, manifest)}; "
                             f"{FRESH_HINT}, or choose another output directory (--output)")
        if self._plan_problem(existing) is None:
            difference = _first_difference(pd.read_parquet(self.plan_path), plan)
            if difference is not None:
                raise StoreError(f"{self.plan_path}: same configuration hash but {difference}; {FRESH_HINT}")

    def prepare(self, manifest: dict, plan: pd.DataFrame, fresh: bool = False) -> list[str]:
        """Create the store, or check that it holds the same campaign and bring it up to date; call it while
        holding :meth:`lock`. Returns one line per action taken (for the user).

        ``fresh``: move an existing store aside to ``DIR.previous-<UTC time>`` first (never deletes).
        Same configuration hash and a plan of another size (another case count): accepted when every
        case in both plans is planned identically; the new plan is recorded and case files of cases
        outside it are kept but not counted. A missing or corrupt plan of the same configuration is
        written again (the bad one goes to ``rejected/``). Bad case files are moved to ``rejected/``.
        """
        import pandas as pd

        notes = []
        if fresh and self.root.exists():
            notes.append(f"moved the previous store aside to {self.move_aside()}")
        self._hold_directory()                 # before the first write (a removed DIR.lock lets no one in)
        self.check(manifest, plan)
        existing = self.manifest()
        plan = plan.reset_index(drop=True)
        if existing is None:
            self.cases_dir.mkdir(parents=True, exist_ok=True)
            self._record_plan(manifest, plan)
            return notes
        self.cases_dir.mkdir(parents=True, exist_ok=True)
        recorded = {"cases_per_class": manifest["cases_per_class"], "estimators": manifest.get("estimators")}
        problem = self._plan_problem(existing)
        if problem is not None:
            if self.plan_path.exists():
                self._reject(self.plan_path, problem)
            notes.append(f"{self.plan_path}: {problem}; written again from the configuration")
            self._record_plan({**existing, **recorded}, plan)
        elif set(pd.read_parquet(self.plan_path, columns=["case_id"])["case_id"]) != set(plan["case_id"]):
            old_size = existing.get("plan_cases", "?")   # check() found the cases in both planned identically
            self._record_plan({**existing, **recorded}, plan)
            notes.append(f"{self.root}: same configuration, plan of {len(plan)} cases recorded (was {old_size}); "
                         "the cases in both are unchanged and reused")
        elif existing.get("estimators") != manifest.get("estimators"):   # a manifest from before they were recorded
            self._record_plan({**existing, "estimators": manifest.get("estimators")}, plan)
            notes.append(f"{self.root}: manifest.json now records the estimator list its case files must match")
        rejected = self.reject_bad_files()
        if rejected:
            notes.append(f"{self.root}: moved {rejected} bad or superseded case files to {self.rejected_dir} "
                         "(see rejected.log); their cases are computed again")
        return notes

    def _record_plan(self, manifest: dict, plan: pd.DataFrame) -> None:
        """Write the plan, then the manifest recording its digest (the manifest is the commit point)."""
        digest = atomic_write_table(self.plan_path, pa.Table.from_pandas(plan, preserve_index=False))
        sealed = seal_manifest({**manifest, "plan_sha256": digest, "plan_cases": len(plan)})
        atomic_write_bytes(self.manifest_path, json.dumps(sealed, indent=2, sort_keys=True).encode())
        fsync_directory(self.root)

    def move_aside(self) -> Path:
        """Rename the whole store directory to ``DIR.previous-<UTC time>`` (a new name, never overwritten)."""
        root = Path(os.path.abspath(self.root))             # "." names the working directory
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        target = root.with_name(f"{root.name}.previous-{stamp}")
        counter = 1
        while target.exists():
            counter += 1
            target = root.with_name(f"{root.name}.previous-{stamp}-{counter}")
        os.rename(root, target)
        fsync_directory(root.parent)
        return target

    def _reject(self, path: Path, reason: str) -> Path:
        self.rejected_dir.mkdir(exist_ok=True)
        target = self.rejected_dir / path.name
        while target.exists():
            target = self.rejected_dir / f"{path.name}.{time.time_ns()}"
        os.rename(path, target)
        stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        with open(self.rejected_dir / "rejected.log", "a") as log:
            log.write(f"{stamp} {path.relative_to(self.root)} -> {target.relative_to(self.root)}: {reason}\n")
        return target

    def reject_bad_files(self) -> int:
        """Move bad and superseded case files to ``rejected/`` (one log line each); return how many."""
        scan = scan_case_files(self.cases_dir, expected=self.identity())   # everything hashed afresh before a run
        for path, reason in [*scan.bad, *scan.superseded]:
            self._reject(path, reason)
        if scan.bad or scan.superseded:
            fsync_directory(self.cases_dir)
        return len(scan.bad) + len(scan.superseded)

    # --- reading -------------------------------------------------------------------------------
    def scan(self) -> CaseScan:
        """Every case file verified (files this object verified before and that are unchanged: by stat)."""
        return scan_case_files(self.cases_dir, self._verified, self.identity())

    def finished_case_ids(self) -> dict[int, str]:
        """case_id -> 'ok' or 'failed' for every verified case file (works during a run and after a crash)."""
        return {case_id: case.state for case_id, case in self.scan().cases.items()}

    def planned_case_ids(self) -> set[int]:
        """The case ids of the verified plan."""
        plan = pq.ParquetFile(self._verified_plan_path()).read(columns=["case_id"])   # no pandas, no dataset
        return {int(case_id) for case_id in plan.column("case_id").to_pylist()}

    def status(self) -> CaseStatus:
        planned = self.planned_case_ids()
        scan = self.scan()
        counted = [case for case_id, case in scan.cases.items() if case_id in planned]
        failed = sum(1 for case in counted if case.state == "failed")
        return CaseStatus(planned=len(planned), done=len(counted) - failed, failed=failed, bad=len(scan.bad),
                          outside_plan=len(scan.cases) - len(counted),
                          foreign=sum(1 for _, reason in scan.bad if reason.startswith(FOREIGN)),
                          rejected=len(self.rejected_files()))

    def rejected_files(self) -> list[Path]:
        """The files moved to ``rejected/`` (``rejected.log`` says when and why)."""
        if not self.rejected_dir.is_dir():
            return []
        return sorted(path for path in self.rejected_dir.iterdir() if path.name != "rejected.log")

    def read_case_table(self, case_ids: Iterable[int] | None = None, scan: CaseScan | None = None,
                        planned: set[int] | None = None) -> pa.Table:
        """The rows of the verified case files of the planned cases (of ``case_ids`` if given), by case_id,
        as one table of :data:`~campaign.store.result_schema.CASE_FILE_SCHEMA` (``scan`` and ``planned``:
        already read by the caller). Raises ResultSchemaError for a file that does not fit the schema."""
        scan = self.scan() if scan is None else scan
        wanted = (self.planned_case_ids() if planned is None else planned) & set(scan.cases)
        if case_ids is not None:
            wanted &= {int(case_id) for case_id in case_ids}
        tables = [read_case_table(scan.cases[case_id].path) for case_id in sorted(wanted)]
        return pa.concat_tables(tables) if tables else CASE_FILE_SCHEMA.empty_table()

    # --- compaction ----------------------------------------------------------------------------
    def compact(self) -> pd.DataFrame:
        """Write results.parquet (deterministic columns, sorted by case_id), timings.parquet and their record
        results.json, from the verified case files of the planned cases."""
        import pandas as pd

        scan, planned = self.scan(), self.planned_case_ids()
        rows = self.read_case_table(scan=scan, planned=planned)
        if rows.num_rows == 0:
            return pd.DataFrame()
        rows = rows.sort_by("case_id")           # a stable sort: estimators stay in [[estimators]] order
        results = rows.select(RESULTS_SCHEMA.names)
        record = {"case_files_sha256": scan.fingerprint(planned),
                  "cases": len(pc.unique(results["case_id"])),
                  "results_sha256": atomic_write_table(self.results_path, results),
                  "timings_sha256": atomic_write_table(self.timings_path, rows.select(TIMINGS_SCHEMA.names))}
        atomic_write_bytes(self.results_record_path, json.dumps(record, indent=2, sort_keys=True).encode())
        return results.to_pandas()

    def results_problem(self, scan: CaseScan | None = None, planned: set[int] | None = None) -> str | None:
        """Why results.parquet cannot be trusted (None: it matches the verified case files of the plan)."""
        if not self.results_path.exists():
            return "missing"
        try:
            record = json.loads(self.results_record_path.read_text())
            recorded = record["results_sha256"], record["case_files_sha256"]
        except (OSError, ValueError, KeyError, TypeError):
            return "no valid record in results.json, so it cannot be verified"
        if sha256_file(self.results_path) != recorded[0]:
            return "corrupted: its sha256 differs from the one recorded in results.json"
        scan = self.scan() if scan is None else scan
        if scan.fingerprint(self.planned_case_ids() if planned is None else planned) != recorded[1]:
            return "out of date: compacted from other case files than the verified ones now in cases/"
        return None

    def results(self) -> pd.DataFrame:
        """The compacted results if they match the verified case files, else the rows read from those files."""
        import pandas as pd

        scan, planned = self.scan(), self.planned_case_ids()
        if self.results_problem(scan, planned) is None:
            return pd.read_parquet(self.results_path)
        rows = self.read_case_table(scan=scan, planned=planned)
        return rows.select(RESULTS_SCHEMA.names).to_pandas() if rows.num_rows else pd.DataFrame()
