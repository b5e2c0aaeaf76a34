"""The campaign store at 10^4, 10^5 and 10^6 cases, without simulating: ``store/<operation>`` rows.

A store is written through the real writer (:func:`campaign.store.case_files.write_case_batch`, batches
of :data:`BATCH_CASES` cases as the runner's worker tasks write them) with synthetic rows of the declared
schema and identity: each row is one template row (every declared column, 8 tracked features) with its
case id, class, seed and a drawn velocity error, so the table has realistic numbers. The manifest is a Gusev manifest with a
synthetic plan of ``cases`` cases (case ids ``class_index * 1 000 000 + index``).

Timed, each in its own process (so the index is read from disk as a new ``campaign`` command reads it,
and the peak RSS is that operation's), with 99 % of the cases written: ``index`` (the first scan after
the batches were written: every batch verified once and indexed, what a run's driver pays as batches
arrive), ``compact_full`` (results of every case); then with the last 1 % written:
``compact_incremental`` (their cases only), ``status`` (``CampaignStore.status``), ``resume_scan`` (what
``campaign submit`` does before it submits anything: ``prepare`` under the lock and
``finished_case_ids``), ``verify`` (every file re-hashed), ``table`` (``write_table``) and ``report_load``
(``CampaignStore.results``, every column: the data ``campaign report`` loads). Each row has ``cases``,
``measured`` (s), ``per_case_us`` and ``peak_rss_mib``; ``store/disk`` the bytes per case and the largest
directory; a final row per operation gives the growth per case between the smallest and the largest
size.

``BENCH_STORE_SIZES=10000,100000`` limits the sizes (default 10^4, 10^5, 10^6; 10^6 takes ~10 min to write
and ~2 GB of disk under ``$TMPDIR``).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.targets import (
    STORE_COMPACT_INCREMENTAL_S,
    STORE_RESUME_SCAN_S,
    STORE_STATUS_S,
    STORE_TABLE_S,
    target_columns,
)

REPO = Path(__file__).resolve().parents[1]
SIZES = (10_000, 100_000, 1_000_000)
BATCH_CASES = 100
"""Cases per batch file (a worker task's cases)."""
CLASSES = {"gcp": 0.59, "gdcp": 0.41, "gkep": 0.0}
ESTIMATORS = ("dimes",)
INCREMENT = 0.01
"""Fraction of the plan written after the first compaction (the incremental compaction's new cases)."""
TARGETS = {"status": STORE_STATUS_S, "resume_scan": STORE_RESUME_SCAN_S, "table": STORE_TABLE_S}


def _template_row() -> dict:
    """One case row of every declared column (a valid reference-estimator answer, 8 features)."""
    from campaign.store.result_schema import CASE_FILE_SCHEMA, SENSOR_PREFIX

    row: dict = {}
    for field in CASE_FILE_SCHEMA:
        name = field.name
        if name.startswith(SENSOR_PREFIX):
            row[name] = 0.001
        elif str(field.type) == "double":
            row[name] = 1.0
        elif str(field.type) == "int64":
            row[name] = 0
        elif str(field.type) == "bool":
            row[name] = True
        elif str(field.type) == "string":
            row[name] = ""
    row.update({"class_name": "gcp", "terrain_name": "synthetic-gcp-4101", "profile_name": "gusev-0220",
                "worker": "node:1234", "status": "ok", "reason": "ok", "attempts": 1,
                "feature_brightness": [4000.0 + 10 * k for k in range(8)],
                "feature_contrast": [40.0 + k for k in range(8)],
                "feature_correlation": [0.95] * 8, "feature_status": ["ok"] * 8,
                "heat_shield_in_view": [True, False, False], "outside_terrain_fraction": [0.0, 0.0, 0.0],
                "velocity_uncertainty_mps": 1.9})
    missing = [field.name for field in CASE_FILE_SCHEMA if field.name not in row]
    assert not missing, missing
    return row


def synthetic_plan(cases: int) -> list[dict]:
    """A plan of ``cases`` cases split over the Gusev classes by their ellipse fractions (gkep: 1 %)."""
    counts = {"gcp": int(cases * 0.58), "gkep": max(1, cases // 100)}
    counts["gdcp"] = cases - sum(counts.values())
    plan = []
    for class_index, class_name in enumerate(CLASSES):
        for index in range(counts[class_name]):
            plan.append({"case_id": class_index * 1_000_000 + index, "class_name": class_name,
                         "class_index": class_index, "case_in_class": index,
                         "ellipse_fraction": CLASSES[class_name], "terrain_name": f"synthetic-{class_name}-4101",
                         "profile_index": index % 400, "profile_name": f"gusev-{index % 400:04d}",
                         "heading_rad": 0.001 * (index % 6283), "offset_east_m": float(index % 1000),
                         "offset_north_m": float(index % 977), "footprint_inside": True})
    return plan


def case_rows(template: dict, plan_row: dict, seed: int, generator: np.random.Generator) -> list[dict]:
    """The rows of one synthetic case (one per estimator), with a drawn velocity error."""
    rows = []
    for estimator in ESTIMATORS:
        error = float(abs(generator.normal(0.0, 2.0)))
        rows.append({**template, **{key: plan_row[key] for key in plan_row if key in template},
                     "campaign_seed": seed, "estimator": estimator, "velocity_error_mps": error,
                     "estimate_velocity_east_mps": error, "valid": error < 6.0})
    return rows


def build_store(root: Path, cases: int, written_fraction: float = 1.0, batch_cases: int = BATCH_CASES) -> tuple:
    """A store of ``cases`` planned cases with the first ``written_fraction`` of them written; returns
    (store, plan rows, manifest, seconds spent writing cases)."""
    import pandas as pd

    from campaign.store.campaign_store import CampaignStore
    from campaign.store.case_identity import StoreIdentity

    seed = 1
    plan = synthetic_plan(cases)
    manifest = {"config_hash": "b" * 64, "seed": seed, "estimators": list(ESTIMATORS), "site": "Gusev",
                "cases_per_class": {}, "ellipse_fractions": CLASSES, "config_file": "synthetic.toml",
                "config": {"campaign": {"false_valid_mps": 5.0}}}
    store = CampaignStore(root)
    with store.lock():
        store.prepare(manifest, pd.DataFrame(plan))
    identity = StoreIdentity.of_manifest(manifest)
    template = _template_row()
    generator = np.random.default_rng(seed)
    written = int(round(cases * written_fraction))
    start = time.perf_counter()
    write_cases(store, plan[:written], template, seed, identity, generator, batch_cases)
    return store, plan, manifest, time.perf_counter() - start


def write_cases(store, plan_rows: list[dict], template: dict, seed: int, identity, generator,
                batch_cases: int = BATCH_CASES) -> None:
    """Write the cases of ``plan_rows`` in batches of ``batch_cases`` (one file per case with the older
    one-case writer when there is no batch writer)."""
    from campaign.store import case_files

    batch_writer = getattr(case_files, "write_case_batch", None)
    for start in range(0, len(plan_rows), batch_cases):
        entries = [(row["case_id"], case_rows(template, row, seed, generator), True)
                   for row in plan_rows[start:start + batch_cases]]
        if batch_writer is not None:
            batch_writer(store.cases_dir, entries, identity)
        else:
            for case_id, rows, ok in entries:
                case_files.write_case_rows(store.cases_dir, case_id, rows, ok, identity)


OPERATIONS = {
    "index": "store.status()",
    "status": "store.status()",
    "resume_scan": ("with store.lock():\n"
                    "    store.prepare(manifest, plan)\n"
                    "    finished = store.finished_case_ids()\n"
                    "assert len(finished) >= 1"),
    "verify": "from campaign.store.verify import verify_store\nassert verify_store(root).clean",
    "compact_full": "store.compact()",
    "compact_incremental": "store.compact()",
    "table": "from campaign.report.table import write_table\nwrite_table(root)",
    "report_load": "store.results()",
}
PROLOGUE = """
import json, sys, time
from pathlib import Path
import pandas as pd
from campaign.store.campaign_store import CampaignStore
root = Path(sys.argv[1])
store = CampaignStore(root)
manifest = store.manifest()
plan = store.plan()
start = time.perf_counter()
"""
EPILOGUE = """
seconds = time.perf_counter() - start
peak_kib = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))
print(json.dumps({"seconds": seconds, "peak_rss_mib": peak_kib / 1024}))
"""
# VmHWM, not getrusage's ru_maxrss: Linux carries ru_maxrss over exec, so a child would report its parent's peak


def time_operation(root: Path, operation: str) -> dict:
    """Run one operation on the store at ``root`` in a new process: its seconds and the process's peak RSS."""
    code = PROLOGUE + OPERATIONS[operation] + EPILOGUE
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", code, str(root)], capture_output=True, text=True, env=env,
                          check=False)
    if done.returncode != 0:
        raise RuntimeError(f"store/{operation}: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def disk_bytes(root: Path) -> int:
    return sum(entry.stat().st_size for entry in (root / "cases").rglob("*") if entry.is_file())


def largest_directory(root: Path) -> int:
    return max((len(os.listdir(path)) for path, _, _ in os.walk(root)), default=0)


def measure(cases: int, scratch: Path) -> list[dict]:
    """Build a store of ``cases`` cases (99 % written), time every operation, add the last 1 %, time the
    incremental compaction and the operations after it."""
    import pandas as pd  # noqa: F401  (the builder needs it; imported here so the timing does not)

    from campaign.store.case_identity import StoreIdentity

    root = scratch / f"store-{cases}"
    shutil.rmtree(root, ignore_errors=True)
    store, plan, manifest, write_s = build_store(root, cases, written_fraction=1.0 - INCREMENT)
    written = int(round(cases * (1.0 - INCREMENT)))
    rows = [{"name": "store/write", "cases": written, "measured": write_s, "unit": "s",
             "per_case_us": 1e6 * write_s / written, "peak_rss_mib": float("nan")}]
    results: dict[str, dict] = {}
    for operation in ("index", "compact_full"):
        results[operation] = time_operation(root, operation)
        print(f"store/{operation} cases={cases} {results[operation]}", file=sys.stderr, flush=True)
    generator = np.random.default_rng(2)
    write_cases(store, plan[written:], _template_row(), 1, StoreIdentity.of_manifest(manifest), generator)
    for operation in ("compact_incremental", "status", "resume_scan", "verify", "table", "report_load"):
        results[operation] = time_operation(root, operation)
        print(f"store/{operation} cases={cases} {results[operation]}", file=sys.stderr, flush=True)
    size = disk_bytes(root)
    for operation, figures in results.items():
        row = {"name": f"store/{operation}", "cases": cases, "measured": figures["seconds"], "unit": "s",
               "per_case_us": 1e6 * figures["seconds"] / cases, "peak_rss_mib": figures["peak_rss_mib"]}
        if cases == max(SIZES) and operation in TARGETS:
            row.update(target_columns(figures["seconds"], TARGETS[operation], "s"))
        if cases == max(SIZES) and operation == "compact_incremental":
            row.update(target_columns(figures["seconds"], STORE_COMPACT_INCREMENTAL_S, "s"))
        rows.append(row)
    rows.append({"name": "store/disk", "cases": cases, "measured": size / cases, "unit": "B/case",
                 "largest_directory_entries": largest_directory(root)})
    shutil.rmtree(root, ignore_errors=True)
    return rows


def growth_rows(rows: list[dict]) -> list[dict]:
    """Per operation: the seconds per added case between the smallest and the largest size measured."""
    growth = []
    for name in dict.fromkeys(row["name"] for row in rows if row["unit"] == "s"):
        measured = sorted((row["cases"], row["measured"]) for row in rows if row["name"] == name)
        if len(measured) >= 2 and measured[-1][0] > measured[0][0]:
            (small, small_s), (large, large_s) = measured[0], measured[-1]
            growth.append({"name": f"{name}/growth", "cases": f"{small}-{large}",
                           "per_case_us": 1e6 * (large_s - small_s) / (large - small), "unit": "us/case"})
    return growth


def sizes() -> tuple[int, ...]:
    text = os.environ.get("BENCH_STORE_SIZES")
    return tuple(int(size) for size in text.split(",")) if text else SIZES


def run() -> list[dict]:
    scratch = Path(tempfile.mkdtemp(prefix="bench-store-"))
    rows: list[dict] = []
    try:
        for cases in sizes():
            rows += measure(cases, scratch)
        rows += growth_rows(rows)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return rows
