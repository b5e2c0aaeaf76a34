"""A store that knows what belongs in it: every case file records its identity (configuration hash, case id,
seed, estimators, result-schema version) in its Parquet metadata, and the store counts it only where that
identity is the store's; the writer's lock survives the deletion of ``DIR.lock``; a read-only store can
be inspected.

Real parts: the ``campaign`` CLI on a real dask LocalCluster (the test process's warm one, ``warm_scheduler`` in
tests/conftest.py; a subprocess for the two campaigns, then
``campaign.cli.main`` in this process with its file descriptors captured, see
``service_campaigns.campaign_in_process``), two real campaigns with different seeds, real Parquet files, a
real second process holding the lock, a real read-only bind mount.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from store_files import case_files as _case_files
from store_files import place as _place
from store_files import results

from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import (
    BATCH_FILE,
    case_file_name,
    sha256_bytes,
    table_bytes,
    write_case_rows,
)
from campaign.store.case_identity import BATCH_IDENTITY_KEY, IDENTITY_KEY, StoreIdentity
from campaign.store.case_index import CaseIndex, scan_cases
from campaign.store.lock import StoreBusy, StoreLock
from campaign.store.result_schema import CASE_FILE_SCHEMA, RESULT_SCHEMA_VERSION, ResultSchemaError, rows_table
from service_campaigns import campaign_in_process, file_tree, project_environment, site_copy, start_lock_holders

REPO = Path(__file__).resolve().parents[3]
SCALE = "0.005"               # gcp 1, gdcp 1, gkep 1 case
SEED, OTHER_SEED = 5, 8
HASH = "a" * 64
def _campaign(*args, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "campaign.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO, env=project_environment())


def _submit(site: Path, out: Path, scheduler: str) -> list:
    """``campaign submit`` of ``site`` into ``out`` on the cluster at ``scheduler`` (the test process's warm one,
    ``warm_scheduler`` in tests/conftest.py: what is tested here is the store, not the cluster's start-up)."""
    return ["submit", site, "--output", out, "--cases-scale", SCALE, "--scheduler", scheduler, "--no-progress"]


def _rows(case_id: int, seed: int, estimators=("dimes", "yes_man")) -> list[dict]:
    return [{**dict.fromkeys(CASE_FILE_SCHEMA.names), "case_id": case_id, "campaign_seed": seed, "estimator": name}
            for name in estimators]


def _recorded(cases: Path, case_id: int, table: pa.Table) -> Path:
    data = table_bytes(table)
    path = cases / case_file_name(case_id, True, len(data), sha256_bytes(data))
    path.write_bytes(data)
    return path


def test_only_files_whose_recorded_identity_and_rows_are_the_stores_are_counted(tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    store = StoreIdentity(HASH, SEED, ("dimes", "yes_man"))
    good = write_case_rows(cases, 7, _rows(7, SEED), ok=True, identity=store)
    record = json.loads(pq.read_schema(good).metadata[BATCH_IDENTITY_KEY])
    assert record.pop("written_ns") > 0 and record == {
        "config_hash": HASH, "case_ids": [7], "states": ["ok"], "campaign_seed": SEED,
        "estimators": ["dimes", "yes_man"], "result_schema_version": RESULT_SCHEMA_VERSION}
    other_seed = write_case_rows(cases, 11, _rows(11, OTHER_SEED), ok=True,
                                 identity=StoreIdentity(HASH, OTHER_SEED, ("dimes", "yes_man")))
    other_hash = write_case_rows(cases, 12, _rows(12, SEED), ok=True,
                                 identity=StoreIdentity("b" * 64, SEED, ("dimes", "yes_man")))
    other_estimators = write_case_rows(cases, 13, _rows(13, SEED, ("dimes",)), ok=True,
                                       identity=StoreIdentity(HASH, SEED, ("dimes",)))
    newer_schema = write_case_rows(cases, 14, _rows(14, SEED), ok=True, identity=StoreIdentity(
        HASH, SEED, ("dimes", "yes_man"), result_schema_version=RESULT_SCHEMA_VERSION + 1))
    unrecorded = _recorded(cases, 15, rows_table(_rows(15, SEED)))          # written before identities
    renamed = good.with_name(good.name.replace("batch-000007-1.", "batch-000016-1."))
    renamed.write_bytes(good.read_bytes())                                   # case 7's batch named case 16's
    lying = _recorded(cases, 17, rows_table(_rows(17, OTHER_SEED)).replace_schema_metadata(
        {IDENTITY_KEY: json.dumps(store.record(17)).encode()}))              # record says seed 5, rows say 8
    old_good = _recorded(cases, 19, rows_table(_rows(19, SEED)).replace_schema_metadata(
        {IDENTITY_KEY: json.dumps(store.record(19)).encode()}))              # an older store's one-case file

    scan = scan_cases(cases, CaseIndex(tmp_path / "index"), store)
    assert scan.case_ids.tolist() == [7, 19] and scan.path_of(7) == good and scan.path_of(19) == old_good
    reasons = dict(scan.bad)
    assert set(reasons) == {other_seed, other_hash, other_estimators, newer_schema, unrecorded, renamed, lying}
    assert all(reason.startswith("foreign: ") for reason in reasons.values()), reasons
    assert f"campaign_seed {OTHER_SEED} (this store: {SEED})" in reasons[other_seed]
    assert "config_hash bbbbbbbbbbbb (this store: aaaaaaaaaaaa)" in reasons[other_hash]
    assert 'estimators ["dimes"] (this store: ["dimes", "yes_man"])' in reasons[other_estimators]
    assert f"result_schema_version {RESULT_SCHEMA_VERSION + 1} (this store: {RESULT_SCHEMA_VERSION})" in reasons[newer_schema]
    assert "no identity record" in reasons[unrecorded]
    assert "its name says 1 cases from case 000016, its identity record 1 from case 7" in reasons[renamed]
    assert f"rows have campaign_seed [{OTHER_SEED}]" in reasons[lying]

    with pytest.raises(ResultSchemaError, match="campaign_seed"):        # a writer cannot mislabel its rows
        write_case_rows(cases, 18, _rows(18, OTHER_SEED), ok=True, identity=store)
    assert not list(cases.rglob("*000018*"))


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory, warm_scheduler) -> tuple[Path, Path]:
    """Two finished stores of the same campaign but for the seed (SEED, OTHER_SEED), 3 cases each."""
    root = tmp_path_factory.mktemp("identity")
    stores = []
    for seed in (SEED, OTHER_SEED):
        site = site_copy(root, f"\n[campaign]\nseed = {seed}\n", name=f"gusev-seed{seed}.toml")
        result = _campaign(*_submit(site, root / f"seed{seed}", warm_scheduler))
        assert result.returncode == 0, result.stdout + result.stderr
        stores.append(root / f"seed{seed}")
    return stores[0], stores[1]


@pytest.fixture()
def cli(capfd):
    """``cli(*args)``: the ``campaign`` command in this process (``service_campaigns.campaign_in_process``)."""
    return lambda *args: campaign_in_process(capfd, *args)


def _site(store: Path) -> Path:
    return Path(json.loads((store / "manifest.json").read_text())["config_file"])


@pytest.mark.cluster
@pytest.mark.slow
def test_a_case_file_of_another_seed_is_rejected_by_verify_and_by_submit(campaigns, tmp_path, cli, warm_scheduler):
    reference, other = campaigns
    store = tmp_path / "store"
    shutil.copytree(reference, store)
    case_id = min(_case_files(other))
    stranger = _case_files(other)[case_id]
    placed = _place(store, case_id, stranger.read_bytes())
    assert BATCH_FILE.match(placed.name).group(4) == sha256_bytes(placed.read_bytes()), "its name verifies it"

    status = cli("status", store)
    assert status.returncode == 0 and f"{store}: 3 planned, 2 done, 0 failed, 1 missing" in status.stdout, status.stdout
    assert "1 bad case files not counted, 1 of them foreign" in status.stdout
    verify = cli("verify", store)
    assert verify.returncode == 1 and "Traceback" not in verify.stderr
    named = [line for line in verify.stdout.splitlines() if line.startswith(f"{placed}: foreign: ")]
    assert len(named) == 1 and f"campaign_seed {OTHER_SEED} (this store: {SEED})" in named[0], verify.stdout

    rerun = cli(*_submit(_site(reference), store, warm_scheduler))
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    assert "(1 done, 0 failed this run)" in rerun.stdout and "moved 1 bad or superseded case files" in rerun.stdout
    assert (store / "rejected" / placed.name).read_bytes() == stranger.read_bytes(), "moved aside, not deleted"
    log = (store / "rejected" / "rejected.log").read_text().splitlines()
    assert len(log) == 1 and f"cases/{placed.parent.name}/{placed.name} -> rejected/{placed.name}: foreign: " in log[0]
    assert set(results(store)["campaign_seed"]) == {SEED}
    pd.testing.assert_frame_equal(results(store), results(reference), check_exact=True)
    assert cli("verify", store).returncode == 0
    assert "1 files rejected earlier" in cli("status", store).stdout


@pytest.mark.cluster
@pytest.mark.slow
def test_a_foreign_schema_and_a_file_without_identity_are_rejected_without_a_traceback(campaigns, tmp_path, cli,
                                                                                       warm_scheduler):
    reference, _ = campaigns
    store = tmp_path / "store"
    shutil.copytree(reference, store)
    first, second, _ = sorted(_case_files(store))
    foreign_schema = _place(store, first, table_bytes(pa.table({"speed": [1.0, 2.0], "label": ["a", "b"]})))
    old = pq.read_table(_case_files(store)[second])
    unrecorded = _place(store, second, table_bytes(old.replace_schema_metadata(None)))   # a pre-identity file
    kept = {path.name: path.read_bytes() for path in (foreign_schema, unrecorded)}

    for command in ("status", "verify", "table"):
        result = cli(command, store)
        assert "Traceback" not in result.stdout + result.stderr, result.stderr
        assert result.returncode == (1 if command == "verify" else 0), result.stdout + result.stderr
        if command == "verify":
            lines = result.stdout.splitlines()
            assert any(line.startswith(f"{foreign_schema}: does not fit the result schema") for line in lines)
            assert any(line.startswith(f"{unrecorded}: foreign: no identity record") for line in lines)
        if command == "table":
            assert "1 of 3 cases finished (0 failed, 2 missing)" in result.stdout

    rerun = cli(*_submit(_site(reference), store, warm_scheduler))
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    assert "(2 done, 0 failed this run)" in rerun.stdout
    assert {name: (store / "rejected" / name).read_bytes() for name in kept} == kept, "nothing lost"
    pd.testing.assert_frame_equal(results(store), results(reference), check_exact=True)


@pytest.fixture()
def holder():
    """Start a process holding a store's lock: ``holder(store_dir) -> Popen`` (killed at the end)."""
    yield from start_lock_holders()


@pytest.mark.cluster
@pytest.mark.slow
def test_deleting_the_lock_file_does_not_let_a_second_writer_in(campaigns, tmp_path, holder, cli, warm_scheduler):
    reference, _ = campaigns
    store = tmp_path / "store"
    shutil.copytree(reference, store)
    _case_files(store)[min(_case_files(store))].unlink()        # a case for a second writer to compute
    process = holder(store)
    (tmp_path / "store.lock").unlink()                           # the bypass: remove the lock file
    before = file_tree(store)
    refused = cli(*_submit(_site(reference), store, warm_scheduler))
    assert refused.returncode == 1, refused.stdout + refused.stderr
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in refused.stderr, refused.stderr
    assert f"pid {process.pid}" in lines[0] and "removed or replaced" in lines[0] and "--wait" in lines[0]
    assert file_tree(store) == before, "the refused writer changed the store"

    os.killpg(process.pid, signal.SIGKILL)                      # the holder dies: the kernel frees both locks
    process.wait()
    with StoreLock(store):
        pass


def test_the_directory_lock_follows_a_fresh_store_and_a_new_one(tmp_path):
    """prepare() locks the directory it creates (a new store, or the new one after --fresh) before writing."""
    out = tmp_path / "store"
    plan = pd.DataFrame({"case_id": [0, 1]})
    manifest = {"config_hash": HASH, "seed": SEED, "estimators": ["dimes"], "cases_per_class": {"gcp": 2}}
    for fresh in (False, True):                  # first a new store, then --fresh moves it aside
        store = CampaignStore(out)
        with store.lock():
            store.prepare(manifest, plan, fresh=fresh)
            (tmp_path / "store.lock").unlink()
            with pytest.raises(StoreBusy, match=f"pid {os.getpid()}.*removed or replaced"):
                StoreLock(out).acquire()          # another open file description: flock conflicts as between processes
        assert CampaignStore(out).manifest()["config_hash"] == HASH
    assert len(list(tmp_path.glob("store.previous-*"))) == 1


@pytest.mark.cluster
@pytest.mark.slow
def test_status_verify_and_table_work_on_a_read_only_store(campaigns, tmp_path, cli):
    reference, _ = campaigns
    copy, mounted = tmp_path / "copy", tmp_path / "mounted"
    shutil.copytree(reference, copy)
    mounted.mkdir()
    mount = subprocess.run(["mount", "--bind", "-o", "ro", str(copy), str(mounted)], capture_output=True, text=True)
    if mount.returncode != 0:
        pytest.skip(f"no read-only bind mount here (needs root and mount rights): {mount.stderr.strip()}")
    try:
        with pytest.raises(OSError):
            (mounted / "probe").write_text("x")               # writes really fail (root ignores chmod, not ro mounts)
        before = file_tree(copy)
        status = cli("status", mounted)
        assert status.returncode == 0 and f"{mounted}: 3 planned, 3 done, 0 failed, 0 missing" in status.stdout
        verify = cli("verify", mounted)
        assert verify.returncode == 0 and "clean" in verify.stdout, verify.stdout + verify.stderr
        table = cli("table", mounted)
        assert table.returncode == 0 and "Traceback" not in table.stderr, table.stderr
        assert "3 of 3 cases finished" in table.stdout and "table.md and table.csv not written" in table.stdout
        assert file_tree(copy) == before
    finally:
        subprocess.run(["umount", str(mounted)], check=True)
