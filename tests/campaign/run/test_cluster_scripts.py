"""Batch-job scripts that run (issue 32): the workers of ``[execution] cluster = "slurm"`` run the interpreter of
the environment the user configured (``[execution.slurm] prologue``, ``python``), ``--workers N`` gives N
workers (or says in one line how the jobs are shaped), and a refused submit leaves nothing behind.

The SLURM tests run on the private single-node SLURM cluster of tests/slurm_node.py, whose jobs start the
workers from the job script alone (nothing else starts a dask worker here); the others need no SLURM.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from slurm_node import SlurmNode, install_reason, node_resources

from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import batch_job_script, cluster_description, connected_client, job_shape
from config_tables.models import parse
from service_campaigns import REPO, campaign_command, campaign_file, file_tree, stderr_line

pytest.importorskip("dask_jobqueue")


@pytest.fixture(scope="module")
def slurm():
    reason = install_reason()
    if reason:
        pytest.skip(f"no SLURM cluster for the tests: {reason}")
    node = SlurmNode()
    yield node
    node.stop()


def _execution(tmp_path: Path, workers: int = 0, **fields) -> ExecutionConfig:
    """An [execution] table of slurm jobs for the test cluster (loopback, output files in tmp_path)."""
    settings = {"queue": SlurmNode.partition, "cores": 1, "memory": "1500MiB", "jobs": 1, "interface": "lo",
                "walltime": "00:10:00", "job_extra": [f"--output={tmp_path}/slurm-%j.out"], **fields}
    text = (f'[execution]\ncluster = "slurm"\nworkers = {workers}\nno_workers_timeout_s = 120\n[execution.slurm]\n'
            + "\n".join(f"{key} = {json.dumps(value)}" for key, value in settings.items()))
    return parse(ExecutionConfig, tomllib.loads(text)["execution"], "campaign.toml", prefix="execution")


def _worker_line(script: str) -> str:
    [line] = [line for line in script.splitlines() if "distributed.cli.dask_worker" in line]
    return line


def test_the_job_script_runs_the_interpreter_of_the_configured_environment(tmp_path):
    """No prologue: the driver's interpreter by its path; a prologue (a venv's activate, `module load`): python3
    as that environment finds it, after the prologue; an explicit [execution.slurm] python: that one."""
    plain = batch_job_script(_execution(tmp_path))
    assert _worker_line(plain).startswith(f"{sys.executable} -m distributed.cli.dask_worker ")
    activate = "source /home/me/moc2dimes/.venv/bin/activate"
    script = batch_job_script(_execution(tmp_path, prologue=[activate]))
    assert _worker_line(script).startswith("python3 -m distributed.cli.dask_worker ")
    assert script.index(activate) < script.index(_worker_line(script))        # the environment first
    assert sys.executable not in script                                      # no path of the login node's
    chosen = batch_job_script(_execution(tmp_path, prologue=["module load python/3.11"], python="/opt/py/bin/python3.11"))
    assert _worker_line(chosen).startswith("/opt/py/bin/python3.11 -m distributed.cli.dask_worker ")


@pytest.mark.parametrize("workers, cores, jobs, per_job, noted", [
    (3, 8, 1, 3, True),      # fewer than a job: one job of 3 cores, not one of 8
    (10, 8, 2, 5, True),     # 8 does not divide 10: two jobs of 5
    (16, 8, 2, 8, False),    # jobs of `cores` workers
    (7, 4, 7, 1, True),      # a prime: seven one-core jobs
])
def test_workers_n_gives_exactly_n_workers_and_says_how_the_jobs_are_shaped(tmp_path, workers, cores, jobs, per_job,
                                                                            noted):
    execution = _execution(tmp_path, workers=workers, cores=cores, memory=f"{cores}GiB")
    shape = job_shape(execution)
    assert (shape.jobs, shape.workers_per_job, shape.workers) == (jobs, per_job, workers)
    script = batch_job_script(execution)
    assert f"--cpus-per-task={per_job}\n" in script
    assert (f"--nworkers {per_job} " in _worker_line(script)) if per_job > 1 else "--nworkers" not in script
    assert f"--mem={per_job}G\n" in script                                   # 1 GiB per worker, as configured
    _, note = cluster_description(execution)
    assert note.startswith(f"{jobs} such job(s) of {per_job} single-threaded worker(s)"), note
    assert (f"{workers} workers: {jobs} job(s) of {per_job} worker(s)" in note) == noted, note
    assert "\n" not in note


def test_a_submit_refused_for_want_of_sbatch_leaves_nothing_behind(tmp_path):
    """Needs no SLURM: PATH holds only the interpreter's directory."""
    text = '[execution]\ncluster = "slurm"\n[execution.slurm]\ncores = 1\n'
    config = campaign_file(tmp_path / "config", execution=text.removeprefix("[execution]\n"))
    before = file_tree(tmp_path)
    result = subprocess.run(campaign_command("submit", config, "--output", tmp_path / "out", "--no-progress"),
                            capture_output=True, text=True, timeout=120, cwd=REPO,
                            env={"PATH": str(Path(sys.executable).parent), "PYTHONPATH": str(REPO)})
    assert result.returncode == 1
    line = stderr_line(result)
    assert "sbatch is not on PATH" in line and "nothing was run or changed" in line, line
    assert file_tree(tmp_path) == before                 # no store, no lock file, nothing


@pytest.mark.cluster
@pytest.mark.slurm
def test_slurm_workers_run_in_the_prologue_environment_with_exactly_n_workers(slurm, tmp_path, monkeypatch):
    """A real venv activated by the job script's prologue: the workers SLURM starts from that script run its
    interpreter (sys.prefix is the venv); `workers` below `cores` gives that many workers in one job the node
    can run (before: one job asking for every configured core, which this node cannot hold)."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], check=True)
    cpus, _ = node_resources()
    monkeypatch.setenv("SLURM_CONF", slurm.environment["SLURM_CONF"])
    monkeypatch.setenv("PYTHONPATH", str(REPO))            # sbatch exports it: the workers import this checkout
    monkeypatch.chdir(tmp_path)
    before = set(slurm.jobs())
    execution = _execution(tmp_path, workers=cpus, cores=2 * cpus, memory=f"{3 * cpus}GiB",
                           prologue=[f"source {venv}/bin/activate"])
    with connected_client(execution, quiet=True) as client:
        client.wait_for_workers(cpus, timeout=120)
        prefixes = client.run(eval, "__import__('sys').prefix")
        executables = client.run(eval, "__import__('sys').executable")
        assert client.submit(pow, 3, 4).result(timeout=60) == 81
        workers = len(client.scheduler_info()["workers"])
    assert set(prefixes.values()) == {str(venv)}, prefixes
    assert all(Path(path).parent == venv / "bin" for path in executables.values()), executables
    assert workers == cpus
    jobs = [job_id for job_id, (name, _, _) in slurm.jobs().items()
            if job_id not in before and name == "moc2dimes-worker"]
    assert len(jobs) == 1, jobs
    script = slurm.run("scontrol", "write", "batch_script", jobs[0], "-").stdout
    assert f"source {venv}/bin/activate" in script and re.search(r"^python3 -m distributed\.cli\.dask_worker ", script,
                                                                   re.MULTILINE), script


@pytest.mark.cluster
@pytest.mark.slurm
def test_a_submit_whose_job_slurm_rejects_leaves_nothing_behind(slurm, tmp_path):
    """The lock is taken before the jobs are submitted (so that a busy store is refused before any job is
    queued); a submit the batch system then refuses removes the lock file it made."""
    text = "\n".join(f"{key} = {json.dumps(value)}" for key, value in {
        "queue": "nosuchpartition", "cores": 1, "memory": "1500MiB", "interface": "lo"}.items())
    config = campaign_file(tmp_path / "config", execution=f'cluster = "slurm"\n[execution.slurm]\n{text}')
    before = file_tree(tmp_path)
    result = subprocess.run(campaign_command("submit", config, "--output", tmp_path / "out", "--no-progress"),
                            capture_output=True, text=True, timeout=300, cwd=tmp_path,
                            env={**os.environ, **slurm.environment, "PYTHONPATH": str(REPO)})
    assert result.returncode == 1
    line = stderr_line(result)
    assert "sbatch rejected the worker job" in line and "nothing was run or changed" in line, line
    assert file_tree(tmp_path) == before                 # no store, no lock file, no certificate directory
