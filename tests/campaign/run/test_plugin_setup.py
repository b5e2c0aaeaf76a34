"""Plug-ins on real workers: a python plug-in package importable only on the driver runs on a separate
`dask worker` process (another cwd, PYTHONPATH without it), in-process and isolated, because submit ships
it; a plug-in that cannot be set up on a worker stops the run with one line, records nothing, exits 1,
and the next submit runs those cases."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from service_campaigns import DASK, REPO, campaign_file, case_files, run_campaign, scheduler_address

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

PLUGIN = '''import os
from .answer import EAST_MPS, NORTH_MPS          # a sibling module: the whole package must arrive

if os.path.exists("h2_break_here"):              # in the workers' directory, for one test only
    import h2_licence_client_not_installed        # noqa: F401


def estimate(inputs):
    """A fixed answer whose east component says where the module was loaded from (-1: not the shipped zip)."""
    east = EAST_MPS if ".zip" in __file__ else -1.0
    return {"velocity_east_mps": east, "velocity_north_mps": NORTH_MPS, "valid": True, "reason": "ok"}
'''


def _plugin_package(root: Path) -> Path:
    package = root / "h2_shipped"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "answer.py").write_text("EAST_MPS = 1.25\nNORTH_MPS = -2.5\n")
    (package / "est.py").write_text(PLUGIN)
    return root


class _Dask:
    """`dask scheduler` + one `dask worker` on loopback, both started in ``cwd`` with PYTHONPATH = the
    project only (never the plug-in's directory)."""

    def __init__(self, cwd: Path):
        self.cwd = cwd
        command = [str(DASK)] if DASK.exists() else [sys.executable, "-m", "distributed.cli.dask_spec"]
        environment = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
        scheduler_file = cwd / "scheduler.json"
        self.processes = [subprocess.Popen([*command, "scheduler", "--host", "127.0.0.1", "--port", "0",
                                            "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(scheduler_file)],
                                           cwd=cwd, env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                           start_new_session=True)]
        self.processes.append(subprocess.Popen([*command, "worker", "--scheduler-file", str(scheduler_file),
                                                "--nthreads", "1", "--nworkers", "1", "--host", "127.0.0.1",
                                                "--no-dashboard", "--memory-limit", "1.5GiB"],
                                               cwd=cwd, env=environment, stdout=subprocess.DEVNULL,
                                               stderr=subprocess.DEVNULL, start_new_session=True))
        from dask.distributed import Client

        with Client(scheduler_address(scheduler_file), timeout="60s") as client:
            client.wait_for_workers(1, timeout=60)
            self.address = client.scheduler.address
            # the worker alone cannot import the plug-in (so what runs there was shipped)
            self.worker_finds_plugin = any(client.run(lambda: __import__("importlib.util").util.find_spec("h2_shipped")
                                                      is not None).values())

    def close(self) -> None:
        for process in self.processes:
            try:
                os.killpg(process.pid, 9)
            except ProcessLookupError:
                pass
            process.wait()


SECOND = '''
[[estimators]]
name = "shipped_isolated"'''
ESTIMATORS = '''
[estimator]
flat_field = "none"

[[estimators]]
name = "shipped"
kind = "python"
callable = "h2_shipped.est:estimate"

[[estimators]]
name = "shipped_isolated"
kind = "python"
callable = "h2_shipped.est:estimate"
isolate = true
'''


@pytest.fixture(scope="module")
def dask_elsewhere(tmp_path_factory):
    """The cluster, and the plug-in package in a directory only the driver's PYTHONPATH holds."""
    root = tmp_path_factory.mktemp("shipping")
    plugins = _plugin_package(root / "plugins")
    elsewhere = root / "elsewhere"
    elsewhere.mkdir()
    dask = _Dask(elsewhere)
    yield dask, {"PYTHONPATH": f"{plugins}{os.pathsep}{REPO}"}
    dask.close()


def test_python_plugin_only_on_the_driver_runs_on_a_separate_dask_worker(tmp_path, dask_elsewhere):
    dask, driver_env = dask_elsewhere
    assert not dask.worker_finds_plugin
    config = campaign_file(tmp_path, {"gcp": 1, "gdcp": 1, "gkep": 0}, extra=ESTIMATORS)
    out = tmp_path / "out"
    submit = run_campaign("submit", config, "--output", out, "--scheduler", dask.address, "--no-progress", env=driver_env)
    assert submit.returncode == 0, submit.stdout + submit.stderr
    results = pd.read_parquet(out / "results.parquet")
    assert len(results) == 4 and set(results["estimator"]) == {"shipped", "shipped_isolated"}
    assert set(results["status"]) == {"ok"}, results[["error", "reason"]]
    assert set(results["estimate_velocity_east_mps"]) == {1.25} and set(results["estimate_velocity_north_mps"]) == {-2.5}


def test_plugin_that_does_not_import_on_the_worker_stops_the_run_and_records_nothing(tmp_path, dask_elsewhere):
    dask, driver_env = dask_elsewhere
    marker = dask.cwd / "h2_break_here"
    marker.write_text("")
    try:
        config = campaign_file(tmp_path, {"gcp": 1, "gdcp": 1, "gkep": 0}, extra=ESTIMATORS.split(SECOND)[0])
        out = tmp_path / "out"
        submit = run_campaign("submit", config, "--output", out, "--scheduler", dask.address, "--no-progress",
                              env=driver_env)
    finally:
        marker.unlink()
    assert submit.returncode == 1, submit.stdout + submit.stderr
    lines = submit.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in submit.stderr, submit.stderr
    assert lines[0].startswith("campaign: run stopped before any case ran: estimator shipped cannot be set up on worker "
                               "tcp://127.0.0.1:"), lines[0]
    assert "ModuleNotFoundError: No module named 'h2_licence_client_not_installed'" in lines[0]
    assert "install what it imports on every worker" in lines[0]
    assert case_files(out) == []


NOT_EXECUTABLE = '''import json, sys
json.dump({"velocity_east_mps": 3.0, "velocity_north_mps": 4.0, "valid": True, "reason": "ok"}, open(sys.argv[1], "w"))
'''


def test_command_that_cannot_start_stops_the_run_and_the_next_submit_runs_its_cases(tmp_path):
    """The program passes the file's check (it exists) but is not executable: every worker fails its set-up;
    no case is recorded for any estimator, the reference included; made executable, the same campaign runs
    all of them. Slow by design (about 70 s in a loaded suite run): two `campaign submit` processes, each with
    its own embedded cluster, since the set-up of fresh workers is what is tested."""
    program = tmp_path / "flight.py"
    program.write_text(f"#!{sys.executable}\n{NOT_EXECUTABLE}")
    program.chmod(0o644)
    extra = f'''
[estimator]
flat_field = "none"

[[estimators]]
name = "dimes"
kind = "reference"

[[estimators]]
name = "flight"
kind = "command"
argv = ["{program}", "{{output}}"]
'''
    config = campaign_file(tmp_path, {"gcp": 1, "gdcp": 1, "gkep": 0}, execution="workers = 1", extra=extra)
    out = tmp_path / "out"
    first = run_campaign("submit", config, "--output", out, "--no-progress")
    assert first.returncode == 1, first.stdout + first.stderr
    lines = first.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in first.stderr, first.stderr
    assert lines[0].startswith("campaign: run stopped: estimator flight cannot be set up on worker tcp://127.0.0.1:")
    assert f"PermissionError: '{program}' is not executable" in lines[0]
    assert lines[0].endswith("0 cases of this run finished and kept, 2 left for the next submit"), lines[0]
    assert case_files(out) == []
    program.chmod(0o755)
    second = run_campaign("submit", config, "--output", out, "--no-progress")
    assert second.returncode == 0, second.stdout + second.stderr
    assert "(2 done, 0 failed this run)" in second.stdout
    results = pd.read_parquet(out / "results.parquet")
    flight = results[results["estimator"] == "flight"]
    assert len(flight) == 2 and set(flight["status"]) == {"ok"} and set(flight["estimate_velocity_east_mps"]) == {3.0}
    assert set(results.loc[results["estimator"] == "dimes", "status"]) == {"ok"}
