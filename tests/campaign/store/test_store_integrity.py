"""Store integrity (issue 16): every case file verified by the size and sha256 recorded when it was written;
bad files never counted or read, moved to rejected/ and recomputed; manifest and plan verified; results
trusted only when they match; ``--fresh`` checks everything and moves the old store aside.

Real processes (the ``campaign`` CLI as a subprocess for the reference run and the unusable-cluster check, as
``campaign.cli.main`` in this process with its file descriptors captured for the other commands, see
``service_campaigns.campaign_in_process``; the cases run on the test process's warm LocalCluster,
``warm_scheduler`` in tests/conftest.py, whose start-up is not what is tested here), real files, damaged the way
disks, editors and kills damage them.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from store_files import all_case_files, results, results_part
from store_files import case_files as _case_files

from campaign.store.campaign_store import CampaignStore, StoreError
from campaign.store.case_files import (
    BATCH_FILE,
    sha256_bytes,
    write_case_rows,
)
from campaign.store.case_identity import StoreIdentity
from campaign.store.case_index import CaseIndex, scan_cases
from service_campaigns import campaign_in_process, file_tree, site_copy

REPO = Path(__file__).resolve().parents[3]
SITE = REPO / "sitedata" / "gusev.toml"
SCALE = "0.005"   # gcp 1, gdcp 1, gkep 1 case


def _environment() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def _campaign(*args, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "campaign.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO, env=_environment())


def _submit(out: Path, *extra, site: Path = SITE, scale: str = SCALE, scheduler: str = "") -> list:
    """``campaign submit`` of ``site`` into ``out``: on the cluster at ``scheduler`` (the session's warm one, see
    tests/conftest.py), else on an embedded cluster of one worker."""
    cluster = ["--scheduler", scheduler] if scheduler else ["--workers", "1"]
    return ["submit", site, "--output", out, "--cases-scale", scale, *cluster, "--no-progress", *extra]


def _one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in text, text
    return lines[0]


def _replaced(table: pa.Table, **values) -> pa.Table:
    """``table`` with each named column set to one value in every row (its declared type kept)."""
    for name, value in values.items():
        index = table.schema.get_field_index(name)
        table = table.set_column(index, table.schema.field(index), pa.array([value] * table.num_rows,
                                                                             type=table.schema.field(index).type))
    return table


def _flip_byte(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.fixture()
def cli(capfd):
    """``cli(*args)``: the ``campaign`` command in this process (``service_campaigns.campaign_in_process``)."""
    return lambda *args: campaign_in_process(capfd, *args)


@pytest.fixture(scope="module")
def reference(tmp_path_factory, warm_scheduler) -> Path:
    out = tmp_path_factory.mktemp("integrity") / "reference"
    result = _campaign(*_submit(out, scheduler=warm_scheduler))
    assert result.returncode == 0, result.stdout + result.stderr
    return out


@pytest.fixture()
def store(reference, tmp_path) -> Path:
    """A copy of the finished reference store to damage."""
    copy = tmp_path / "store"
    shutil.copytree(reference, copy)
    return copy


@pytest.mark.cluster
@pytest.mark.slow
def test_a_clean_store_verifies_and_names_record_size_and_sha256(reference, cli):
    files = _case_files(reference)
    assert sorted(files) == sorted(CampaignStore(reference).plan()["case_id"])
    for path in files.values():
        match = BATCH_FILE.match(path.name)
        data = path.read_bytes()
        assert int(match.group(3)) == len(data) and match.group(4) == sha256_bytes(data)
    result = cli("verify", reference)
    assert result.returncode == 0 and "clean" in result.stdout, result.stdout


@pytest.mark.cluster
@pytest.mark.slow
def test_damaged_and_stray_case_files_are_not_counted_then_rejected_and_recomputed(reference, store, cli,
                                                                                   warm_scheduler):
    files = _case_files(store)
    first, second, third = sorted(files)
    os.truncate(files[first], 100)                                 # truncated (disk full, killed copy)
    _flip_byte(files[second], files[second].stat().st_size // 2)   # corrupted, same size
    unrecorded = store / "cases" / f"case-{third:06d}.ok.parquet"   # no record (older version, by hand)
    files[third].rename(unrecorded)
    stray_rows = pq.read_table(unrecorded).to_pylist()
    stray = write_case_rows(store / "cases", 999999, [{**row, "case_id": 999999} for row in stray_rows], ok=True)
    os.utime(stray, ns=(0, 0))                    # older than the index: found and verified by its name, not its time
    junk = store / "cases" / "notes.txt"
    junk.write_text("not a case")

    status = cli("status", store)
    assert status.returncode == 0, status.stderr
    assert f"{store}: 3 planned, 0 done, 0 failed, 3 missing" in status.stdout
    assert "4 bad case files not counted" in status.stdout and "1 case files of cases outside the plan" in status.stdout

    verify = cli("verify", store)
    assert verify.returncode == 1
    lines = verify.stdout.splitlines()
    for path, what in ((files[first], "truncated: 100 bytes"), (files[second], "corrupted: sha256"), (unrecorded, "unrecorded"),
                       (junk, "not a case file"), (store / "results.parquet", "out of date")):
        assert any(line.startswith(f"{path}: {what}") for line in lines), (path, verify.stdout)
    assert str(stray) not in "\n".join(line for line in lines if not line.startswith("note:"))

    table = cli("table", store)
    assert table.returncode == 0 and "Traceback" not in table.stderr, table.stderr
    assert "0 of 3 cases finished (0 failed, 3 missing)" in table.stdout

    rerun = cli(*_submit(store, scheduler=warm_scheduler))
    assert rerun.returncode == 0, rerun.stderr
    assert "(3 done, 0 failed this run)" in rerun.stdout and "moved 4 bad or superseded case files" in rerun.stdout
    log = (store / "rejected" / "rejected.log").read_text().splitlines()
    assert len(log) == 4 and all(" -> rejected/" in line for line in log)
    assert (store / "rejected" / files[first].name).stat().st_size == 100, "a rejected file is moved, not deleted"
    assert (store / "rejected" / "notes.txt").read_text() == "not a case"
    assert stray.exists(), "a verified case file outside the plan is kept"
    pd.testing.assert_frame_equal(results(store), results(reference), check_exact=True)
    assert cli("verify", store).returncode == 0


@pytest.mark.cluster
@pytest.mark.slow
def test_two_verified_files_of_one_case_count_once(reference, store, cli):
    """A case computed twice (a worker killed after its write, a task retried) has two verified files: the
    later write counts, once; a file none of whose cases count is superseded."""
    files = _case_files(store)
    first, second, _ = sorted(files)
    again = [{**row, "t_case_ms": 1.0} for row in pq.read_table(files[first]).to_pylist()]
    newer = write_case_rows(store / "cases", first, again, ok=True)
    failed = [{**row, "status": "failed", "error": "RuntimeError: test"} for row in pq.read_table(files[second]).to_pylist()]
    failed_path = write_case_rows(store / "cases", second, failed, ok=False)
    for path in (files[first], files[second]):
        os.utime(path, ns=(time.time_ns() + 10**9, time.time_ns() + 10**9))   # the write time counts, not mtime

    status = cli("status", store)
    assert f"{store}: 3 planned, 2 done, 1 failed, 0 missing" in status.stdout, status.stdout
    assert status.returncode == 1 and "estimator dimes: 1 failed rows" in status.stdout, status.stdout
    verify = cli("verify", store)
    assert f"note: {files[first]}: superseded: each of its cases is in a newer file" in verify.stdout, verify.stdout
    assert newer.exists() and failed_path.exists()
    results = CampaignStore(store).results()
    assert results["case_id"].is_unique and len(results) == 3
    assert results.set_index("case_id").at[second, "status"] == "failed"
    assert results.set_index("case_id").at[first, "status"] == "ok"


KILLED_WRITER = """
import sys, itertools
from pathlib import Path
from campaign.store.case_files import write_case_rows
from campaign.store.case_identity import StoreIdentity
from campaign.store.result_schema import CASE_FILE_SCHEMA
cases = Path(sys.argv[1])
identity = StoreIdentity("0" * 64, 1, ("dimes",))
for attempt in itertools.count():
    rows = [{**dict.fromkeys(CASE_FILE_SCHEMA.names), "case_id": 7, "campaign_seed": 1, "estimator": "dimes",
             "attempts": attempt, "error": "x" * (1000 + attempt % 5000)}]
    write_case_rows(cases, 7, rows, ok=attempt % 2 == 0, identity=identity)
    if attempt == 0:
        print("writing", flush=True)
"""


def test_a_writer_killed_at_any_instant_leaves_a_verified_file_or_an_ignored_one(tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    for delay_s in (0.003, 0.05, 0.13, 0.31):
        process = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(cases)], stdout=subprocess.PIPE,
                                   text=True, cwd=REPO, env=_environment())
        assert process.stdout.readline().strip() == "writing"
        time.sleep(delay_s)
        process.send_signal(signal.SIGKILL)
        process.wait()
        scan = scan_cases(cases, CaseIndex(tmp_path / "index"), StoreIdentity("0" * 64, 1, ("dimes",)))
        assert scan.bad == [], scan.bad
        assert scan.case_ids.tolist() == [7], "exactly one counted file for the case"
        for path in [scan.path_of(7), *(path for path, _ in scan.superseded)]:
            assert pq.read_table(path).column("case_id").to_pylist() == [7]


@pytest.mark.cluster
@pytest.mark.slow
def test_corrupt_or_edited_manifest_is_one_line(store, cli, warm_scheduler):
    (store / "manifest.json").write_text('{"config_hash": "abc", "seed": ')
    before = file_tree(store)
    for command in (["status", store], ["table", store], _submit(store, scheduler=warm_scheduler)):
        result = cli(*command)
        assert result.returncode == 2, (command, result.stdout, result.stderr)
        line = _one_line(result.stderr)
        assert f"{store / 'manifest.json'}: corrupt: not valid JSON" in line and "--fresh" in line
    verify = cli("verify", store)
    assert verify.returncode == 1 and f"{store / 'manifest.json'}: corrupt" in verify.stdout
    assert file_tree(store) == before


@pytest.mark.cluster
@pytest.mark.slow
def test_edited_manifest_and_corrupt_plan_and_results_are_detected(reference, store, cli, warm_scheduler):
    path = store / "manifest.json"
    manifest = json.loads(path.read_text())
    path.write_text(json.dumps({**manifest, "seed": 2}, indent=2))
    result = cli("status", store)
    assert result.returncode == 2 and "corrupted or edited" in _one_line(result.stderr)
    path.write_text(json.dumps(manifest, indent=2, sort_keys=True))

    _flip_byte(results_part(store), 200)
    table = cli("table", store)
    assert table.returncode == 0 and table.stdout == cli("table", reference).stdout.replace(str(reference), str(store))
    verify = cli("verify", store)
    assert verify.returncode == 1 and f"{store / 'results.parquet'}: corrupted" in verify.stdout

    _flip_byte(store / "plan.parquet", 100)
    status = cli("status", store)
    assert status.returncode == 2 and f"{store / 'plan.parquet'}: corrupted or replaced" in _one_line(status.stderr)
    rerun = cli(*_submit(store, scheduler=warm_scheduler))
    assert rerun.returncode == 0, rerun.stderr
    assert "written again from the configuration" in rerun.stdout and "(0 done, 0 failed this run)" in rerun.stdout
    assert cli("verify", store).returncode == 0
    pd.testing.assert_frame_equal(results(store), results(reference), check_exact=True)


def _site_with_seed(directory: Path, seed: int) -> Path:
    """The Gusev campaign with another seed (input paths made absolute so the file can live anywhere)."""
    return site_copy(directory, f"\n[campaign]\nseed = {seed}\n", name=f"gusev-seed{seed}.toml")


@pytest.mark.cluster
@pytest.mark.slow
def test_deleted_manifest_and_new_seed_never_mix_and_fresh_moves_the_store_aside(store, tmp_path, cli, warm_scheduler):
    (store / "manifest.json").unlink()
    old_tree = file_tree(store)
    site = _site_with_seed(tmp_path, 5)
    refused = cli(*_submit(store, site=site, scheduler=warm_scheduler))
    assert refused.returncode == 2 and "no manifest.json" in _one_line(refused.stderr)
    assert file_tree(store) == old_tree

    fresh = cli(*_submit(store, "--fresh", site=site, scheduler=warm_scheduler))
    assert fresh.returncode == 0, fresh.stderr
    previous = [p for p in tmp_path.iterdir() if p.name.startswith("store.previous-")]
    assert len(previous) == 1 and f"moved the previous store aside to {previous[0]}" in fresh.stdout
    assert file_tree(previous[0]) == old_tree, "the old store (examples included) is moved aside intact"
    assert "(3 done, 0 failed this run)" in fresh.stdout
    assert CampaignStore(store).manifest()["seed"] == 5
    assert not all_case_files(store) & all_case_files(previous[0])
    old_examples = {p.name: p.read_bytes() for p in (previous[0] / "examples").iterdir()}
    new_examples = {p.name: p.read_bytes() for p in (store / "examples").iterdir()}
    assert old_examples and all(new_examples.get(name) != data for name, data in old_examples.items())
    assert cli("verify", store).returncode == 0


@pytest.mark.cluster
@pytest.mark.slow
def test_fresh_checks_the_cluster_before_touching_the_store(store, tmp_path):
    # the same campaign ([execution] is not hashed), giving up on a scheduler after 2 s
    site = site_copy(tmp_path, "\n[execution]\nconnect_timeout_s = 2\n", name="site.toml")
    before = file_tree(tmp_path)
    result = _campaign(*_submit(store, "--fresh", "--scheduler", "tcp://127.0.0.1:9", site=site), timeout=120)
    assert result.returncode == 1 and "127.0.0.1:9" in _one_line(result.stderr), result.stderr
    after = file_tree(tmp_path)
    lock = after.pop("store.lock", None)     # released (no holder record), or removed when this run made it
    assert lock is None or lock[0] == 0, "the lock file beside the store is left released (no holder record)"
    before.pop("store.lock", None)
    assert after == before, "--fresh moved or changed the store although the cluster was unusable"


@pytest.mark.cluster
@pytest.mark.slow
def test_another_case_count_reuses_the_cases_in_both_plans(reference, store, cli, warm_scheduler):
    """Case identity is (class, index within class) and the configuration hash ignores case counts: a
    larger --cases-scale on the same store computes only the new cases, a smaller one runs nothing; the
    cases outside the current plan are kept and reported, not counted."""
    before = all_case_files(store)
    larger = cli(*_submit(store, scale="0.011", scheduler=warm_scheduler))   # gcp 2, gdcp 1, gkep 1
    assert larger.returncode == 0, larger.stderr
    assert "plan of 4 cases recorded (was 3)" in larger.stdout and "(1 done, 0 failed this run)" in larger.stdout
    assert before < all_case_files(store), "the three cases of both plans are reused"
    smaller = cli(*_submit(store, scheduler=warm_scheduler))
    assert smaller.returncode == 0 and "(0 done, 0 failed this run)" in smaller.stdout, smaller.stderr
    status = cli("status", store).stdout
    assert "3 planned, 3 done, 0 failed, 0 missing" in status and "1 case files of cases outside the plan" in status
    pd.testing.assert_frame_equal(results(store), results(reference), check_exact=True)
    assert cli("verify", store).returncode == 0


@pytest.mark.cluster
@pytest.mark.slow
def test_same_configuration_hash_with_a_differently_planned_case_is_refused(store):
    campaign = CampaignStore(store)
    manifest, plan = campaign.manifest(), campaign.plan()
    moved_id = int(plan["case_id"].iloc[1])
    moved = plan.assign(offset_east_m=plan["offset_east_m"] + (plan["case_id"] == moved_id) * 1.0)
    before = file_tree(store)
    with pytest.raises(StoreError) as refused:
        campaign.prepare(manifest, moved)
    message = str(refused.value)
    assert "\n" not in message and f"case {moved_id} has offset_east_m" in message
    assert file_tree(store) == before, "a refused plan is not recorded"
