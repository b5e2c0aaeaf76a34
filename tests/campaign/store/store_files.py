"""Helpers of the store tests: find, replace and read the case files of stores whose files each hold one
case (what the worker writes with ``write_case_rows``: one-case batches, or one-case files of older stores)."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import BATCH_FILE, CASE_FILE, batch_file_name, sha256_bytes


def case_files(store: Path) -> dict[int, Path]:
    """case id -> its file (one-case batches in the shard directories, older one-case files at the top)."""
    files = {}
    cases = store / "cases"
    for path in sorted(cases.glob("??/batch-*.parquet")) + sorted(cases.glob("case-*.parquet")):
        match = BATCH_FILE.match(path.name) or CASE_FILE.match(path.name)
        if match is not None:
            files[int(match.group(1))] = path
    return files


def all_case_files(store: Path) -> set[str]:
    """The names of every file under ``cases/``."""
    return {path.name for path in (store / "cases").rglob("*") if path.is_file()}


def place(store: Path, case_id: int, data: bytes) -> Path:
    """``data`` as a one-case batch file of ``case_id`` under its own correct size and sha256 name, replacing
    the store's file of that case."""
    case_files(store)[case_id].unlink()
    return write_named(store, case_id, data)


def write_named(store: Path, case_id: int, data: bytes) -> Path:
    """``data`` in ``cases/`` named as a one-case batch of ``case_id`` with its correct size and sha256."""
    path = store / "cases" / batch_file_name(case_id, 1, len(data), sha256_bytes(data))
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(data)
    return path


def results_part(store: Path) -> Path:
    """The first part of the store's compacted results (``results.parquet/`` is a directory of parts)."""
    return sorted((store / "results.parquet").glob("part-*.parquet"))[0]


def results(store: Path) -> pd.DataFrame:
    """The store's results as ``campaign table`` reads them (sorted by case_id, estimators in order)."""
    return CampaignStore(store).results()


def case_rows(case_id: int, seed: int = 1, estimators=("dimes",), failed: tuple = ()) -> list[dict]:
    """Rows of one case of the declared schema: one per estimator, those of ``failed`` with status failed;
    the velocity error is ``case_id / 100`` m/s (so a test can tell the rows of cases apart)."""
    from campaign.store.result_schema import CASE_FILE_SCHEMA

    return [{**dict.fromkeys(CASE_FILE_SCHEMA.names), "case_id": case_id, "campaign_seed": seed, "estimator": name,
             "status": "failed" if name in failed else "ok", "error": "RuntimeError: planted" if name in failed else "",
             "velocity_error_mps": case_id / 100, "feature_brightness": [1.0, 2.0]} for name in estimators]


def make_store(root: Path, case_ids, estimators=("dimes",), seed: int = 1) -> CampaignStore:
    """An empty store (manifest and plan) of the planned ``case_ids``."""
    manifest = {"config_hash": "c" * 64, "seed": seed, "estimators": list(estimators), "cases_per_class": {}}
    store = CampaignStore(root)
    with store.lock():
        store.prepare(manifest, pd.DataFrame({"case_id": list(case_ids)}))
    return CampaignStore(root)
