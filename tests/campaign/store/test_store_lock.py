"""One writer per campaign store (issue 16, store integrity): the lock beside the store, with real processes.

The holder is a real process holding the real ``flock`` (a small Python process using
:class:`campaign.store.lock.StoreLock`, or a real ``campaign submit``); the other side is the
``campaign`` CLI on a real dask LocalCluster (the test process's warm one, ``warm_scheduler`` in
tests/conftest.py): a subprocess where it waits or races, else ``campaign.cli.main``
in this process with its file descriptors captured (``service_campaigns.campaign_in_process``; the lock is
a ``flock`` of another open file description, refused as between processes).
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from campaign.store.campaign_store import CampaignStore
from service_campaigns import campaign_in_process, file_tree, project_environment, site_copy, start_lock_holders

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[3]
SITE = REPO / "sitedata" / "gusev.toml"
SCALE = "0.005"   # gcp 1, gdcp 1, gkep 1 case
def _popen_campaign(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "campaign.cli", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, env=project_environment(), start_new_session=True)


def _submit(out: Path, *extra, site: Path = SITE, scheduler: str) -> list:
    """``campaign submit`` of ``site`` into ``out`` on the cluster at ``scheduler`` (the test process's warm one,
    ``warm_scheduler`` in tests/conftest.py: the lock is what is tested, not the cluster's start-up)."""
    return ["submit", site, "--output", out, "--cases-scale", SCALE, "--scheduler", scheduler, "--no-progress", *extra]


def _site_with_seed(directory: Path, seed: int) -> Path:
    """The Gusev campaign with another seed (input paths made absolute so the file can live anywhere)."""
    return site_copy(directory, f"\n[campaign]\nseed = {seed}\n", name=f"gusev-seed{seed}.toml")


@pytest.fixture()
def holder():
    """Start a process holding a store's lock: ``holder(store_dir) -> Popen`` (killed at the end)."""
    yield from start_lock_holders()


def test_second_writer_is_told_who_holds_the_lock_and_wait_takes_over_a_killed_holder(tmp_path, holder, capfd,
                                                                                       warm_scheduler):
    out = tmp_path / "store"
    process = holder(out)
    record = json.loads((tmp_path / "store.lock").read_text())
    assert record["pid"] == process.pid and record["host"] == socket.gethostname()
    assert "StoreLock" in record["command"] and record["started"].endswith("Z")

    refused = campaign_in_process(capfd, *_submit(out, scheduler=warm_scheduler))
    assert refused.returncode == 1, refused.stdout + refused.stderr
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in refused.stderr, refused.stderr
    assert f"pid {process.pid} on {socket.gethostname()}" in lines[0] and "--wait" in lines[0]
    assert not out.exists(), "a refused writer must not create the store"

    waiting = _popen_campaign(*_submit(out, "--wait", scheduler=warm_scheduler))
    try:
        first_line = waiting.stderr.readline()
        assert "waiting for the lock held by" in first_line and f"pid {process.pid}" in first_line
        time.sleep(1.0)
        assert waiting.poll() is None and not out.exists(), "the waiting writer went ahead while the lock was held"
        os.killpg(process.pid, signal.SIGKILL)        # the holder dies: the kernel frees its flock
        stdout, stderr = waiting.communicate(timeout=300)
    finally:
        if waiting.poll() is None:
            os.killpg(waiting.pid, signal.SIGKILL)
    assert waiting.returncode == 0, stderr
    assert "(3 done, 0 failed this run)" in stdout
    status = CampaignStore(out).status()
    assert (status.planned, status.done + status.failed) == (3, 3)
    assert (tmp_path / "store.lock").read_text() == "", "a released lock keeps no holder record"


def test_fresh_while_another_writer_holds_the_lock_changes_nothing(tmp_path, holder, capfd, warm_scheduler):
    out = tmp_path / "store"
    (out / "cases").mkdir(parents=True)
    (out / "cases" / "case-000000.ok.parquet").write_bytes(b"results of a running campaign")
    (out / "examples").mkdir()
    (out / "examples" / "gcp-case000000-image1.png").write_bytes(b"png")
    holder(out)
    before = file_tree(tmp_path)
    result = campaign_in_process(capfd, *_submit(out, "--fresh", scheduler=warm_scheduler))
    assert result.returncode == 1 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "another writer holds its lock" in result.stderr
    assert file_tree(tmp_path) == before, "--fresh changed something while another writer held the lock"


def test_two_submits_of_different_configurations_at_once_accept_one(tmp_path, capfd, warm_scheduler):
    """The prepare race: both start together on an empty store; the lock serialises them and the second,
    once it has the lock, finds the first's configuration and is refused (exit 2). Never two configs."""
    out = tmp_path / "store"
    sites = [_site_with_seed(tmp_path, seed) for seed in (11, 12)]
    processes = [_popen_campaign(*_submit(out, "--wait", site=site, scheduler=warm_scheduler)) for site in sites]
    results = [(process.wait(timeout=300), *process.communicate()) for process in processes]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    winner = sites[[code for code, _, _ in results].index(0)]
    loser_err = [err for code, _, err in results if code == 2][0]
    assert "another configuration" in loser_err and len(loser_err.strip().splitlines()) <= 2, loser_err
    store = CampaignStore(out)
    assert store.manifest()["seed"] == int(winner.stem.removeprefix("gusev-seed"))
    verify = campaign_in_process(capfd, "verify", out)
    assert verify.returncode == 0, verify.stdout
    results_seed = set(store.results()["case_id"])
    assert results_seed == set(store.plan()["case_id"])


def test_sweep_takes_the_lock_of_each_point_store(tmp_path, holder, capfd, warm_scheduler):
    from campaign.configuration.sweep_file import load_sweep

    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nbase = "{SITE}"\n[sweep.cases]\ngcp = 1\ngdcp = 0\ngkep = 0\n'
                     '[axes]\n"sensors.attitude_random_sigma_deg" = [0.05, 0.1]\n')
    out = tmp_path / "sweep-out"
    points = load_sweep(sweep, output_dir=out).points
    process = holder(points[1].config.output_dir)
    before = {path: stat for path, stat in file_tree(out).items()        # the point stores (sweep.json, the
              if path.startswith("points") and not path.endswith(".lock")}  # sweep's own record, may be written)
    result = campaign_in_process(capfd, "sweep", sweep, "--output", out, "--scheduler", warm_scheduler, "--no-progress")
    assert result.returncode == 1, result.stdout + result.stderr
    line = result.stderr.strip()
    assert len(line.splitlines()) == 1 and str(points[1].config.output_dir) in line and f"pid {process.pid}" in line
    after = {path: stat for path, stat in file_tree(out).items()
             if path.startswith("points") and not path.endswith(".lock")}
    assert after == before, "the sweep wrote a point store while it was locked by another writer"
