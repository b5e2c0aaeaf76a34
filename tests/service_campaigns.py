"""Tiny real campaigns and real dask processes for the runner's tests (fault injection, cluster
backends, progress and dashboard): a Gusev campaign file with a few cases, the `campaign` CLI as a
subprocess, and a `dask scheduler` with `dask worker` processes on 127.0.0.1."""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SITEDATA = REPO / "sitedata"
GUSEV = SITEDATA / "gusev.toml"
DASK = Path(sys.executable).with_name("dask")


def campaign_file(directory: Path, cases: dict | None = None, execution: str = "", extra: str = "",
                  trajectory: Path | None = None, name: str = "campaign.toml") -> Path:
    """A copy of the Gusev site file with absolute input paths, ``[campaign] cases`` (default gcp 2,
    gdcp 1) and the given ``[execution]`` lines."""
    cases = cases or {"gcp": 2, "gdcp": 1, "gkep": 0}
    text = GUSEV.read_text()
    text = text.replace('camera = "cameras/', f'camera = "{SITEDATA}/cameras/')
    text = text.replace('trajectory_set = "trajectories/gusev.parquet"',
                        f'trajectory_set = "{trajectory or SITEDATA / "trajectories" / "gusev.parquet"}"')
    counts = ", ".join(f"{key} = {value}" for key, value in cases.items())
    text += f"\n[campaign]\ncases = {{ {counts} }}\n\n[execution]\n{execution}\n{extra}\n"
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / name
    path.write_text(text)
    return path


def site_copy(directory: Path, extra: str = "", name: str = "gusev.toml") -> Path:
    """sitedata/gusev.toml with absolute input paths (so the copy can live anywhere) plus ``extra`` TOML."""
    text = GUSEV.read_text()
    for relative in ('"cameras/mer_a.toml"', '"trajectories/gusev.parquet"'):
        text = text.replace(relative, f'"{SITEDATA / relative.strip(chr(34))}"')
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / name
    path.write_text(text + extra)
    return path


def file_tree(root: Path) -> dict:
    """Relative path -> (size, mtime ns) of every file under ``root`` (None for a directory): a snapshot
    that shows whether anything was written, moved or removed."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else None
            for p in sorted(root.rglob("*"))} if root.exists() else {}


def low_camera_trajectory(path: Path) -> Path:
    """One Gusev trajectory lowered so that the lander is 0.45 m above the ground at image 3: valid as a
    trajectory file (the lander stays above z = 0 while imaging), but the camera, 0.5 m below the
    lander's origin, is under the ground during image 3, so the simulation of the case itself raises."""
    from sitedata.edl.trajectory_io import read_profiles, write_profiles

    profile = read_profiles(SITEDATA / "trajectories" / "gusev.parquet")[0]
    height = profile.pose(float(profile.image_times_s[-1])).position_m[2]
    position = profile.position_m.copy()
    position[:, 2] -= height - 0.45
    write_profiles(path, [dataclasses.replace(profile, position_m=position)])
    return path


def campaign_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "campaign.cli", *map(str, args)]


def run_campaign(*args, timeout: float = 300, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(campaign_command(*args), capture_output=True, text=True, timeout=timeout, cwd=REPO,
                          env={**os.environ, **(env or {})})


def campaign_in_process(capfd, *args) -> subprocess.CompletedProcess:
    """``campaign ARGS`` as ``campaign.cli.main`` in this process, with what a `campaign` process would give:
    its exit code and everything written to file descriptors 1 and 2 (``capfd``: this process's prints and
    logs, and those of the cluster's worker processes it starts). Saves the interpreter start, the imports
    and the code digest (cached per process) that a subprocess pays on every command; used where the process
    itself (a kill, a signal, a timeout) is not what is tested."""
    from campaign.cli import main

    capfd.readouterr()
    code = main([str(arg) for arg in args])
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess(["campaign", *map(str, args)], code, out, err)


def stderr_line(result) -> str:
    """The single line a stopped or failed command prints on stderr (asserts there is exactly one)."""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    return lines[0]


def case_files(out: Path, pattern: str = "*/batch-*.parquet") -> list[Path]:
    """The batch files of a store's worker tasks (``cases/<xx>/batch-*.parquet``), or those matching ``pattern``."""
    return sorted((out / "cases").glob(pattern)) if (out / "cases").exists() else []


def wait_for_case_files(out: Path, count: int, process: subprocess.Popen, limit_s: float = 120.0) -> None:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if len(case_files(out)) >= count:
            return
        if process.poll() is not None:
            raise AssertionError(f"campaign ended early ({process.returncode}): {process.stderr.read()}")
        time.sleep(0.1)
    raise AssertionError(f"no {count} case files in {limit_s} s")


def scheduler_address(scheduler_file: Path, limit_s: float = 60.0) -> str:
    """The address in the ``--scheduler-file`` a starting `dask scheduler` writes, once the whole file is there (the
    scheduler writes it in place: the file can exist, empty or half-written, before it parses)."""
    deadline = time.monotonic() + limit_s
    while True:
        try:
            return json.loads(scheduler_file.read_text())["address"]
        except (OSError, ValueError, KeyError):
            if time.monotonic() > deadline:
                raise AssertionError(f"no scheduler address in {scheduler_file} within {limit_s} s") from None
            time.sleep(0.05)


class DaskProcesses:
    """A `dask scheduler` and `dask worker` processes on loopback (each in its own process group)."""

    def __init__(self, directory: Path, workers: int = 1, memory_limit: str = "1.5GiB"):
        command = [str(DASK)] if DASK.exists() else [sys.executable, "-m", "distributed.cli.dask_spec"]
        scheduler_file = directory / "scheduler.json"
        self.scheduler = subprocess.Popen([*command, "scheduler", "--host", "127.0.0.1", "--port", "0",
                                           "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(scheduler_file)],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.address = scheduler_address(scheduler_file)
        environment = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
        self.workers = [subprocess.Popen([*command, "worker", self.address, "--nthreads", "1", "--nworkers", "1",
                                          "--host", "127.0.0.1", "--no-dashboard", "--memory-limit", memory_limit],
                                         cwd=REPO, env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                         start_new_session=True)
                        for _ in range(workers)]
        from dask.distributed import Client

        with Client(self.address, timeout="30s") as client:
            client.wait_for_workers(workers, timeout=60)

    def import_case_code(self) -> None:
        """Import the case code in every worker (3-4 s of imports, as in a worker that has served a campaign),
        so that a test's first case takes its own time only."""
        import importlib

        from dask.distributed import Client

        with Client(self.address, timeout="30s") as client:
            client.run(importlib.import_module, "campaign.run.worker")

    def signal_workers(self, number: int) -> None:
        for process in self.workers:
            _signal_group(process, number)

    def close(self) -> None:
        for process in [*self.workers, self.scheduler]:
            _signal_group(process, signal.SIGCONT)
            _signal_group(process, signal.SIGKILL)
            process.wait()


def _signal_group(process: subprocess.Popen, number: int) -> None:
    try:
        os.killpg(process.pid, number)
    except ProcessLookupError:
        pass


#: a process that takes a store's lock (``StoreLock``), prints "locked" and holds it for 10 minutes
LOCK_HOLDER_SCRIPT = ("import sys, time; from campaign.store.lock import StoreLock; "
                      "lock = StoreLock(sys.argv[1]).acquire(); print('locked', flush=True); time.sleep(600)")


def project_environment() -> dict:
    """The environment with the checkout first on PYTHONPATH (subprocesses import this checkout's code)."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def start_lock_holders():
    """Generator behind the ``holder`` fixtures: yields ``start(store_dir) -> Popen`` (a real process holding
    the store's real ``flock``, started once it says it holds it) and kills every holder afterwards."""
    processes = []

    def start(store: Path) -> subprocess.Popen:
        process = subprocess.Popen([sys.executable, "-c", LOCK_HOLDER_SCRIPT, str(store)], stdout=subprocess.PIPE,
                                   text=True, cwd=REPO, env=project_environment(), start_new_session=True)
        assert process.stdout.readline().strip() == "locked"
        processes.append(process)
        return process

    yield start
    for process in processes:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def campaign_with_command_estimator(directory: Path, name: str, program: str,
                                    cases: dict | None = None) -> Path:
    """A campaign file (``campaign_file``, one worker) running the reference ``dimes`` and a command estimator
    ``name``: ``program`` (Python source) written to ``directory/<name>.py``, called with the output path."""
    script = directory / f"{name}.py"
    script.write_text(program)
    estimators = (f'\n[[estimators]]\nname = "dimes"\nkind = "reference"\n\n[[estimators]]\nname = "{name}"\n'
                  f'kind = "command"\nargv = ["{sys.executable}", "{script}", "{{output}}"]\n')
    return campaign_file(directory, cases or {"gcp": 2, "gdcp": 1, "gkep": 0}, execution="workers = 1",
                         extra=estimators)


def embedded_scheduler(workers: int):
    """Generator behind module ``scheduler`` fixtures: the address of a campaign's own embedded cluster
    (``campaign.run.cluster.start_cluster``) with ``workers`` workers, closed afterwards."""
    from campaign.configuration.execution import ExecutionConfig
    from campaign.run.cluster import start_cluster

    client, cluster = start_cluster(ExecutionConfig(workers=workers), quiet=True)
    yield client.scheduler.address
    client.close()
    cluster.close()
