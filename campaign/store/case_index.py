"""The store's case index: which verified file holds each finished case, so a scan hashes only new files.

``cases/`` holds batch files (``<sha256[:2]>/batch-<first case id>-<cases>.<bytes>.<sha256>.parquet``,
:func:`~campaign.store.case_files.write_case_batch`; 256 shard directories, so no directory holds more
than ~4 000 files even at 10^6 one-case batches) and, in stores written before batches, one-case files
``case-<id>.<ok|failed>.<bytes>.<sha256>.parquet`` at its top (read as batches of one case).

A file is *verified* once: its size and sha256 against its name, its schema against the declared one, its
identity record against the store's, its rows against its record (:func:`verify_case_file`). What that
found (per case: its file, rows, state and the estimators whose row failed) is appended to the index,
``OUT/index/segment-<uuid>.<bytes>.<sha256>.parquet`` (:data:`INDEX_SCHEMA`; each segment records the
store identity it was verified against, and its own size and sha256 in its name). A later scan lists
``cases/`` and trusts a file without reading it when the index has it with the same name, size and
modification time (a file is never rewritten in place: a new write has a new name); a file the index
lacks, or whose size or time changed, is verified again. A segment that is corrupt or of another
identity is ignored (its files are verified again) and removed by the next writer. ``campaign verify``
re-hashes every file regardless of the index.

Of two verified files holding a case (a case computed twice: a worker killed after its write, a task
retried), the later write counts (``written_ns`` of its record; the modification time for one-case
files) and the other is *superseded* for that case; a file none of whose cases count is superseded as a
whole and moved to ``rejected/`` by the next ``submit``.
"""
from __future__ import annotations

import json
import os
import re
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from campaign.store.case_files import (
    BATCH_FILE,
    CASE_FILE,
    SHARD,
    TEMPORARY_PREFIX,
    UNRECORDED_CASE_FILE,
    atomic_write_bytes,
    parquet_file_of_bytes,
    sha256_bytes,
    table_bytes,
)
from campaign.store.case_identity import (
    FOREIGN,
    StoreIdentity,
    batch_rows_problem,
    campaign_problem,
    identity_problem,
    read_batch_identity,
    read_identity,
    rows_problem,
)
from campaign.store.result_schema import CASE_FILE_SCHEMA, RESULT_SCHEMA_VERSION, schema_problem

INDEX_SCHEMA = pa.schema([
    pa.field("batch", pa.string()),          # the file, relative to cases/
    pa.field("size", pa.int64()),            # its size (bytes) when verified
    pa.field("mtime_ns", pa.int64()),        # its modification time when verified
    pa.field("written_ns", pa.int64()),      # when it was written (its record; one-case files: mtime)
    pa.field("case_id", pa.int64()),
    pa.field("failed_case", pa.bool_()),     # the case's simulation failed (after its retries)
    pa.field("first_row", pa.int64()),       # the case's rows in the file: first_row .. first_row + row_count
    pa.field("row_count", pa.int64()),
    pa.field("failed_estimators", pa.list_(pa.string())),   # estimators whose row has status 'failed'
])
"""One row per (file, case) of the index."""
INDEX_KEY = b"moc2dimes.index_identity"
SEGMENT_FILE = re.compile(r"^segment-([0-9a-f]{32})\.(\d+)\.([0-9a-f]{64})\.parquet$")
MERGE_SEGMENTS = 16
"""A writer holding the store's lock merges the index's segments when there are more than this."""
LISTING_SCHEMA = pa.schema([pa.field("batch", pa.string()), pa.field("size", pa.int64()),
                            pa.field("mtime_ns", pa.int64())])


def verify_case_file(path: Path, relative: str, expected: StoreIdentity | None,
                     data: bytes | None = None, keep_rows: list | None = None) -> tuple[pa.Table | None, str | None]:
    """Verify one file of ``cases/`` (a batch, or a one-case file of an older store): (its index rows, None)
    or (None, what is wrong). ``relative``: its path relative to ``cases/``; ``data``: its bytes if read;
    ``keep_rows``: a list that receives every row of the file (read once, for compaction)."""
    name = relative.rsplit("/", 1)[-1]
    batch = BATCH_FILE.match(name) if "/" in relative else None
    legacy = CASE_FILE.match(name) if "/" not in relative else None
    match = batch or legacy
    if match is None:
        return None, "not a case file"
    recorded_size, recorded_digest = int(match.group(3)), match.group(4)
    try:
        stat = path.stat()
        if stat.st_size != recorded_size:
            kind = "truncated" if stat.st_size < recorded_size else "too long"
            return None, f"{kind}: {stat.st_size} bytes, {recorded_size} recorded at write time"
        data = path.read_bytes() if data is None else data
    except OSError as exc:
        return None, f"unreadable: {exc.strerror or exc}"
    digest = sha256_bytes(data)
    if digest != recorded_digest:
        return None, (f"corrupted: sha256 {digest[:16]}... differs from the {recorded_digest[:16]}... recorded "
                      "at write time")
    try:
        parquet = parquet_file_of_bytes(data)
        schema = parquet.schema_arrow
        problem = schema_problem(schema, CASE_FILE_SCHEMA)
        if problem is not None:
            return None, problem
        if keep_rows is None:
            rows = parquet.read(columns=["case_id", "campaign_seed", "estimator", "status"], use_threads=False)
        else:
            rows = parquet.read(use_threads=False)
            keep_rows.append(rows)
        if batch:
            record, problem = read_batch_identity(schema.metadata)
            if record is None:
                return None, problem
            problem = campaign_problem(record, expected)
            if problem is None and (record["case_ids"][0] != int(batch.group(1))
                                    or len(record["case_ids"]) != int(batch.group(2))):
                problem = (f"{FOREIGN}: its name says {batch.group(2)} cases from case {batch.group(1)}, its "
                           f"identity record {len(record['case_ids'])} from case {record['case_ids'][0]}")
            problem = problem or batch_rows_problem(rows, record)
            if problem is not None:
                return None, problem
            case_ids, failed = record["case_ids"], [state == "failed" for state in record["states"]]
            written_ns = int(record["written_ns"])
        else:
            assert legacy is not None                    # a name that is neither was refused above
            record, problem = read_identity(schema.metadata)
            if record is None:
                return None, problem
            case_id = int(legacy.group(1))
            problem = identity_problem(record, case_id, expected) or rows_problem(rows, record)
            if problem is not None:
                return None, problem
            case_ids, failed, written_ns = [case_id], [legacy.group(2) == "failed"], stat.st_mtime_ns
    except (OSError, pa.ArrowException) as exc:
        return None, f"unreadable as Parquet: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    estimators = list(record["estimators"])
    per_case = len(estimators)
    status = np.asarray(rows.column("status").to_pylist(), dtype=object).reshape(len(case_ids), per_case)
    failed_estimators = [[name for name, state in zip(estimators, states) if state == "failed"] for states in status]
    count = len(case_ids)
    table = pa.table({"batch": [relative] * count, "size": [stat.st_size] * count,
                      "mtime_ns": [stat.st_mtime_ns] * count, "written_ns": [written_ns] * count,
                      "case_id": case_ids, "failed_case": failed,
                      "first_row": [index * per_case for index in range(count)], "row_count": [per_case] * count,
                      "failed_estimators": failed_estimators}, schema=INDEX_SCHEMA)
    return table, None


@dataclass
class Listing:
    """What ``cases/`` holds, by name and stat only."""
    files: list[tuple[str, int, int]] = field(default_factory=list)     # (relative path, size, mtime_ns)
    bad: list[tuple[Path, str]] = field(default_factory=list)
    temporary: list[Path] = field(default_factory=list)


NOT_A_CASE_FILE = ("not a case file (allowed: <2 hex digits>/batch-<first case id>-<cases>.<bytes>.<sha256>.parquet, "
                   "or case-<id>.<ok|failed>.<bytes>.<sha256>.parquet of an older store)")


def list_case_files(cases_dir: Path) -> Listing:
    """The files of ``cases/`` and its shard directories, with their size and modification time."""
    listing = Listing()
    if not cases_dir.is_dir():
        return listing
    for entry in os.scandir(cases_dir):
        if entry.name.startswith(TEMPORARY_PREFIX):
            listing.temporary.append(Path(entry.path))
        elif SHARD.match(entry.name) and entry.is_dir(follow_symlinks=False):
            for inner in os.scandir(entry.path):
                if inner.name.startswith(TEMPORARY_PREFIX):
                    listing.temporary.append(Path(inner.path))
                elif BATCH_FILE.match(inner.name) and inner.is_file(follow_symlinks=False):
                    stat = inner.stat(follow_symlinks=False)
                    listing.files.append((f"{entry.name}/{inner.name}", stat.st_size, stat.st_mtime_ns))
                else:
                    listing.bad.append((Path(inner.path), NOT_A_CASE_FILE))
        elif CASE_FILE.match(entry.name) and entry.is_file(follow_symlinks=False):
            stat = entry.stat(follow_symlinks=False)
            listing.files.append((entry.name, stat.st_size, stat.st_mtime_ns))
        elif UNRECORDED_CASE_FILE.match(entry.name):
            listing.bad.append((Path(entry.path), "unrecorded: no size and sha256 in its name (written by an older "
                                                  "version or by hand), so it cannot be verified"))
        else:
            listing.bad.append((Path(entry.path), NOT_A_CASE_FILE))
    listing.files.sort()
    listing.bad.sort()
    return listing


def index_identity(expected: StoreIdentity | None) -> bytes:
    """The record a segment keeps of the identity its files were verified against."""
    record = (expected.record(0) if expected is not None
              else {"config_hash": None, "result_schema_version": RESULT_SCHEMA_VERSION})
    record.pop("case_id", None)
    return json.dumps(record, sort_keys=True).encode()


@dataclass
class Entries:
    """Index rows as numpy columns, one per (file, case); files by code into ``names``.

    ``failures``: row -> the estimators whose row failed, for the rows that have any (rare)."""
    names: list[str]
    codes: np.ndarray
    size: np.ndarray
    mtime_ns: np.ndarray
    written_ns: np.ndarray
    case_id: np.ndarray
    failed_case: np.ndarray
    first_row: np.ndarray
    row_count: np.ndarray
    failures: dict[int, list[str]] = field(default_factory=dict)

    NUMERIC = ("size", "mtime_ns", "written_ns", "case_id", "first_row", "row_count")

    @property
    def num_rows(self) -> int:
        return len(self.case_id)

    @classmethod
    def empty(cls) -> Entries:
        return cls.from_table(INDEX_SCHEMA.empty_table())

    @classmethod
    def from_table(cls, table: pa.Table) -> Entries:
        """From a table of :data:`INDEX_SCHEMA` (``batch`` plain or dictionary-encoded)."""
        batch = table.column("batch").combine_chunks()
        if not pa.types.is_dictionary(batch.type):
            batch = batch.dictionary_encode()
        names = batch.dictionary.to_pylist()
        lists = table.column("failed_estimators").combine_chunks()
        lengths = pc.fill_null(pc.list_value_length(lists), 0).to_numpy()
        with_failures = np.flatnonzero(lengths)
        failures = dict(zip(with_failures.tolist(), lists.take(pa.array(with_failures)).to_pylist()))
        columns = {name: table.column(name).to_numpy().astype(np.int64) for name in cls.NUMERIC}
        return cls(names=names, codes=batch.indices.to_numpy(zero_copy_only=False).astype(np.int64),
                   failed_case=table.column("failed_case").to_numpy(zero_copy_only=False).astype(bool),
                   failures=failures, **columns)

    def to_table(self) -> pa.Table:
        """As a table of :data:`INDEX_SCHEMA`, ``batch`` dictionary-encoded (a name per file, not per case)."""
        lengths = np.zeros(self.num_rows, dtype=np.int32)
        values: list[str] = []
        for row in sorted(self.failures):
            lengths[row] = len(self.failures[row])
            values += self.failures[row]
        offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)
        failed = pa.ListArray.from_arrays(pa.array(offsets), pa.array(values, type=pa.string()))
        batch = pa.DictionaryArray.from_arrays(pa.array(self.codes.astype(np.int32)), pa.array(self.names, type=pa.string()))
        schema = INDEX_SCHEMA.set(0, pa.field("batch", batch.type))
        return pa.table({"batch": batch, "size": self.size, "mtime_ns": self.mtime_ns, "written_ns": self.written_ns,
                         "case_id": self.case_id, "failed_case": self.failed_case, "first_row": self.first_row,
                         "row_count": self.row_count, "failed_estimators": failed}, schema=schema)

    def take(self, rows: np.ndarray) -> Entries:
        """These rows (positions), in this order."""
        rows = np.asarray(rows, dtype=np.int64)
        failures = {}
        if self.failures:
            position = {int(row): new for new, row in enumerate(rows.tolist()) if int(row) in self.failures}
            failures = {new: self.failures[row] for row, new in position.items()}
        return Entries(names=self.names, codes=self.codes[rows], failed_case=self.failed_case[rows],
                       failures=failures, **{name: getattr(self, name)[rows] for name in self.NUMERIC})

    def mask(self, keep: np.ndarray) -> Entries:
        return self.take(np.flatnonzero(keep))

    @staticmethod
    def concat(parts: list[Entries]) -> Entries:
        if not parts:
            return Entries.empty()
        if len(parts) == 1:
            return parts[0]
        names: list[str] = []
        codes, failures, offset = [], {}, 0
        for part in parts:
            codes.append(part.codes + len(names))
            names += part.names
            failures.update({row + offset: value for row, value in part.failures.items()})
            offset += part.num_rows
        return Entries(names=names, codes=np.concatenate(codes),
                       failed_case=np.concatenate([part.failed_case for part in parts]), failures=failures,
                       **{name: np.concatenate([getattr(part, name) for part in parts]) for name in Entries.NUMERIC})

    def file_names(self) -> np.ndarray:
        """The file of each row (object array)."""
        return np.asarray(self.names, dtype=object)[self.codes] if self.num_rows else np.zeros(0, dtype=object)

    def used_codes(self) -> np.ndarray:
        return np.unique(self.codes)


@dataclass
class Segment:
    """One index segment as loaded: its rows, and the key (size, mtime) of each file it records."""
    entries: Entries
    identity: bytes

    @cached_property
    def file_keys(self) -> list[tuple[int, str, int, int]]:
        """(code, name, size, mtime_ns) of each file of the segment."""
        codes, first = np.unique(self.entries.codes, return_index=True)
        sizes, times = self.entries.size[first].tolist(), self.entries.mtime_ns[first].tolist()
        return [(code, self.entries.names[code], size, mtime) for code, size, mtime in zip(codes.tolist(), sizes, times)]


class CaseIndex:
    """The index segments of one store, as loaded by this process (a segment is never rewritten: new
    names only, so a loaded one stays valid while its file exists)."""

    def __init__(self, index_dir: Path):
        self.dir = index_dir
        self._segments: dict[str, Segment] = {}
        self.last_scan: tuple[tuple, CaseScan] | None = None    # (what it was made from, the scan)
        self.bad: list[tuple[Path, str]] = []

    def segment_names(self) -> list[str]:
        if not self.dir.is_dir():
            return []
        return sorted(entry.name for entry in os.scandir(self.dir) if not entry.name.startswith(TEMPORARY_PREFIX))

    def load(self, expected: StoreIdentity | None) -> list[Segment]:
        """The valid segments of identity ``expected`` (segments read before: from memory)."""
        names = self.segment_names()
        identity = index_identity(expected)
        self._segments = {name: segment for name, segment in self._segments.items() if name in names}
        self.bad = []
        for name in names:
            if name in self._segments:
                continue
            segment, problem = self._read(name)
            if segment is None:
                self.bad.append((self.dir / name, problem or "bad"))
            else:
                self._segments[name] = segment
        return [segment for segment in self._segments.values() if segment.identity == identity]

    def _read(self, name: str) -> tuple[Segment | None, str | None]:
        match = SEGMENT_FILE.match(name)
        if match is None:
            return None, "not an index segment (allowed: segment-<uuid>.<bytes>.<sha256>.parquet)"
        try:
            data = (self.dir / name).read_bytes()
        except FileNotFoundError:
            return None, "removed while read"
        except OSError as exc:
            return None, f"unreadable: {exc.strerror or exc}"
        if len(data) != int(match.group(2)) or sha256_bytes(data) != match.group(3):
            return None, "corrupted or truncated: its size or sha256 differs from its name (its files are verified again)"
        try:
            table = parquet_file_of_bytes(data, read_dictionary=["batch"]).read(use_threads=False)
        except pa.ArrowException as exc:
            return None, f"unreadable as Parquet: {str(exc).splitlines()[0]}"
        identity = (table.schema.metadata or {}).get(INDEX_KEY)
        if identity is None:
            return None, "no identity record"
        expected_types = {field.name: field.type for field in INDEX_SCHEMA}
        expected_types["batch"] = pa.dictionary(pa.int32(), pa.string())
        if table.column_names != INDEX_SCHEMA.names or any(
                table.schema.field(name).type != kind for name, kind in expected_types.items()):
            return None, "not of the index schema"
        return Segment(Entries.from_table(table), identity), None

    def append(self, entries: Entries, expected: StoreIdentity | None) -> str | None:
        """Write ``entries`` as a new segment (best effort: None when the store is not writable); its name."""
        identity = index_identity(expected)
        data = table_bytes(entries.to_table().replace_schema_metadata({INDEX_KEY: identity}))
        name = f"segment-{uuid.uuid4().hex}.{len(data)}.{sha256_bytes(data)}.parquet"
        try:
            self.dir.mkdir(exist_ok=True)
            atomic_write_bytes(self.dir / name, data)
        except OSError:
            return None
        self._segments[name] = Segment(entries, identity)
        return name

    def merge(self, current: Entries, current_files: set[str], expected: StoreIdentity | None) -> None:
        """Replace the segments by fewer (call it holding the store's lock): bad segments and segments of
        another identity are removed, and when there are more than :data:`MERGE_SEGMENTS` every segment
        but the largest is rewritten as one, keeping only the rows of ``current`` (the files now listed)."""
        for path, _ in self.bad:
            path.unlink(missing_ok=True)
        identity = index_identity(expected)
        for name, segment in list(self._segments.items()):
            if segment.identity != identity:
                (self.dir / name).unlink(missing_ok=True)
                del self._segments[name]
        if len(self._segments) <= MERGE_SEGMENTS:
            return
        largest = max(self._segments, key=lambda name: self._segments[name].entries.num_rows)
        small = [name for name in self._segments if name != largest]
        files = {key[1] for name in small for key in self._segments[name].file_keys} & current_files
        largest_files = {key[1] for key in self._segments[largest].file_keys}
        wanted = np.array([name in files and name not in largest_files for name in current.names], dtype=bool)
        kept = current.mask(wanted[current.codes]) if current.num_rows else current
        if kept.num_rows and self.append(kept, expected) is None:
            return
        for name in small:
            (self.dir / name).unlink(missing_ok=True)
            del self._segments[name]


@dataclass
class CaseScan:
    """What ``cases/`` holds: the counted file of each finished case and the files that are not counted.

    ``counted``: one index row per counted case, sorted by case_id."""
    cases_dir: Path
    counted: Entries = field(default_factory=Entries.empty)
    bad: list[tuple[Path, str]] = field(default_factory=list)
    superseded: list[tuple[Path, str]] = field(default_factory=list)
    temporary: list[Path] = field(default_factory=list)
    files: int = 0                       # verified files (counted or superseded)

    @property
    def case_ids(self) -> np.ndarray:
        return self.counted.case_id

    @property
    def failed_case(self) -> np.ndarray:
        return self.counted.failed_case

    def states(self) -> dict[int, str]:
        """case_id -> 'ok' or 'failed' for every counted case."""
        return dict(zip(self.case_ids.tolist(), np.where(self.failed_case, "failed", "ok").tolist()))

    def path_of(self, case_id: int) -> Path:
        """The file case ``case_id`` counts from (KeyError: not counted)."""
        position = int(np.searchsorted(self.case_ids, case_id))
        if position >= len(self.case_ids) or self.case_ids[position] != case_id:
            raise KeyError(case_id)
        return self.cases_dir / self.counted.names[int(self.counted.codes[position])]

    def in_plan(self, planned: np.ndarray) -> np.ndarray:
        """Mask of the counted cases that are in ``planned`` (case ids, sorted)."""
        if len(planned) == 0 or len(self.case_ids) == 0:
            return np.zeros(len(self.case_ids), dtype=bool)
        position = np.minimum(np.searchsorted(planned, self.case_ids), len(planned) - 1)
        return planned[position] == self.case_ids

    def failed_rows(self, mask: np.ndarray) -> dict[str, int]:
        """Estimator -> rows with status 'failed' among the counted cases of ``mask``."""
        counts: dict[str, int] = {}
        for row, names in self.counted.failures.items():
            if mask[row]:
                for name in names:
                    counts[name] = counts.get(name, 0) + 1
        return counts

    def fingerprint(self, planned: np.ndarray | Iterable[int]) -> str:
        """sha256 over the counted cases of ``planned`` and the names (so sizes and digests) of their files."""
        planned = planned if isinstance(planned, np.ndarray) else np.sort(np.fromiter(planned, np.int64))
        return fingerprint(self.counted.mask(self.in_plan(planned)))


def fingerprint(counted: Entries) -> str:
    """sha256 over the case ids (sorted) and the name of the file each counts from."""
    order = np.argsort(counted.case_id, kind="stable")
    codes = counted.codes[order]
    used = np.unique(codes)
    names = [counted.names[code] for code in used.tolist()]
    rank_of_used = np.argsort(np.argsort(np.asarray(names, dtype=object))) if names else np.zeros(0, np.int64)
    rank = np.zeros(len(counted.names) or 1, dtype=np.int64)
    rank[used] = rank_of_used
    return sha256_bytes("\n".join(sorted(names)).encode() + b"\0" + counted.case_id[order].astype("<i8").tobytes()
                        + b"\0" + rank[codes].astype("<i8").tobytes())


def scan_cases(cases_dir: Path, index: CaseIndex, expected: StoreIdentity | None, *, merge: bool = False,
               record: bool = True) -> CaseScan:
    """List ``cases/``, trust the files the index has unchanged, verify the others (appending what they hold
    to the index unless not ``record``, or the store has no identity), and count each case once.
    ``merge``: the caller holds the store's lock (the index's segments may be merged)."""
    listing = list_case_files(cases_dir)
    key = (tuple(listing.files), tuple(path for path, _ in listing.bad), tuple(listing.temporary),
           tuple(index.segment_names()), index_identity(expected), record)
    if not merge and index.last_scan is not None and index.last_scan[0] == key:
        return index.last_scan[1]                   # nothing changed since this process's last scan
    scan = _scan_listed(cases_dir, listing, index, expected, merge=merge, record=record)
    index.last_scan = (key, scan) if not merge else None
    return scan


def _scan_listed(cases_dir: Path, listing: Listing, index: CaseIndex, expected: StoreIdentity | None, *,
                 merge: bool, record: bool) -> CaseScan:
    scan = CaseScan(cases_dir, bad=list(listing.bad), temporary=listing.temporary)
    listed = {relative: (size, mtime) for relative, size, mtime in listing.files}
    claimed: set[str] = set()
    parts = []
    for segment in index.load(expected):
        keep = np.zeros(len(segment.entries.names), dtype=bool)
        for code, name, size, mtime in segment.file_keys:
            if name not in claimed and listed.get(name) == (size, mtime):
                keep[code] = True
                claimed.add(name)
        if keep.any():
            parts.append(segment.entries.mask(keep[segment.entries.codes]))
    new_parts = []
    for relative in sorted(set(listed) - claimed):
        table, problem = verify_case_file(cases_dir / relative, relative, expected)
        if table is None:
            scan.bad.append((cases_dir / relative, problem or "bad"))
        else:
            new_parts.append(Entries.from_table(table))
            claimed.add(relative)
    if new_parts:
        new = Entries.concat(new_parts)
        if record and expected is not None:
            index.append(new, expected)
        parts.append(new)
    everything = Entries.concat(parts)
    if merge:
        index.merge(everything, claimed, expected)
    scan.bad.sort(key=lambda item: str(item[0]))
    if everything.num_rows == 0:
        return scan
    order = np.argsort(everything.case_id, kind="stable")
    ordered = everything.case_id[order]
    repeated = np.flatnonzero(ordered[1:] == ordered[:-1])
    if repeated.size:                       # a case in several files: the latest write counts
        keep = np.ones(len(order), dtype=bool)
        starts = np.unique(np.searchsorted(ordered, ordered[repeated]))
        for start in starts.tolist():
            end = int(np.searchsorted(ordered, ordered[start], side="right"))
            rows = order[start:end].tolist()
            best = max(range(len(rows)), key=lambda k: (int(everything.written_ns[rows[k]]),
                                                        everything.names[int(everything.codes[rows[k]])]))
            keep[start:end] = False
            keep[start + best] = True
        order = order[keep]
    scan.counted = everything.take(order)
    files = set(np.unique(everything.codes).tolist())
    counting = set(np.unique(scan.counted.codes).tolist())
    scan.files = len({everything.names[code] for code in files})
    superseded = {everything.names[code] for code in files - counting} - {everything.names[c] for c in counting}
    scan.superseded = [(cases_dir / name, "superseded: each of its cases is in a newer file")
                       for name in sorted(superseded)]
    return scan
