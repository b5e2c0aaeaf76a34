"""No traceback, ever, from any `campaign` command: generated bad paths (input files, output directories,
store directories), TOML nested beyond any schema, huge declared sizes, corrupt store and baseline files,
scheduler addresses without host:port, an interrupted submit (SIGINT to the whole process group, as Ctrl-C
sends it) and a closed stdout. Each answer is one line on stderr with a documented exit code (2 bad input, 1
store problems, 130 interrupted, 141 closed pipe). Real files, FIFOs, sockets, devices, /proc/sys and real
processes; anything that could block (a FIFO opened by mistake) runs as a subprocess with a timeout."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from campaign.cli import main as campaign_main
from fuzz_inputs import (
    Outcome,
    bad_input_paths,
    bad_output_dirs,
    corrupt_file_variants,
    deep_toml_texts,
    no_traceback_problems,
    refusal_problems,
    run_main,
    snapshot,
)

REPO = Path(__file__).resolve().parents[2]
GUSEV = REPO / "sitedata" / "gusev.toml"
SWEEP = REPO / "sitedata" / "sweeps" / "nightly.toml"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
BLOCKING = ("FIFO", "device /dev/zero")      # classes that hang if opened: subprocesses with a timeout


def _campaign(argv: list, cwd: Path, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "campaign.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env=ENV)


def _outcome(argv: list, cwd: Path, blocking: bool) -> Outcome:
    """The command in-process, or as a subprocess with a timeout when a mistake would block (a FIFO opened)."""
    if not blocking:
        return run_main(campaign_main, argv, cwd)
    result = _campaign(argv, cwd, timeout=60)
    return Outcome(result.returncode, result.stdout, result.stderr)


def _site_file(tmp_path: Path, **replace: str) -> Path:
    """gusev.toml with absolute camera/trajectory paths and the given text replacements."""
    text = GUSEV.read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    text = text.replace('"cameras/', f'"{REPO}/sitedata/cameras/').replace('"trajectories/', f'"{REPO}/sitedata/trajectories/')
    path = tmp_path / "campaign.toml"
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------ bad paths
INPUT_COMMANDS = [["submit", "{}", "--no-progress"], ["plan", "{}"], ["sweep", "{}", "--no-progress"], ["camera", "{}"],
                  ["compare-flight", "{}"]]


@pytest.mark.slow
def test_every_bad_input_path_of_every_command_is_one_line_exit_2(tmp_path):
    tried = 0
    for name, path in bad_input_paths(tmp_path / "inputs"):
        for command in INPUT_COMMANDS:
            argv = [str(path) if item == "{}" else item for item in command]
            before = snapshot(tmp_path)
            outcome = _outcome(argv, tmp_path, name in BLOCKING)
            assert not refusal_problems(outcome, before, snapshot(tmp_path)), (name, argv, outcome)
            tried += 1
    assert tried == 12 * len(INPUT_COMMANDS)


@pytest.mark.parametrize("command", [["submit", GUSEV, "--no-progress", "--output"], ["plan", GUSEV, "--out"],
                                     ["sweep", SWEEP, "--no-progress", "--output"]])
def test_every_bad_output_directory_is_refused_before_anything_is_written(tmp_path, command):
    for name, path in bad_output_dirs(tmp_path / "outputs"):
        before = snapshot(tmp_path)
        outcome = run_main(campaign_main, [*command, path], tmp_path)
        assert not refusal_problems(outcome, before, snapshot(tmp_path)), (name, outcome)
        if name == "empty":
            assert "is empty" in outcome.err


@pytest.mark.parametrize("command", ["status", "table", "verify", "report"])
def test_every_bad_store_directory_is_one_line(tmp_path, command):
    for name, path in bad_output_dirs(tmp_path / "stores"):
        before = snapshot(tmp_path)
        outcome = run_main(campaign_main, [command, path], tmp_path)
        assert not refusal_problems(outcome, before, snapshot(tmp_path)), (name, outcome)


@pytest.fixture()
def read_only_dir(tmp_path):
    """A read-only bind mount of an empty directory (root can write through chmod 000, not through this)."""
    source, mount = tmp_path / "ro-source", tmp_path / "ro"
    source.mkdir()
    mount.mkdir()
    done = subprocess.run(["mount", "--bind", str(source), str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot bind-mount here: {done.stderr.decode().strip()}")
    try:
        subprocess.run(["mount", "-o", "remount,bind,ro", str(mount)], check=True, capture_output=True)
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)


def test_a_read_only_file_system_is_refused_as_output(tmp_path, read_only_dir):
    with pytest.raises(OSError):
        (read_only_dir / "probe").write_text("x")            # the mount really is read-only, even for root
    for argv in (["submit", GUSEV, "--no-progress", "--output", read_only_dir / "store"],
                 ["plan", GUSEV, "--out", read_only_dir], ["sweep", SWEEP, "--output", read_only_dir / "s"]):
        before = snapshot(tmp_path)
        outcome = run_main(campaign_main, argv, tmp_path)
        assert not refusal_problems(outcome, before, snapshot(tmp_path)), outcome
        assert "read-only or not writable" in outcome.err


@pytest.mark.slow
@pytest.mark.parametrize("field, replace", [
    ("site.trajectory_set", {'"trajectories/gusev.parquet"': '"{fifo}"'}),
    ("site.classes[0].terrain.path", {'{ kind = "synthetic", preset = "gcp", seed = 4101 }': '{ kind = "file", path = "{fifo}" }'}),
])
def test_a_fifo_or_device_as_trajectory_or_terrain_is_refused_without_opening_it(tmp_path, field, replace):
    fifo = tmp_path / "input.fifo"
    os.mkfifo(fifo)
    for target in (fifo, "/dev/zero"):
        path = _site_file(tmp_path, **{old: new.replace("{fifo}", str(target)) for old, new in replace.items()})
        result = _campaign(["plan", path, "--out", tmp_path / "maps"], tmp_path, timeout=60)  # a hang = a failure
        assert result.returncode == 2 and result.stdout == "", result
        assert result.stderr.count("\n") == 1 and field in result.stderr and "allowed: a regular file" in result.stderr
        assert not (tmp_path / "maps").exists()


# ------------------------------------------------------------------------------------------ TOML structure
def test_toml_nested_beyond_any_schema_is_one_line(tmp_path):
    for name, text in deep_toml_texts():
        path = tmp_path / "deep.toml"
        path.write_text(text)
        for argv in (["plan", path], ["camera", path], ["sweep", path]):
            before = snapshot(tmp_path)
            outcome = run_main(campaign_main, argv, tmp_path)
            assert not refusal_problems(outcome, before, snapshot(tmp_path)), (name, argv, outcome)


@pytest.mark.parametrize("overrides", ["rows = 1000000000, cols = 1000000000", "rows = 4611686018427387904"])
def test_huge_declared_terrain_size_is_one_line(tmp_path, overrides):
    path = _site_file(tmp_path, **{'seed = 4101 }': f'seed = 4101, overrides = {{ {overrides} }} }}'})
    outcome = run_main(campaign_main, ["plan", path, "--out", tmp_path / "maps"], tmp_path)
    assert outcome.code == 2 and outcome.out == "" and not no_traceback_problems(outcome, (2,)), outcome


@pytest.mark.parametrize("address", ["tcp://", "tcp://host", "tcp://host:", "tcp://host:0", "tcp://host:65536",
                                     "tls://:8786", "inproc://", "tcp://host:port"])
def test_scheduler_address_without_host_and_port_is_one_line(tmp_path, address):
    path = _site_file(tmp_path)
    path.write_text(path.read_text() + f'\n[execution]\nscheduler = "{address}"\n')
    for argv in (["submit", path, "--no-progress"], ["submit", GUSEV, "--no-progress", "--scheduler", address]):
        before = snapshot(tmp_path)
        outcome = run_main(campaign_main, argv, tmp_path)
        assert not refusal_problems(outcome, before, snapshot(tmp_path)), (argv, outcome)
        assert "scheduler" in outcome.err and "host:port" in outcome.err


# ------------------------------------------------------------------------------------------ closed stdout
def _closed_stdout_run(argv: list, cwd: Path) -> subprocess.CompletedProcess:
    read_end, write_end = os.pipe()
    os.close(read_end)                                      # the reader (| head) is gone before anything is written
    try:
        return subprocess.run([sys.executable, "-m", "campaign.cli", *map(str, argv)], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, cwd=cwd, timeout=90, env=ENV)
    finally:
        os.close(write_end)


@pytest.mark.parametrize("argv", [["schema", "execution"], ["schema"], ["camera", REPO / "sitedata" / "cameras" / "mer_a.toml"]])
def test_a_closed_stdout_ends_quietly(tmp_path, argv):
    result = _closed_stdout_run(argv, tmp_path)
    assert result.returncode == 141 and result.stderr == "", result


@pytest.mark.slow
@pytest.mark.cluster
@pytest.mark.parametrize("command", ["status", "table"])
def test_a_closed_stdout_on_store_commands_ends_quietly(tmp_path, command, interrupted):
    result = _closed_stdout_run([command, interrupted.store], tmp_path)
    assert result.returncode == 141 and result.stderr == "", result


# ------------------------------------------------------------------------------------------ interrupt
def _session_processes(session: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[3]) == session and fields[0] != "Z":
                found.append(int(entry.name))
    return found


@dataclass(frozen=True)
class Interrupted:
    store: Path
    code: int
    out: str
    err: str
    left: list[int]                 # processes of the submit's session still alive 30 s after it ended


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory) -> Interrupted:
    """A real `campaign submit` on a 2-worker LocalCluster, interrupted by SIGINT to its process group once a
    case file exists (188 planned cases: far more than can finish between the first file and the signal)."""
    root = tmp_path_factory.mktemp("interrupted")
    store = root / "store"
    process = subprocess.Popen([sys.executable, "-m", "campaign.cli", "submit", str(GUSEV), "--output", str(store),
                                "--cases-scale", "0.5", "--workers", "2", "--no-progress"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=root, env=ENV, start_new_session=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not list((store / "cases").glob("??/batch-*.parquet")):
        if process.poll() is not None:
            break
        time.sleep(0.2)
    os.killpg(process.pid, signal.SIGINT)                   # what Ctrl-C in a terminal does
    out, err = process.communicate(timeout=120)
    deadline = time.monotonic() + 30
    while _session_processes(process.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return Interrupted(store, process.returncode, out, err, _session_processes(process.pid))


@pytest.mark.slow
@pytest.mark.cluster
def test_sigint_during_submit_is_one_line_exit_130_and_workers_stop_quietly(interrupted):
    cases = list((interrupted.store / "cases").glob("??/batch-*.parquet"))
    assert interrupted.code == 130, interrupted
    err = interrupted.err
    assert err.count("\n") == 1 and "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert f"interrupted; {len(cases)} finished case files kept in {interrupted.store}" in err
    assert len(cases) >= 1 and interrupted.left == [], interrupted.left    # no worker or nanny left behind
    assert "Traceback" not in interrupted.out


# ------------------------------------------------------------------------------------------ corrupt side files
@pytest.mark.slow
@pytest.mark.cluster
@pytest.mark.parametrize("name", ["manifest.json", "plan.parquet"])
def test_corrupt_store_files_are_one_line(tmp_path, interrupted, name):
    store = tmp_path / "store"
    tried = 0
    for damage_name, _ in corrupt_file_variants(interrupted.store / name):
        shutil.rmtree(store, ignore_errors=True)
        shutil.copytree(interrupted.store, store, symlinks=True)
        target_variants = dict(corrupt_file_variants(store / name))
        target_variants[damage_name]()
        for command in ("status", "table", "verify", "report"):
            outcome = _outcome([command, store], tmp_path, damage_name == "FIFO")
            assert not no_traceback_problems(outcome), (name, damage_name, command, outcome.code, outcome.err)
            tried += 1
        if name == "manifest.json":         # refused before any cluster starts (a damaged plan is rewritten: it is derived)
            outcome = _outcome(["submit", GUSEV, "--output", store, "--cases-scale", "0.1", "--no-progress"], tmp_path,
                               damage_name == "FIFO")
            assert outcome.code == 2 and not no_traceback_problems(outcome), (name, damage_name, outcome.err)
    assert tried == 8 * 4


@pytest.mark.slow
def test_corrupt_baseline_sweep_json_is_one_line(tmp_path):
    baseline = tmp_path / "baseline"
    baseline.mkdir()
    (baseline / "sweep.json").write_text('{"axes": {}, "points": []}')
    for damage_name, damage in corrupt_file_variants(baseline / "sweep.json"):
        damage()
        before = snapshot(tmp_path)
        outcome = _outcome(["sweep", SWEEP, "--output", tmp_path / "new", "--baseline", baseline, "--no-progress"],
                           tmp_path, damage_name == "FIFO")
        assert not refusal_problems(outcome, before, snapshot(tmp_path)), (damage_name, outcome)
