"""The campaign store: one directory per campaign, durable per-case results, a compacted dataset.

Layout::

    OUT/manifest.json          config (as resolved), its hash, input file digests, package versions
    OUT/plan.parquet           every planned case (ids, class, terrain, trajectory, placement, seeds)
    OUT/cases/<id>.ok.parquet  the rows of one finished case, one per estimator (``estimator`` column, in
                               [[estimators]] order), written by the worker that computed it
    OUT/cases/<id>.failed.parquet  the same for a case whose simulation failed after its retries (with its error)
    OUT/results.parquet        all rows, sorted by case_id (deterministic: same seed -> same bits)
    OUT/timings.parquet        per-case stage timings and worker names (vary from run to run)

Durability: a row is written to a temporary file in ``cases/``, flushed, fsynced and renamed into
place (``os.replace`` is atomic on POSIX), so a reader never sees a partial file; temporary files
start with ``.tmp-`` and are never read as results. A case computed twice (a worker killed after
writing) renames an identical file over the first: nothing is duplicated.
"""
from __future__ import annotations

import json
import os
import re
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

CASE_FILE = re.compile(r"^case-(\d{6,})\.(ok|failed)\.parquet$")
TIMING_COLUMNS = ("worker", "t_scene_ms", "t_camera_ms", "t_sensors_ms", "t_estimator_ms", "t_case_ms", "attempts")


class StoreError(RuntimeError):
    """The output directory holds another campaign (or is unusable); one-line message."""


@dataclass(frozen=True)
class CaseStatus:
    planned: int
    done: int
    failed: int

    @property
    def missing(self) -> int:
        return self.planned - self.done - self.failed


def case_file_name(case_id: int, ok: bool) -> str:
    return f"case-{case_id:06d}.{'ok' if ok else 'failed'}.parquet"


def write_case_rows(cases_dir: Path, case_id: int, rows: list[dict], ok: bool) -> Path:
    """Durably write a case's rows (one per estimator) in one file (atomic rename); replaces any earlier
    file of the same case. ``ok``: the case was simulated (an estimator's own failure is in its row)."""
    table = pa.Table.from_pylist(rows)
    temporary = cases_dir / f".tmp-{case_id:06d}-{uuid.uuid4().hex}.parquet"
    with open(temporary, "wb") as handle:
        pq.write_table(table, handle)
        handle.flush()
        os.fsync(handle.fileno())
    target = cases_dir / case_file_name(case_id, ok)
    os.replace(temporary, target)
    stale = cases_dir / case_file_name(case_id, not ok)
    if stale.exists():
        stale.unlink()
    _fsync_directory(cases_dir)
    return target


def _fsync_directory(directory: Path) -> None:
    try:
        descriptor = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


class CampaignStore:
    """A campaign's output directory."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.cases_dir = self.root / "cases"
        self.manifest_path = self.root / "manifest.json"
        self.plan_path = self.root / "plan.parquet"
        self.results_path = self.root / "results.parquet"
        self.timings_path = self.root / "timings.parquet"

    # --- creation and identity -------------------------------------------------------------
    def manifest(self) -> dict | None:
        if not self.manifest_path.exists():
            return None
        return json.loads(self.manifest_path.read_text())

    def prepare(self, manifest: dict, plan: pd.DataFrame, fresh: bool = False) -> None:
        """Create the store, or check that it holds the same campaign (same config hash).

        A store of another config is refused unless ``fresh``, which removes its results first.
        """
        existing = self.manifest()
        if existing is not None and existing.get("config_hash") != manifest["config_hash"]:
            if not fresh:
                raise StoreError(
                    f"{self.root}: holds a campaign with another configuration (hash "
                    f"{existing.get('config_hash', '?')[:12]} != {manifest['config_hash'][:12]}); "
                    "use --fresh to discard its results and start afresh, or choose another output directory")
            self.clear()
        elif existing is not None and fresh:
            self.clear()
        self.cases_dir.mkdir(parents=True, exist_ok=True)
        if self.manifest() is None:
            _atomic_write_bytes(self.manifest_path, json.dumps(manifest, indent=2, sort_keys=True).encode())
        if not self.plan_path.exists():
            _atomic_write_table(self.plan_path, pa.Table.from_pandas(plan, preserve_index=False))

    def clear(self) -> None:
        for path in list(self.cases_dir.glob("*")) if self.cases_dir.exists() else []:
            path.unlink()
        for path in (self.manifest_path, self.plan_path, self.results_path, self.timings_path):
            if path.exists():
                path.unlink()

    # --- reading ---------------------------------------------------------------------------
    def plan(self) -> pd.DataFrame:
        if not self.plan_path.exists():
            raise StoreError(f"{self.root}: no plan.parquet: not a campaign directory (run `campaign submit` first)")
        return pd.read_parquet(self.plan_path)

    def finished_case_ids(self) -> dict[int, str]:
        """case_id -> 'ok' or 'failed', from file names alone (works during a run and after a crash)."""
        finished: dict[int, str] = {}
        if not self.cases_dir.exists():
            return finished
        for entry in os.scandir(self.cases_dir):
            match = CASE_FILE.match(entry.name)
            if match:
                finished[int(match.group(1))] = match.group(2)
        return finished

    def status(self) -> CaseStatus:
        planned = len(self.plan())
        finished = self.finished_case_ids()
        failed = sum(1 for state in finished.values() if state == "failed")
        return CaseStatus(planned=planned, done=len(finished) - failed, failed=failed)

    def read_case_rows(self, case_ids: Iterable[int] | None = None) -> pd.DataFrame:
        finished = self.finished_case_ids()
        wanted = sorted(finished if case_ids is None else set(case_ids) & set(finished))
        tables = [pq.read_table(self.cases_dir / case_file_name(case_id, finished[case_id] == "ok"))
                  for case_id in wanted]
        if not tables:
            return pd.DataFrame()
        return pa.concat_tables(tables, promote_options="permissive").to_pandas()

    # --- compaction --------------------------------------------------------------------------
    def compact(self) -> pd.DataFrame:
        """Write results.parquet (deterministic columns, sorted by case_id) and timings.parquet."""
        rows = self.read_case_rows()
        if rows.empty:
            return rows
        rows = rows.sort_values("case_id", kind="stable").reset_index(drop=True)
        keys = ["case_id"] + (["estimator"] if "estimator" in rows.columns else [])
        timing_columns = keys + [column for column in TIMING_COLUMNS if column in rows.columns]
        results = rows.drop(columns=[column for column in TIMING_COLUMNS if column in rows.columns])
        _atomic_write_table(self.results_path, pa.Table.from_pandas(results, preserve_index=False))
        _atomic_write_table(self.timings_path, pa.Table.from_pandas(rows[timing_columns], preserve_index=False))
        return results

    def results(self) -> pd.DataFrame:
        """The compacted results if up to date, else the rows read from the case files."""
        if self.results_path.exists():
            results = pd.read_parquet(self.results_path)
            if results["case_id"].nunique() == len(self.finished_case_ids()):
                return results
        rows = self.read_case_rows()
        return rows.drop(columns=[c for c in TIMING_COLUMNS if c in rows.columns]) if not rows.empty else rows


def _atomic_write_table(path: Path, table: pa.Table) -> None:
    temporary = path.with_name(f".tmp-{uuid.uuid4().hex}-{path.name}")
    with open(temporary, "wb") as handle:
        pq.write_table(table, handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    temporary = path.with_name(f".tmp-{uuid.uuid4().hex}-{path.name}")
    with open(temporary, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
