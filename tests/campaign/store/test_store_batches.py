"""The store at scale (issue 34): batch files of many cases, the case index, incremental compaction, and the
guarantees of the one-file-per-case store kept: a batch counts only where its identity matches, a writer
killed mid-batch loses and duplicates nothing, a truncated batch or a corrupt index is found and costs only
a re-verification, a case written twice counts once, ``status`` counts failed rows per estimator.

Real files, real Parquet, a real writer process killed with SIGKILL, the ``campaign`` command line as a
subprocess.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from store_files import case_rows, make_store

from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import (
    BATCH_FILE,
    SHARD,
    case_file_name,
    sha256_bytes,
    table_bytes,
    write_case_batch,
    write_case_rows,
)
from campaign.store.case_identity import StoreIdentity, identity_metadata
from campaign.store.case_index import MERGE_SEGMENTS
from campaign.store.result_schema import RESULTS_SCHEMA, rows_table
from campaign.store.verify import verify_store

REPO = Path(__file__).resolve().parents[3]
HASH = "c" * 64


def _identity(store: CampaignStore) -> StoreIdentity:
    identity = store.identity()
    assert identity is not None
    return identity


def _batch(store: CampaignStore, case_ids, **rows) -> Path:
    return write_case_batch(store.cases_dir, [(case_id, case_rows(case_id, **rows), True) for case_id in case_ids],
                            _identity(store))


def _flip_byte(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def _environment() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def test_a_batch_holds_its_cases_in_one_file_named_by_its_size_and_sha256_in_a_shard_directory(tmp_path):
    store = make_store(tmp_path / "store", range(40))
    path = _batch(store, range(10, 30))
    match = BATCH_FILE.match(path.name)
    data = path.read_bytes()
    assert (int(match.group(1)), int(match.group(2))) == (10, 20)
    assert int(match.group(3)) == len(data) and match.group(4) == sha256_bytes(data)
    assert SHARD.match(path.parent.name) and path.parent.name == sha256_bytes(data)[:2]
    assert pq.read_table(path).column("case_id").to_pylist() == list(range(10, 30))
    status = store.status()
    assert (status.planned, status.done, status.failed, status.missing) == (40, 20, 0, 20)


def test_many_batches_spread_over_shard_directories(tmp_path):
    store = make_store(tmp_path / "store", range(3000))
    for start in range(0, 3000, 3):
        _batch(store, range(start, start + 3))
    top = list(store.cases_dir.iterdir())
    assert all(SHARD.match(path.name) and path.is_dir() for path in top)
    largest = max(len(os.listdir(path)) for path in top)
    assert len(top) <= 256 and largest < 30, largest      # 1000 files over up to 256 directories (~4 each)
    assert store.status().done == 3000


KILLED_BATCH_WRITER = """
import itertools, sys
from pathlib import Path
from campaign.store.case_files import write_case_batch
from campaign.store.case_identity import StoreIdentity
from campaign.store.result_schema import CASE_FILE_SCHEMA
cases = Path(sys.argv[1])
identity = StoreIdentity("c" * 64, 1, ("dimes",))
for attempt in itertools.count():
    entries = [(case_id, [{**dict.fromkeys(CASE_FILE_SCHEMA.names), "case_id": case_id, "campaign_seed": 1,
                           "estimator": "dimes", "status": "ok", "attempts": attempt,
                           "error": "x" * (1000 + attempt % 3000)}], True) for case_id in range(50)]
    write_case_batch(cases, entries, identity)
    if attempt == 0:
        print("writing", flush=True)
"""


def test_a_writer_killed_mid_batch_leaves_the_whole_batch_or_nothing(tmp_path):
    """SIGKILL at any instant of a loop writing a 50-case batch again and again: every case is counted
    exactly once, from a complete batch; a half-written batch is a temporary file, never read."""
    store = make_store(tmp_path / "store", range(50))
    for delay_s in (0.002, 0.04, 0.11, 0.27):
        process = subprocess.Popen([sys.executable, "-c", KILLED_BATCH_WRITER, str(store.cases_dir)],
                                   stdout=subprocess.PIPE, text=True, cwd=REPO, env=_environment())
        assert process.stdout is not None and process.stdout.readline().strip() == "writing"
        time.sleep(delay_s)
        process.send_signal(signal.SIGKILL)
        process.wait()
        scan = CampaignStore(store.root).scan()
        assert scan.bad == [], scan.bad
        assert scan.case_ids.tolist() == list(range(50)), "each case exactly once"
        counting = {scan.path_of(case_id) for case_id in range(50)}
        assert len(counting) == 1, "all 50 from the latest complete batch"
        assert pq.read_table(next(iter(counting))).column("case_id").to_pylist() == list(range(50))
    with store.lock():
        store.reject_bad_files()                 # the superseded batches move to rejected/
    rows = store.read_case_table()
    assert rows.column("case_id").to_pylist() == list(range(50))
    assert len(set(rows.column("attempts").to_pylist())) == 1, "one batch's rows, not a mix"
    assert verify_store(store.root, progress=None).clean


def test_a_truncated_batch_is_found_by_status_rejected_and_its_cases_computed_again(tmp_path):
    store = make_store(tmp_path / "store", range(30))
    batches = [_batch(store, range(start, start + 10)) for start in (0, 10, 20)]
    assert store.status().done == 30                                   # indexed
    os.truncate(batches[1], batches[1].stat().st_size // 2)            # a full disk, a killed copy
    status = CampaignStore(store.root).status()
    assert (status.done, status.missing, status.bad) == (20, 10, 1)
    problems = dict(verify_store(store.root, progress=None).problems)
    assert problems[batches[1]].startswith("truncated: ")
    with store.lock():
        assert store.reject_bad_files() == 1
    assert (store.rejected_dir / batches[1].name).exists()
    _batch(store, range(10, 20))                                       # the next submit computes them
    assert CampaignStore(store.root).status().done == 30
    assert CampaignStore(store.root).read_case_table().column("case_id").to_pylist() == list(range(30))


def test_a_corrupt_index_costs_a_reverification_only(tmp_path):
    store = make_store(tmp_path / "store", range(40))
    for start in range(0, 40, 10):
        _batch(store, range(start, start + 10), failed=("dimes",) if start == 30 else ())
    before = store.status()
    segments = list(store.index_dir.iterdir())
    assert len(segments) == 1
    _flip_byte(segments[0], segments[0].stat().st_size // 2)
    again = CampaignStore(store.root).status()
    assert again == before and again.failed_rows == {"dimes": 10}
    notes = verify_store(store.root, progress=None).notes
    assert any(f"{segments[0]}: bad index segment, corrupted" in note for note in notes), notes
    with store.lock():
        CampaignStore(store.root).reject_bad_files()                     # a writer removes the bad segment
    assert not segments[0].exists() and CampaignStore(store.root).status() == before
    segments = list(store.index_dir.iterdir())
    segments[0].write_bytes(b"")                                        # emptied (its name keeps the record)
    assert CampaignStore(store.root).status() == before


def test_a_batch_corrupted_in_place_with_its_time_restored_is_found_by_verify_and_never_compacted(tmp_path):
    """The index trusts a file by name, size and time; verify re-hashes everything, and compaction checks
    the bytes it reads."""
    store = make_store(tmp_path / "store", range(20))
    good, bad = _batch(store, range(10)), _batch(store, range(10, 20))
    assert store.status().done == 20
    stat = bad.stat()
    _flip_byte(bad, stat.st_size // 2)
    os.utime(bad, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    problems = dict(verify_store(store.root, progress=None).problems)
    assert problems[bad].startswith("corrupted: sha256") and good not in problems
    with store.lock():
        CampaignStore(store.root).compact()
    results = CampaignStore(store.root).results()
    assert results["case_id"].tolist() == list(range(10)), "the corrupted batch's rows are not read"
    assert (store.rejected_dir / bad.name).exists()
    assert CampaignStore(store.root).status().done == 10


def test_a_foreign_batch_is_not_counted(tmp_path):
    store = make_store(tmp_path / "store", range(30))
    _batch(store, range(10))
    other_seed = write_case_batch(store.cases_dir, [(c, case_rows(c, seed=2), True) for c in range(10, 20)],
                                  StoreIdentity(HASH, 2, ("dimes",)))
    other_config = write_case_batch(store.cases_dir, [(c, case_rows(c), True) for c in range(20, 30)],
                                    StoreIdentity("d" * 64, 1, ("dimes",)))
    good = _batch(store, range(20, 30))
    renamed = good.with_name(good.name.replace("batch-000020-10.", "batch-000021-10."))
    good.rename(renamed)                                                # a batch under another batch's name
    data = table_bytes(rows_table(case_rows(25)))                       # rows without any identity record
    unrecorded = store.cases_dir / sha256_bytes(data)[:2] / f"batch-000025-1.{len(data)}.{sha256_bytes(data)}.parquet"
    unrecorded.parent.mkdir(exist_ok=True)
    unrecorded.write_bytes(data)
    status = CampaignStore(store.root).status()
    assert (status.done, status.bad, status.foreign) == (10, 4, 4)
    problems = dict(verify_store(store.root, progress=None).problems)
    assert "campaign_seed 2 (this store: 1)" in problems[other_seed]
    assert "config_hash dddddddddddd (this store: cccccccccccc)" in problems[other_config]
    assert "its name says 10 cases from case 000021" in problems[renamed]
    assert problems[unrecorded].startswith("foreign: no identity record")


def test_a_case_written_twice_counts_once_from_the_later_write(tmp_path):
    store = make_store(tmp_path / "store", range(20))
    first = _batch(store, range(10))
    later = write_case_batch(store.cases_dir, [(c, case_rows(c, failed=("dimes",)), c != 5) for c in range(5, 15)],
                             _identity(store))
    scan = CampaignStore(store.root).scan()
    assert scan.case_ids.tolist() == list(range(15))
    assert {scan.path_of(c) for c in range(5)} == {first} and {scan.path_of(c) for c in range(5, 15)} == {later}
    status = CampaignStore(store.root).status()
    assert (status.done, status.failed, status.failed_rows) == (14, 1, {"dimes": 10})
    whole = _batch(store, range(0, 5))                                  # now every case of `first` is newer elsewhere
    scan = CampaignStore(store.root).scan()
    assert [path for path, _ in scan.superseded] == [first] and scan.path_of(0) == whole
    with store.lock():
        CampaignStore(store.root).compact()
    results = CampaignStore(store.root).results()
    assert results["case_id"].tolist() == list(range(15))
    assert (results["status"] == "failed").sum() == 10


def test_compaction_reads_only_the_new_cases_and_gives_the_same_results_as_a_full_one(tmp_path):
    store = make_store(tmp_path / "store", range(100))
    for start in range(0, 60, 20):
        _batch(store, range(start, start + 20))
    with store.lock():
        assert store.compact() == 60
    parts = sorted((store.results_path).glob("part-*.parquet"))
    assert len(parts) == 1
    kept = parts[0].stat()
    _batch(store, range(60, 100, 2))
    _batch(store, range(61, 100, 2))
    with store.lock():
        assert CampaignStore(store.root).compact() == 40, "only the new cases are read"
    incremental = CampaignStore(store.root).results()
    parts = sorted((store.results_path).glob("part-*.parquet"))
    assert len(parts) == 2 and parts[0].stat().st_mtime_ns == kept.st_mtime_ns, "the first part is not rewritten"
    assert pq.read_table(parts[1]).column("case_id").to_pylist() == list(range(60, 100)), "the new cases only"
    assert incremental["case_id"].tolist() == list(range(100))
    assert CampaignStore(store.root).results_problem() is None
    for path in [*store.results_path.iterdir(), *store.timings_path.iterdir(), store.results_record_path]:
        path.unlink()
    with store.lock():
        assert CampaignStore(store.root).compact() == 100
    full = CampaignStore(store.root).results()
    pd.testing.assert_frame_equal(full, incremental, check_exact=True)
    assert np.array_equal(pd.read_parquet(store.results_path)["case_id"].sort_values(), np.arange(100))


def test_an_older_store_of_one_case_files_is_read_and_extended(tmp_path):
    store = make_store(tmp_path / "store", range(6))
    identity = _identity(store)
    names = []
    for case_id in range(3):                                # as the one-file-per-case store wrote them
        table = rows_table(case_rows(case_id)).replace_schema_metadata(identity_metadata(identity, case_id))
        data = table_bytes(table)
        names.append(case_file_name(case_id, True, len(data), sha256_bytes(data)))
        (store.cases_dir / names[-1]).write_bytes(data)
    rows = rows_table([row for case_id in range(3) for row in case_rows(case_id)]).select(RESULTS_SCHEMA.names)
    record = {"case_files_sha256": sha256_bytes("\n".join(sorted(names)).encode()), "cases": 3,
              "results_sha256": sha256_bytes(table_bytes(rows)), "timings_sha256": ""}
    store.results_path.write_bytes(table_bytes(rows))      # its compaction: one results.parquet file
    store.results_record_path.write_text(json.dumps(record))
    assert store.status().done == 3
    assert store.results_problem() is None and verify_store(store.root, progress=None).clean
    assert store.results()["velocity_error_mps"].tolist() == [0.0, 0.01, 0.02]
    write_case_rows(store.cases_dir, 3, case_rows(3), ok=True)
    _batch(store, [4, 5])
    assert CampaignStore(store.root).results_problem().startswith("out of date")
    with store.lock():
        CampaignStore(store.root).compact()
    assert store.results_path.is_dir(), "the next compaction writes parts"
    results = CampaignStore(store.root).results()
    assert results["velocity_error_mps"].tolist() == [case_id / 100 for case_id in range(6)]
    assert verify_store(store.root, progress=None).clean


def test_the_index_segments_are_merged_by_the_writer(tmp_path):
    store = make_store(tmp_path / "store", range(200))
    for start in range(0, 200, 10):
        _batch(store, range(start, start + 10))
        CampaignStore(store.root).status()                  # each new reader indexes the new batch: a segment
    assert len(list(store.index_dir.iterdir())) > MERGE_SEGMENTS
    with store.lock():
        store.reject_bad_files()
    assert len(list(store.index_dir.iterdir())) <= 2
    status = CampaignStore(store.root).status()
    assert status.done == 200
    assert verify_store(store.root, progress=None).clean


def test_status_counts_failed_rows_per_estimator_and_exits_1(tmp_path):
    store = make_store(tmp_path / "store", range(19), estimators=("dimes", "myest"))
    write_case_batch(store.cases_dir, [(c, case_rows(c, estimators=("dimes", "myest"), failed=("myest",)), True)
                                       for c in range(19)], _identity(store))
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "status", str(store.root)], capture_output=True,
                            text=True, cwd=REPO, env=_environment(), timeout=120)
    assert result.returncode == 1, result.stdout + result.stderr
    assert f"{store.root}: 19 planned, 19 done, 0 failed, 0 missing" in result.stdout
    assert f"{store.root}: estimator myest: 19 failed rows (of 19 finished cases)" in result.stdout
    assert "estimator dimes" not in result.stdout


def test_a_changed_results_part_is_not_trusted_and_verify_rehashes_the_parts(tmp_path):
    store = make_store(tmp_path / "store", range(30))
    _batch(store, range(30))
    with store.lock():
        store.compact()
    part = next(store.results_path.glob("part-*.parquet"))
    stat = part.stat()
    _flip_byte(part, stat.st_size // 2)                              # a new modification time: found at once
    assert CampaignStore(store.root).results_problem().startswith("corrupted: results.parquet/part-")
    assert CampaignStore(store.root).results()["case_id"].tolist() == list(range(30)), "read from the batches"
    os.utime(part, ns=(stat.st_atime_ns, stat.st_mtime_ns))          # its time restored: only a re-hash finds it
    assert CampaignStore(store.root).results_problem() is None
    problems = dict(verify_store(store.root, progress=None).problems)
    assert problems[store.results_path].startswith("corrupted: results.parquet/part-")
    with store.lock():
        assert CampaignStore(store.root).compact() == 30, "compaction re-hashes the parts it keeps"
    assert verify_store(store.root, progress=None).clean


def test_a_store_has_every_case_only_when_prepare_would_leave_none_to_run(tmp_path):
    manifest = {"config_hash": "c" * 64, "seed": 1, "estimators": ["dimes"], "cases_per_class": {}}
    plan = pd.DataFrame({"case_id": list(range(20))})
    store = make_store(tmp_path / "store", range(20))
    assert not store.has_every_case(manifest, plan)                    # nothing computed yet
    batches = [_batch(store, range(start, start + 10)) for start in (0, 10)]
    assert CampaignStore(store.root).has_every_case(manifest, plan)
    assert not store.has_every_case(manifest, pd.DataFrame({"case_id": list(range(21))}))     # a bigger plan
    assert not store.has_every_case({**manifest, "estimators": ["dimes", "other"]}, plan)     # another estimator list
    assert not store.has_every_case({**manifest, "config_hash": "d" * 64}, plan)
    os.truncate(batches[1], batches[1].stat().st_size // 2)             # prepare would reject it: 10 cases to run
    assert not CampaignStore(store.root).has_every_case(manifest, plan)
    with store.lock():
        store.prepare(manifest, plan)
    assert CampaignStore(store.root).status().missing == 10
