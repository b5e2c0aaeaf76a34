"""Case files: the batch writer, integrity records in file names, atomic writes.

A worker stores finished cases with :func:`write_case_batch` (several cases, one file) or
:func:`write_case_rows` (one case), as a *batch file* whose name records its size and sha256, computed
from the exact bytes written::

    cases/<sha256[:2]>/batch-<first case id>-<cases>.<size in bytes>.<sha256 hex>.parquet

in one of 256 shard directories (named by the first two digits of the sha256). Its rows are every
row of every case of the batch (:data:`~campaign.store.result_schema.CASE_FILE_SCHEMA`, one per estimator,
cases in order), its Parquet metadata records the campaign, the case ids, their states and the write
time (:func:`~campaign.store.case_identity.batch_metadata`). The bytes are written to a temporary file
(``.tmp-`` prefix, never read as a result), fsynced and renamed to that name (``os.replace`` is atomic on
POSIX): the batch and its record appear together, in one step. A kill at any instant leaves either no
file, an ignored temporary file, or a complete batch whose name verifies it. ``sha256sum`` checks a
batch by hand against its name.

Stores written before batches hold one-case files ``cases/case-<id>.<ok|failed>.<size>.<sha256>.parquet``
(:func:`case_file_name`); they are read as batches of one case. Which files are verified and counted,
and the index that spares hashing them again: :mod:`campaign.store.case_index`.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import re
import time
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from campaign.store.case_identity import (
    StoreIdentity,
    batch_metadata,
    check_rows_match,
)
from campaign.store.result_schema import CASE_FILE_SCHEMA, ResultSchemaError, rows_table, schema_problem

CASE_FILE = re.compile(r"^case-(\d{6,})\.(ok|failed)\.(\d+)\.([0-9a-f]{64})\.parquet$")
UNRECORDED_CASE_FILE = re.compile(r"^case-(\d+)\.(ok|failed)\.parquet$")
TEMPORARY_PREFIX = ".tmp-"
BATCH_FILE = re.compile(r"^batch-(\d{6,})-(\d+)\.(\d+)\.([0-9a-f]{64})\.parquet$")
SHARD = re.compile(r"^[0-9a-f]{2}$")
SHARD_DIGITS = 2
CHUNK_BYTES = 1 << 20


def case_file_name(case_id: int, ok: bool, size: int, digest: str) -> str:
    return f"case-{case_id:06d}.{'ok' if ok else 'failed'}.{size}.{digest}.parquet"


def table_bytes(table: pa.Table) -> bytes:
    """A table serialised as Parquet, in memory (so its size and digest are known before it is written)."""
    buffer = io.BytesIO()
    pq.write_table(table, buffer)
    return buffer.getvalue()


def parquet_file_of_bytes(data: bytes, read_dictionary: list[str] | None = None) -> pq.ParquetFile:
    """Parquet held in memory (bytes already verified against their digest), opened for reading on the calling
    thread only: read it with ``read(use_threads=False)``.

    A read by Arrow's thread pools (``pq.read_table`` of a buffer, ``ParquetFile.read()`` with threads) can
    leave the last reference to the Python-owned bytes on a pool thread. If that thread drops it while the
    interpreter shuts down, it cannot take the GIL, and the process ends in ``std::terminate`` (exit -6,
    "terminate called without an active exception") after the command's output was written. Measured with
    pyarrow 26 on the 2-core machine: 8 of 168 ``campaign report`` runs, four at once, on a store whose plan
    is missing; a reference was still held right after 46 of 200 ``read_table`` calls, after none of 200
    ``read(use_threads=False)`` calls (``tests/campaign/store/test_bytes_read_on_calling_thread.py``)."""
    return pq.ParquetFile(pa.BufferReader(data), read_dictionary=read_dictionary)


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(CHUNK_BYTES), b""):
            digest.update(chunk)
    return digest.hexdigest()


def atomic_write_bytes(path: Path, data: bytes, temporary: Path | None = None) -> None:
    """Write ``data`` to ``path`` through a fsynced temporary file (default ``.tmp-<uuid>-<name>`` beside it)
    and an atomic rename; the temporary file is removed if the write fails (e.g. on a full disk)."""
    temporary = temporary or path.with_name(f"{TEMPORARY_PREFIX}{uuid.uuid4().hex}-{path.name}")
    try:
        with open(temporary, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def atomic_write_table(path: Path, table: pa.Table) -> str:
    """Write a table as Parquet atomically; return the sha256 of the bytes written."""
    data = table_bytes(table)
    atomic_write_bytes(path, data)
    return sha256_bytes(data)


def fsync_directory(directory: Path) -> None:
    try:
        descriptor = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def store_identity(store_root: Path) -> StoreIdentity | None:
    """The identity declared by the ``manifest.json`` of ``store_root`` (None: none, or not readable)."""
    path = store_root / "manifest.json"
    if not path.is_file():                   # absent, or a FIFO/device (reading one could block)
        return None
    try:
        return StoreIdentity.of_manifest(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def write_case_rows(cases_dir: Path, case_id: int, rows: Sequence[Mapping[str, Any]], ok: bool,
                    identity: StoreIdentity | None = None) -> Path:
    """Durably write one case's rows (one per estimator): :func:`write_case_batch` of that one case.
    ``ok``: the case was simulated (an estimator's own failure is in its row).

    ``identity``: as :func:`write_case_batch`.

    Raises
    ------
    campaign.store.result_schema.ResultSchemaError
        As :func:`write_case_batch` (nothing is written).
    """
    return write_case_batch(cases_dir, [(case_id, rows, ok)], identity)


def batch_file_name(first_case_id: int, cases: int, size: int, digest: str) -> str:
    """``<sha256[:2]>/batch-<first case id>-<cases>.<size>.<sha256>.parquet``, relative to ``cases/``."""
    return f"{digest[:SHARD_DIGITS]}/batch-{first_case_id:06d}-{cases}.{size}.{digest}.parquet"


def write_case_batch(cases_dir: Path, entries: Sequence[tuple[int, Sequence[Mapping[str, Any]], bool]],
                     identity: StoreIdentity | None = None) -> Path:
    """Durably write several finished cases in one batch file, in one atomic step, and return its path.

    ``entries``: (case_id, rows, ok) per case, rows one per estimator in ``[[estimators]]`` order,
    ``ok``: the case was simulated (False: it failed after its retries; an estimator's own failure is in
    its row). The batch is ``cases/<sha256[:2]>/batch-<first case id>-<cases>.<bytes>.<sha256>.parquet``:
    every row of every case (:data:`~campaign.store.result_schema.CASE_FILE_SCHEMA`), the identity record
    of the batch (:func:`~campaign.store.case_identity.batch_metadata`: campaign, case ids and states,
    write time) in its Parquet metadata, and its size and sha256 in its name. Written to a temporary
    file, fsynced and renamed: a kill leaves either the whole batch or an ignored temporary file.

    ``identity``: the campaign that computed the rows (the worker passes its own); None: the identity of
    the store ``cases_dir`` belongs to, from its ``manifest.json`` (for tools rewriting a store's cases),
    and no record at all when there is no manifest (such a batch is foreign in every store).

    Raises
    ------
    campaign.store.result_schema.ResultSchemaError
        No entries, a case twice, a row that does not fit the schema, or rows that are not their case's
        of ``identity`` (nothing is written).
    """
    identity = identity if identity is not None else store_identity(cases_dir.parent)
    if not entries:
        raise ResultSchemaError("a batch of no cases")
    case_ids = [int(case_id) for case_id, _, _ in entries]
    if len(set(case_ids)) != len(case_ids):
        raise ResultSchemaError(f"case {next(c for c in case_ids if case_ids.count(c) > 1)} twice in one batch")
    all_rows = [row for _, rows, _ in entries for row in rows]
    table = rows_table(all_rows, CASE_FILE_SCHEMA)
    if identity is not None:
        for case_id, rows, _ in entries:
            problem = check_rows_match(rows, identity, case_id)
            if problem is not None:
                raise ResultSchemaError(f"case {case_id}: {problem}")
        states = ["ok" if ok else "failed" for _, _, ok in entries]
        table = table.replace_schema_metadata(batch_metadata(identity, case_ids, states, time.time_ns()))
    data = table_bytes(table)
    digest = sha256_bytes(data)
    target = cases_dir / batch_file_name(case_ids[0], len(case_ids), len(data), digest)
    created = not target.parent.is_dir()
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(target, data, target.parent / f"{TEMPORARY_PREFIX}{uuid.uuid4().hex}.parquet")
    fsync_directory(target.parent)
    if created:
        fsync_directory(cases_dir)
    return target


def read_case_table(path: Path) -> pa.Table:
    """The rows of a case file, checked against the declared schema (without its identity record).

    Raises
    ------
    campaign.store.result_schema.ResultSchemaError
        The file's columns do not fit :data:`~campaign.store.result_schema.CASE_FILE_SCHEMA` (the message
        names the file and the column).
    """
    table = pq.read_table(path)
    problem = schema_problem(table.schema, CASE_FILE_SCHEMA)
    if problem is not None:
        raise ResultSchemaError(f"{path}: {problem}")
    return table.replace_schema_metadata(None)      # the identity record stays with its file
