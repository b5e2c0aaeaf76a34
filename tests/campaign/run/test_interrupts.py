"""Stop signals and full disks end a run the same way (issue 32): real `campaign` processes in their own
process group, real signals, a real full file system (a small tmpfs).

SIGINT (Ctrl-C), SIGTERM (`timeout`, cron, systemd, SLURM) and SIGHUP (a closed terminal) sent to the whole
process group after a few cases: exit 128 + signal, one stderr line naming the kept cases and the user's own
command line (re-quoted), no traceback and no "leaked semaphore" warning, no temporary file left in the
store, no process of the group left; running the printed command finishes the store. A full disk while
results.parquet is compacted is the machine's fault (exit 1, the file and the fix), as during a case write.
"""
from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from campaign.run.interrupts import program_words, resume_command
from campaign.store.campaign_store import CampaignStore
from service_campaigns import GUSEV, campaign_file, project_environment, run_campaign, stderr_line

HINT = re.compile(r"`([^`]+)` again (?:computes the missing ones|runs the rest)")


def _group_processes(group: int) -> list[int]:
    """Live processes of process group ``group`` (zombies excluded)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == group and fields[0] != "Z":
                found.append(int(entry.name))
    return found


def _interrupt(argv: list[str], stores: Path, pattern: str, count: int, number: int, cwd: Path):
    """Run ``argv`` in its own process group until ``count`` files match ``stores.glob(pattern)``, send
    signal ``number`` to the group, and return (exit code, stderr, processes of the group still alive 30 s
    after it ended, seconds from the signal to the exit)."""
    # SIGHUP as a terminal would deliver it: the default disposition even when this test runs under nohup (a
    # command started with SIGHUP ignored keeps ignoring it, as nohup promises: campaign.run.interrupts)
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=cwd,
                               env=project_environment(), start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL))
    deadline = time.monotonic() + 300
    while len(list(stores.glob(pattern))) < count:
        assert process.poll() is None, f"ended early ({process.returncode}): {process.stderr.read()}"
        assert time.monotonic() < deadline, "no case files within 300 s"
        time.sleep(0.1)
    signalled = time.monotonic()
    os.killpg(process.pid, number)
    try:
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    seconds = time.monotonic() - signalled
    deadline = time.monotonic() + 30
    while _group_processes(process.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return process.returncode, err, _group_processes(process.pid), seconds


def _assert_one_clean_line(err: str, number: int, argv: list[str]) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and "leaked" not in err and "resource_tracker" not in err, err
    line = lines[0]
    label = "" if number == signal.SIGINT else f" ({signal.Signals(number).name})"
    assert line.startswith(f"campaign: interrupted{label}; "), line
    hint = HINT.search(line)
    assert hint is not None, line
    assert hint.group(1) == shlex.join(argv), (hint.group(1), argv)       # the user's own command line
    return hint.group(1)


@pytest.mark.cluster
@pytest.mark.slow
@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=lambda n: signal.Signals(n).name)
def test_every_stop_signal_ends_a_submit_the_same_way_and_its_printed_command_resumes(tmp_path, number):
    """Slow by design (over 60 s each in a loaded suite run): a `campaign submit` process with its own embedded
    cluster is stopped by the signal mid-run, then its printed command resumes it; the signal to the process
    group and the stop of its own workers are what is tested."""
    # 12 cases of one case per task: when the second batch file appears 10 are still to run (over a second even on
    # an idle machine, against the 0.1 s the signal waits), so the signal always lands in the middle of the run
    path = campaign_file(tmp_path, {"gcp": 8, "gdcp": 4, "gkep": 0}, "cases_per_task = 1",
                         name="my campaign.toml")   # a space in the name: quoting
    out = tmp_path / "store"
    argv = [sys.executable, "-m", "campaign.cli", "submit", str(path), "--cases-scale", "1", "--workers", "1",
            "--no-progress", "--output", str(out)]
    code, err, left, seconds = _interrupt(argv, out, "cases/??/batch-*.parquet", 2, number, tmp_path)
    assert code == 128 + number, err
    hint = _assert_one_clean_line(err, number, argv)
    kept = sorted((out / "cases").glob("??/batch-*.parquet"))
    assert f"; {len(kept)} finished case files kept in {out} " in err
    assert list(out.rglob(".tmp*")) == []                                 # cases/ and examples/
    assert left == [], f"processes of the submit still alive: {left}"      # workers and nannies stopped
    status = CampaignStore(out).status()
    assert 2 <= status.done < 12 and status.failed == 0, status

    resumed = subprocess.run(shlex.split(hint), capture_output=True, text=True, cwd=tmp_path, timeout=600,
                             env=project_environment())
    assert resumed.returncode == 0, resumed.stderr
    assert f"({12 - status.done} done, 0 failed this run)" in resumed.stdout
    final = CampaignStore(out).status()
    assert (final.done, final.missing, final.failed) == (12, 0, 0)
    assert {path.name for path in kept} <= {path.name for path in (out / "cases").glob("??/batch-*.parquet")}
    print(f"{signal.Signals(number).name}: exit {code} {seconds:.1f} s after the signal, {len(kept)} cases kept")


@pytest.mark.cluster
@pytest.mark.slow
def test_sigterm_ends_a_sweep_in_one_line_and_its_printed_command_resumes(tmp_path):
    """Slow by design (over 60 s in a loaded suite run): a `campaign sweep` process with its own embedded
    cluster is stopped by SIGTERM, then its printed command resumes it; the stopped process and cluster are what
    is tested."""
    sweep = tmp_path / "nightly.toml"
    sweep.write_text(f'[sweep]\nbase = "{GUSEV}"\n[sweep.cases]\ngcp = 2\ngdcp = 1\ngkep = 0\n'
                     '[axes]\n"sensors.attitude_random_sigma_deg" = [0.01, 0.02]\n')
    out = tmp_path / "sweep out"
    argv = [sys.executable, "-m", "campaign.cli", "sweep", str(sweep), "--workers", "1", "--no-progress",
            "--output", str(out)]
    code, err, left, _ = _interrupt(argv, out, "points/*/cases/??/batch-*.parquet", 2, signal.SIGTERM, tmp_path)
    assert code == 128 + signal.SIGTERM, err
    hint = _assert_one_clean_line(err, signal.SIGTERM, argv)
    assert list(out.rglob(".tmp*")) == []
    assert left == [], f"processes of the sweep still alive: {left}"
    resumed = subprocess.run(shlex.split(hint), capture_output=True, text=True, cwd=tmp_path, timeout=600,
                             env=project_environment())
    assert resumed.returncode == 0, resumed.stderr
    stores = [manifest.parent for manifest in out.glob("points/*/manifest.json")]
    assert len(stores) == 2
    for store in stores:
        status = CampaignStore(store).status()
        assert (status.done, status.missing, status.failed) == (3, 0, 0), store


def test_the_resume_command_is_the_program_as_the_user_started_it(tmp_path, monkeypatch):
    """Module run (`python -m campaign.cli`, interpreter and options as typed), an installed command found on
    PATH (its bare name), one given by path (as given), and main() called with a list (`campaign` + the list)."""
    module = ["python3", "-X", "dev", "-m", "campaign.cli", "submit", "a b.toml", "--output", "x"]
    assert program_words(["/repo/campaign/cli.py", "submit", "a b.toml", "--output", "x"], module) == \
        ["python3", "-X", "dev", "-m", "campaign.cli"]
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = bin_dir / "campaign"
    script.write_text("#!/bin/sh\n")
    script.chmod(0o755)
    monkeypatch.setenv("PATH", str(bin_dir))
    assert program_words([str(script), "status", "d"], ["/usr/bin/python3", str(script), "status", "d"]) == ["campaign"]
    elsewhere = tmp_path / "venv" / "campaign"
    elsewhere.parent.mkdir()
    elsewhere.write_text("#!/bin/sh\n")
    assert program_words([str(elsewhere), "status", "d"], ["python", str(elsewhere), "status", "d"]) == [str(elsewhere)]
    assert resume_command(["submit", "my file.toml", "--cases-scale", "0.3"]) == \
        "campaign submit 'my file.toml' --cases-scale 0.3"


@pytest.fixture()
def small_tmpfs(tmp_path):
    """A 4 MiB tmpfs: a real file system that can be filled (needs root and mount permission)."""
    mount_point = tmp_path / "disk"
    mount_point.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mount_point)],
                             capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root with mount permission): {mounted.stderr.strip()}")
    yield mount_point
    subprocess.run(["umount", "-l", str(mount_point)], check=False)


def _fill(directory: Path, leave_bytes: int = 0) -> Path:
    """Fill the file system of ``directory`` with one file, to its last byte but ``leave_bytes``; return it."""
    filler = directory / "filler"
    with open(filler, "wb", buffering=0) as handle:
        try:
            while True:
                handle.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.strerror == "No space left on device", exc
    os.truncate(filler, max(0, filler.stat().st_size - leave_bytes))
    return filler


@pytest.mark.cluster
@pytest.mark.slow
def test_full_disk_at_the_lock_or_while_compacting_results_is_an_infrastructure_stop_naming_the_file(
        tmp_path, small_tmpfs):
    """Slow by design (over 60 s in a loaded suite run): four `campaign submit` processes, with their own
    embedded cluster, on a real small tmpfs filled at the lock and while the results are compacted; the stop of
    a whole run (process and cluster) on a full disk is what is tested, so neither can be shared away."""
    path = campaign_file(tmp_path, {"gcp": 2, "gdcp": 1, "gkep": 0}, "workers = 1")
    out = small_tmpfs / "store"
    first = run_campaign("submit", path, "--output", out, "--no-progress")
    assert first.returncode == 0, first.stderr
    for name in ("results.parquet", "results.json", "timings.parquet"):   # parts directories, or older files
        shutil.rmtree(out / name) if (out / name).is_dir() else (out / name).unlink()   # only the compaction is left

    filler = _fill(small_tmpfs)                   # not a byte left: the lock's holder record cannot be written
    locked = run_campaign("submit", path, "--output", out, "--no-progress")
    assert locked.returncode == 1, locked.stdout + locked.stderr      # the machine's fault, not bad input (2)
    line = stderr_line(locked)
    assert "No space left on device" in line and f"{out}.lock" in line and "free space there" in line, line

    filler.unlink()
    filler = _fill(small_tmpfs, leave_bytes=4096)  # one page: the lock record fits, results.parquet does not
    compacting = run_campaign("submit", path, "--output", out, "--no-progress")
    assert compacting.returncode == 1, compacting.stdout + compacting.stderr
    line = stderr_line(compacting)
    assert "No space left on device" in line and str(out / "results.parquet") in line, line
    assert "free space there" in line and "next submit compacts them" in line, line
    assert list(out.rglob(".tmp-*")) == []

    filler.unlink()
    fixed = run_campaign("submit", path, "--output", out, "--no-progress")
    assert fixed.returncode == 0, fixed.stderr
    assert (out / "results.parquet").exists() and "(0 done, 0 failed this run)" in fixed.stdout
