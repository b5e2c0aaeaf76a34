"""The campaign store: one directory per campaign, durable batches of case results, an index, compacted parts.

Layout::

    OUT/manifest.json          config (as resolved), its hash, input file digests, package versions, the
                               plan's sha256 and case count, and its own sha256 (``manifest_sha256``)
    OUT/plan.parquet           every planned case (ids, class, terrain, trajectory, placement, seeds)
    OUT/cases/<xx>/batch-<first case id>-<cases>.<bytes>.<sha256>.parquet
                               the rows of finished cases, one per case and estimator (``estimator`` column,
                               in [[estimators]] order), written by the worker task that computed them; the
                               name records size and sha256, the metadata the campaign, case ids, states
                               ('failed': the simulation failed after its retries) and write time
                               (:mod:`campaign.store.case_files`); stores from before batches hold
                               ``cases/case-<id>.<ok|failed>.<bytes>.<sha256>.parquet``, read as batches of one
    OUT/index/segment-<uuid>.<bytes>.<sha256>.parquet
                               which verified file holds each case (:mod:`campaign.store.case_index`): a scan
                               hashes only files the index lacks
    OUT/results.parquet/part-<n>.parquet
                               the rows of the planned cases, each part sorted by case_id (same seed -> same
                               bits); :meth:`CampaignStore.results` concatenates and sorts them
    OUT/timings.parquet/part-<n>.parquet
                               per-case stage timings and worker names (vary from run to run)
    OUT/results.json           the parts, their size, time and sha256, and what each was compacted from:
                               they are trusted only while both match; compaction keeps the parts that
                               still match and compacts only the other cases
    OUT/rejected/              bad files moved out of the way (never deleted), ``rejected.log`` says why
    OUT.lock                   beside the store: one writer at a time (:mod:`campaign.store.lock`)

Integrity: every file is checked before it is trusted. A case file that is truncated, corrupted, has no
record, does not fit the result schema or is *foreign* (the identity recorded inside it - configuration
hash, case ids, seed, estimators, schema version: :mod:`campaign.store.case_identity` - is not this
store's) is not counted by ``status``, never read by ``table`` or compaction, and is moved to
``rejected/`` and recomputed by the next ``submit``. Case files of cases that are not in the plan are
kept but not counted. A corrupt ``manifest.json`` or ``plan.parquet`` is a one-line error; ``campaign
verify DIR`` re-hashes every file and lists every bad one.
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from campaign.configuration.differences import describe_change
from campaign.configuration.paths import special_kind
from campaign.store.case_files import (
    TEMPORARY_PREFIX,
    atomic_write_bytes,
    atomic_write_table,
    fsync_directory,
    sha256_bytes,
    sha256_file,
    table_bytes,
)
from campaign.store.case_identity import FOREIGN, StoreIdentity
from campaign.store.case_index import CaseIndex, CaseScan, Entries, fingerprint, scan_cases, verify_case_file
from campaign.store.errors import StoreError
from campaign.store.lock import StoreLock, lock_path_for
from campaign.store.result_schema import CASE_FILE_SCHEMA, RESULTS_SCHEMA, TIMINGS_SCHEMA

if TYPE_CHECKING:
    import pandas as pd

# pandas is imported by the methods that make a DataFrame, when they run: `campaign status` and `verify` read a
# store with pyarrow alone (pandas is half of their start-up time).

RESULTS_FORMAT = 2
"""results.json of a store whose results.parquet and timings.parquet are directories of parts."""

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
    failed_rows: dict[str, int] = field(default_factory=dict)   # estimator -> its rows with status 'failed'

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


def _same_case_ids(first, second) -> bool:
    import numpy as np

    return bool(np.array_equal(np.sort(np.asarray(first, dtype=np.int64)), np.sort(np.asarray(second, dtype=np.int64))))


def _first_difference(old: pd.DataFrame, new: pd.DataFrame) -> str | None:
    """The first case planned differently in two plans (over the case_ids in both), or None."""
    import numpy as np

    if set(old.columns) != set(new.columns):
        return f"the plan columns differ ({', '.join(sorted(set(old.columns) ^ set(new.columns)))})"
    if list(old.columns) == list(new.columns) and old.reset_index(drop=True).equals(new.reset_index(drop=True)):
        return None                                  # the same plan (a resume): no case by case comparison
    old = old.set_index(old["case_id"].astype(np.int64))
    new = new.set_index(new["case_id"].astype(np.int64))
    common = old.index.intersection(new.index).sort_values()
    left, right = old.loc[common, sorted(old.columns)], new.loc[common, sorted(old.columns)]
    for column in left.columns:
        a, b = left[column].to_numpy(), right[column].to_numpy()
        if a.dtype.kind == "f" and b.dtype.kind == "f":
            same = (a == b) | (np.isnan(a) & np.isnan(b))
        else:
            same = np.asarray(a == b, dtype=bool)
        if not same.all():
            position = int(np.flatnonzero(~same)[0])
            return (f"case {int(common[position])} has {column} = {a[position]!r} in the stored plan and "
                    f"{b[position]!r} in the new one")
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
        self.index_dir = self.root / "index"
        self._index = CaseIndex(self.index_dir)   # the index segments this object has read
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
        elif not _same_case_ids(self._plan_case_ids(), plan["case_id"].to_numpy()):
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

    def has_every_case(self, manifest: dict, plan: pd.DataFrame) -> bool:
        """Whether :meth:`prepare` would leave no case of ``plan`` to run; changes nothing.

        True only when the store records this configuration (hash, estimator list) with a verified plan of
        the same case ids, ``cases/`` holds no bad or superseded file (``prepare`` would reject it and its case
        be computed again) and every planned case is counted. A run may then skip its cluster.
        """
        existing, problem = self._manifest_state()
        if (problem is not None or existing is None or existing["config_hash"] != manifest["config_hash"]
                or existing.get("estimators") != manifest.get("estimators") or self._plan_problem(existing) is not None):
            return False
        planned = self._plan_case_ids()
        if not _same_case_ids(planned, plan["case_id"].to_numpy()):
            return False
        scan = self.scan(record=False)
        return not scan.bad and not scan.superseded and bool(scan.in_plan(planned).sum() == len(planned))

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
        """Move bad and superseded case files to ``rejected/`` (one log line each), and merge the index;
        return how many files moved. Call it holding the lock (``prepare`` does)."""
        scan = self.scan(merge=True)
        for path, reason in [*scan.bad, *scan.superseded]:
            self._reject(path, reason)
        if scan.bad or scan.superseded:
            fsync_directory(self.cases_dir)
        return len(scan.bad) + len(scan.superseded)

    # --- reading -------------------------------------------------------------------------------
    def scan(self, merge: bool = False, record: bool = True) -> CaseScan:
        """The counted file of each finished case (files the index has unchanged are trusted by name, size
        and time; others are verified and, if ``record``, indexed: :mod:`~campaign.store.case_index`).
        ``merge``: the caller holds the lock, the index's segments may be merged."""
        return scan_cases(self.cases_dir, self._index, self.identity(), merge=merge, record=record)

    def finished_case_ids(self) -> dict[int, str]:
        """case_id -> 'ok' or 'failed' for every counted case (works during a run and after a crash)."""
        return self.scan().states()

    def planned_case_ids(self) -> set[int]:
        """The case ids of the verified plan."""
        return set(self.planned_case_array().tolist())

    def planned_case_array(self) -> np.ndarray:
        """The case ids of the verified plan, sorted."""
        self._verified_plan_path()
        return self._plan_case_ids()

    def _plan_case_ids(self) -> np.ndarray:
        """The case ids of plan.parquet as it is (the caller has checked it), sorted."""
        plan = pq.ParquetFile(self.plan_path).read(columns=["case_id"])   # no pandas, no dataset
        return np.sort(plan.column("case_id").to_numpy())

    def status(self) -> CaseStatus:
        planned = self.planned_case_array()
        scan = self.scan()
        inside = scan.in_plan(planned)
        counted = int(np.count_nonzero(inside))
        failed = int(np.count_nonzero(scan.failed_case[inside]))
        failed_rows = scan.failed_rows(inside)
        identity = self.identity()
        estimators = list(identity.estimators or ()) if identity is not None else []
        order = estimators + sorted(set(failed_rows) - set(estimators))
        return CaseStatus(planned=len(planned), done=counted - failed, failed=failed, bad=len(scan.bad),
                          outside_plan=int(len(inside) - np.count_nonzero(inside)),
                          foreign=sum(1 for _, reason in scan.bad if reason.startswith(FOREIGN)),
                          rejected=len(self.rejected_files()),
                          failed_rows={name: failed_rows[name] for name in order if name in failed_rows})

    def rejected_files(self) -> list[Path]:
        """The files moved to ``rejected/`` (``rejected.log`` says when and why)."""
        if not self.rejected_dir.is_dir():
            return []
        return sorted(path for path in self.rejected_dir.iterdir() if path.name != "rejected.log")

    def read_case_table(self, case_ids: Iterable[int] | None = None, scan: CaseScan | None = None,
                        planned: np.ndarray | set[int] | None = None) -> pa.Table:
        """The rows of the counted cases of the plan (of ``case_ids`` if given), by case_id, as one table of
        :data:`~campaign.store.result_schema.CASE_FILE_SCHEMA` (``scan`` and ``planned``: already read by
        the caller). Each file read is verified again (its sha256); one that fails is moved to
        ``rejected/`` and its cases are left out."""
        scan = self.scan() if scan is None else scan
        planned = self.planned_case_array() if planned is None else planned
        wanted = scan.in_plan(np.fromiter(planned, np.int64) if not isinstance(planned, np.ndarray) else planned)
        if case_ids is not None:
            wanted &= np.isin(scan.case_ids, np.fromiter((int(c) for c in case_ids), np.int64))
        return self._read_rows(scan.counted.mask(wanted))

    def _read_rows(self, counted: Entries) -> pa.Table:
        """The rows of the cases of ``counted`` (index rows), sorted by case_id (estimators in order)."""
        if counted.num_rows == 0:
            return CASE_FILE_SCHEMA.empty_table()
        order = np.lexsort((counted.first_row, counted.codes))
        codes, first, count = counted.codes[order], counted.first_row[order], counted.row_count[order]
        starts = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]])
        ends = np.r_[starts[1:], len(codes)]
        identity = self.identity()

        def read(bounds: tuple[int, int]) -> tuple[pa.Table | None, Path, str | None]:
            start, end = bounds
            relative = counted.names[int(codes[start])]
            path = self.cases_dir / relative
            try:
                data = path.read_bytes()
            except OSError as exc:
                raise StoreError(f"{path}: unreadable: {exc.strerror or exc}; `campaign verify {self.root}` "
                                 "checks the store") from None
            whole: list[pa.Table] = []
            _, problem = verify_case_file(path, relative, identity, data, keep_rows=whole)
            if problem is not None:
                return None, path, problem
            table = whole[0].replace_schema_metadata(None)
            take = np.concatenate([np.arange(f, f + c) for f, c in zip(first[start:end], count[start:end])])
            whole_file = len(take) == table.num_rows and bool(np.array_equal(take, np.arange(table.num_rows)))
            return (table if whole_file else table.take(pa.array(take))), path, None

        groups = sorted(zip(starts.tolist(), ends.tolist()), key=lambda bounds: int(counted.case_id[order][bounds[0]]))
        tables = []
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:    # Parquet decoding releases the GIL
            for table, path, problem in pool.map(read, groups):
                if table is None:
                    self._reject(path, f"{problem} (found when its rows were read)")
                else:
                    tables.append(table)
        if not tables:
            return CASE_FILE_SCHEMA.empty_table()
        rows = pa.concat_tables(tables)
        case_ids = rows.column("case_id").to_numpy()
        if len(case_ids) > 1 and bool(np.any(case_ids[1:] < case_ids[:-1])):
            rows = rows.take(pc.sort_indices(rows, sort_keys=[("case_id", "ascending")]))   # stable: estimators in order
        return rows

    # --- compaction ----------------------------------------------------------------------------
    def _record(self) -> dict | None:
        try:
            record = json.loads(self.results_record_path.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(record, dict) or record.get("format") != RESULTS_FORMAT or not isinstance(record.get("parts"), list):
            return None
        return record

    def compact(self) -> int:
        """Bring results.parquet and timings.parquet up to date with the counted cases of the plan, compacting
        only what is new: parts whose cases still count from the same files are kept, the other cases are
        read from their files into one new part (sorted by case_id); results.json records the parts, their
        sha256 and what they were compacted from. Returns how many cases were read from case files."""
        scan, planned = self.scan(), self.planned_case_array()
        counted = scan.counted.mask(scan.in_plan(planned))
        record = self._record()
        kept, covered = [], np.zeros(counted.num_rows, dtype=bool)
        for part in (record or {}).get("parts", []):
            batches = set(part.get("batches", ()))
            of_part = np.array([name in batches for name in counted.names], dtype=bool)
            mine = (of_part[counted.codes] if counted.num_rows else covered) & ~covered
            if fingerprint(counted.mask(mine)) == part.get("cases_sha256") and self._part_files_intact(part):
                kept.append(part)
                covered |= mine
        new = counted.mask(~covered)
        parts, compacted = list(kept), covered.copy()
        if new.num_rows:
            rows = self._read_rows(new)
            read = np.isin(new.case_id, rows.column("case_id").to_numpy())   # a batch rejected while read: out
            compacted[np.flatnonzero(~covered)[read]] = True
            if rows.num_rows:
                parts.append(self._write_part(rows, new.mask(read), [p["name"] for p in kept]))
        self._write_parts_record(parts, counted.mask(compacted))
        return new.num_rows

    def _part_files_intact(self, part: dict) -> bool:
        """The part's files exist with the sha256 recorded (hashing is cheap next to reading rows)."""
        try:
            return (sha256_file(self.results_path / part["name"]) == part["results_sha256"]
                    and sha256_file(self.timings_path / part["name"]) == part["timings_sha256"])
        except (OSError, KeyError, TypeError):
            return False

    def _write_part(self, rows: pa.Table, counted: Entries, taken: list[str]) -> dict:
        """Write the rows of a new part (in both results.parquet/ and timings.parquet/) under temporary
        names; :meth:`_write_parts_record` renames them once the record lists them."""
        number = 1 + max((int(name.split("-")[1].split(".")[0]) for name in taken), default=0)
        number = max(number, 1 + max((int(p.name.split("-")[1].split(".")[0]) for directory in
                                      (self.results_path, self.timings_path) if directory.is_dir()
                                      for p in directory.glob("part-*.parquet")), default=0))
        name = f"part-{number:06d}.parquet"
        entry = {"name": name, "cases": counted.num_rows, "cases_sha256": fingerprint(counted),
                 "batches": sorted(counted.names[code] for code in counted.used_codes().tolist())}
        for directory, schema, key in ((self.results_path, RESULTS_SCHEMA, "results"),
                                       (self.timings_path, TIMINGS_SCHEMA, "timings")):
            if directory.is_file():                     # a results.parquet of a store compacted before parts
                directory.unlink()
            directory.mkdir(exist_ok=True)
            data = table_bytes(rows.select(schema.names))
            atomic_write_bytes(directory / f"{TEMPORARY_PREFIX}{name}", data)
            entry[f"{key}_sha256"], entry[f"{key}_bytes"] = sha256_bytes(data), len(data)
            entry[f"{key}_mtime_ns"] = (directory / f"{TEMPORARY_PREFIX}{name}").stat().st_mtime_ns   # kept by rename
        return entry

    def _write_parts_record(self, parts: list[dict], counted: Entries) -> None:
        """results.json (the commit point), then the new parts under their names, then the parts no longer
        recorded removed."""
        for directory in (self.results_path, self.timings_path):
            if directory.is_file():                     # of a store compacted before parts
                directory.unlink()
        record = {"format": RESULTS_FORMAT, "case_files_sha256": fingerprint(counted),
                  "cases": sum(part["cases"] for part in parts), "parts": parts}
        atomic_write_bytes(self.results_record_path, json.dumps(record, indent=1, sort_keys=True).encode())
        names = {part["name"] for part in parts}
        for directory in (self.results_path, self.timings_path):
            if not directory.is_dir():
                continue
            for path in directory.iterdir():
                final = path.name.removeprefix(TEMPORARY_PREFIX)
                if path.name.startswith(TEMPORARY_PREFIX) and final in names:
                    os.replace(path, directory / final)
                elif final not in names or path.name.startswith(TEMPORARY_PREFIX):
                    path.unlink(missing_ok=True)
            fsync_directory(directory)

    def results_problem(self, scan: CaseScan | None = None, planned: np.ndarray | None = None,
                        deep: bool = False) -> str | None:
        """Why results.parquet cannot be trusted (None: its parts match their records and the counted cases
        of the plan). A part matches its record by size and modification time (a part is never rewritten in
        place), or with ``deep`` (``campaign verify``) by its sha256."""
        if not self.results_path.exists():
            return "missing"
        if self.results_path.is_file():                  # compacted before parts: one file
            return self._single_file_problem(scan, planned)
        record = self._record()
        if record is None:
            return "no valid record in results.json, so it cannot be verified"
        for part in record["parts"]:
            for directory, key in ((self.results_path, "results"), (self.timings_path, "timings")):
                try:
                    stat = (directory / part["name"]).stat()
                    same = (stat.st_size, stat.st_mtime_ns) == (part.get(f"{key}_bytes"), part.get(f"{key}_mtime_ns"))
                    if deep or not same:
                        same = sha256_file(directory / part["name"]) == part[f"{key}_sha256"]
                except OSError:
                    return f"part {part['name']} of {directory.name} is missing or unreadable"
                if not same:
                    return f"corrupted: {directory.name}/{part['name']} differs from the sha256 recorded in results.json"
        scan = self.scan() if scan is None else scan
        planned = self.planned_case_array() if planned is None else planned
        if scan.fingerprint(planned) != record["case_files_sha256"]:
            return "out of date: compacted from other case files than the verified ones now in cases/"
        return None

    def _single_file_problem(self, scan: CaseScan | None, planned: np.ndarray | None) -> str | None:
        """Why the single-file results.parquet of a store compacted before parts cannot be trusted (its
        results.json records its sha256 and the sha256 of the sorted names of the case files)."""
        try:
            record = json.loads(self.results_record_path.read_text())
            recorded = record["results_sha256"], record["case_files_sha256"]
        except (OSError, ValueError, KeyError, TypeError):
            return "no valid record in results.json, so it cannot be verified"
        if sha256_file(self.results_path) != recorded[0]:
            return "corrupted: its sha256 differs from the one recorded in results.json"
        scan = self.scan() if scan is None else scan
        planned = self.planned_case_array() if planned is None else planned
        names = sorted(Path(name).name for name in scan.counted.mask(scan.in_plan(planned)).file_names().tolist())
        if sha256_bytes("\n".join(names).encode()) != recorded[1]:
            return "out of date: compacted from other case files than the verified ones now in cases/"
        return None

    def results(self, columns: list[str] | None = None) -> pd.DataFrame:
        """The compacted results (sorted by case_id, estimators in order) if they match the counted cases, else
        the rows read from the case files; ``columns``: only those."""
        import pandas as pd

        scan, planned = self.scan(), self.planned_case_array()
        if self.results_problem(scan, planned) is None and self.results_path.is_file():
            return pd.read_parquet(self.results_path, columns=columns)      # a store compacted before parts
        if self.results_problem(scan, planned) is None:
            record = self._record() or {"parts": []}
            tables = [pq.read_table(self.results_path / part["name"], columns=columns) for part in record["parts"]]
            if not tables:
                return pd.DataFrame()
            rows = pa.concat_tables(tables).replace_schema_metadata(None)
        else:
            rows = self.read_case_table(scan=scan, planned=planned)
            if rows.num_rows == 0:
                return pd.DataFrame()
            rows = rows.select(columns or RESULTS_SCHEMA.names)
        if rows.num_rows == 0:
            return pd.DataFrame()
        if "case_id" in rows.column_names:
            rows = rows.take(pc.sort_indices(rows, sort_keys=[("case_id", "ascending")]))
        return rows.to_pandas()
