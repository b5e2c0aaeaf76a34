"""``[execution] cluster = "slurm"`` on a real single-node SLURM cluster (tests/slurm_node.py: Debian's
SLURM, installed by the set-up when missing and we are root; munged, slurmctld and slurmd started for
the session): dask-jobqueue submits real ``sbatch`` jobs whose workers compute a Gusev quick look, equal
bit for bit to the embedded cluster's, over TLS (a per-run certificate; a client without it, or with
another certificate, is refused by the running scheduler); and every failure of the batch system stops the run within 30 s
in one line naming the command and its error (no sbatch on PATH, a rejected job, a job that can never
start, a job that ends before its worker connects)."""
from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pandas as pd
import pytest
from distributed import Client
from distributed.security import Security
from slurm_node import SlurmNode, install_reason

from campaign.cli import main
from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import connected_client
from campaign.run.faults import RunStopped
from config_tables.models import parse
from service_campaigns import REPO, campaign_command, campaign_file, stderr_line

STOP_WITHIN_S = 30.0
CASES = {"gcp": 1, "gdcp": 1, "gkep": 0}     # one case per SLURM job

pytestmark = [pytest.mark.cluster, pytest.mark.slurm]


@pytest.fixture(scope="session")
def slurm():
    reason = install_reason()
    if reason:
        pytest.skip(f"no SLURM cluster for the tests: {reason}")
    node = SlurmNode()
    yield node
    node.stop()


def _slurm_table(tmp_path: Path, **fields) -> str:
    """An [execution] table for the test cluster: 1-core jobs on loopback, output files in tmp_path."""
    settings = {"queue": SlurmNode.partition, "cores": 1, "memory": "1500MiB", "jobs": 2, "interface": "lo",
                "walltime": "00:10:00", "job_extra": [f"--output={tmp_path}/slurm-%j.out"], **fields}
    lines = [f"{key} = {json.dumps(value)}" for key, value in settings.items()]     # JSON values are TOML here
    return 'cluster = "slurm"\nno_workers_timeout_s = 120\n[execution.slurm]\n' + "\n".join(lines)


def _submit(config: Path, out: Path, environment: dict, cwd: Path) -> tuple[subprocess.CompletedProcess, float]:
    """``campaign submit`` in a subprocess (the repository on PYTHONPATH: the jobs' workers inherit it
    through sbatch's exported environment); returns the result and its wall time (s)."""
    start = time.monotonic()
    result = subprocess.run(campaign_command("submit", config, "--output", out, "--no-progress"), capture_output=True,
                            text=True, timeout=300, cwd=cwd,
                            env={**os.environ, "PYTHONPATH": str(REPO), **environment})
    return result, time.monotonic() - start


@pytest.mark.slow
def test_quick_look_through_sbatch_jobs_equals_the_local_cluster_bit_for_bit(slurm, tmp_path, record_property,
                                                                              capsys):
    before = set(slurm.jobs())
    config = campaign_file(tmp_path / "slurm", cases=CASES, execution=_slurm_table(tmp_path))
    result, wall_s = _submit(config, tmp_path / "slurm" / "out", slurm.environment, tmp_path)
    assert result.returncode == 0, result.stderr
    [jobs_line] = [line for line in result.stdout.splitlines() if line.startswith("slurm jobs: ")]
    job_ids = jobs_line.removeprefix("slurm jobs: ").split(", ")
    scheduler = re.search(r"scheduler: (tls://\S+)", result.stdout).group(1)     # TLS by default
    record_property("slurm_job_ids", job_ids)
    record_property("slurm_run_wall_s", round(wall_s, 1))

    # two jobs of one worker each, submitted to this SLURM cluster under the worker job name, cancelled at the end
    known = slurm.jobs()
    assert len(job_ids) == 2 and not set(job_ids) & before
    for job_id in job_ids:
        name, state, _ = known[job_id]
        assert name == "moc2dimes-worker" and state in ("CANCELLED", "COMPLETED", "COMPLETING"), known[job_id]
    # the jobs' dask workers registered with this run's scheduler, and the cases ran on at most two workers
    logs = [(tmp_path / f"slurm-{job_id}.out").read_text() for job_id in job_ids]
    assert all(re.search(rf"Registered to:\s+{re.escape(scheduler)}", log) for log in logs), logs
    # campaign cluster FILE printed the script sbatch got (the first job's; the address known only at run time)
    scripts = [slurm.run("scontrol", "write", "batch_script", job_id, "-").stdout for job_id in job_ids]
    # the workers presented the run's own certificate (files in a private directory, removed after the run)
    certificates = {re.search(r"--tls-ca-file (\S+)/certificate\.pem", script).group(1) for script in scripts}
    [certificate_directory] = certificates
    assert all(f"--tls-key {certificate_directory}/key.pem" in script and "PRIVATE KEY" not in script
               for script in scripts), scripts
    assert Path(certificate_directory).parent == tmp_path and not Path(certificate_directory).exists()
    capsys.readouterr()
    assert main(["cluster", str(config)]) == 0
    printed = (capsys.readouterr().out.replace("tls://SCHEDULER-ADDRESS:PORT", scheduler)
               .replace("RUN-CERTIFICATE-DIRECTORY", certificate_directory))
    assert printed.strip() in [script.strip() for script in scripts], (printed, scripts)
    assert 1 <= pd.read_parquet(tmp_path / "slurm" / "out" / "timings.parquet")["worker"].nunique() <= 2

    local = campaign_file(tmp_path / "local", cases=CASES, execution="workers = 2")
    assert main(["submit", str(local), "--output", str(tmp_path / "local" / "out"), "--no-progress"]) == 0
    on_slurm = pd.read_parquet(tmp_path / "slurm" / "out" / "results.parquet")   # no run-dependent column
    on_local = pd.read_parquet(tmp_path / "local" / "out" / "results.parquet")
    planned = pd.read_parquet(tmp_path / "slurm" / "out" / "plan.parquet")["case_id"]
    assert len(on_slurm) == 2 and sorted(on_slurm["case_id"]) == sorted(planned)      # 2 cases, one estimator
    pd.testing.assert_frame_equal(on_slurm, on_local, check_exact=True)
    with capsys.disabled():
        print(f"\nSLURM quick look: jobs {', '.join(job_ids)}, campaign submit {wall_s:.1f} s", flush=True)


@pytest.mark.slow
def test_no_sbatch_on_path_stops_at_once_in_one_line(tmp_path):
    """Needs no SLURM: PATH holds only the interpreter's directory."""
    config = campaign_file(tmp_path, execution=_slurm_table(tmp_path))
    result, wall_s = _submit(config, tmp_path / "out", {"PATH": str(Path(sys.executable).parent)}, tmp_path)
    assert result.returncode == 1
    line = stderr_line(result)
    assert "sbatch is not on PATH" in line and "nothing was run or changed" in line, line
    assert wall_s < STOP_WITHIN_S and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_rejected_job_stops_the_run_in_one_line_naming_sbatch_and_its_error(slurm, tmp_path):
    before = set(slurm.jobs())
    config = campaign_file(tmp_path, execution=_slurm_table(tmp_path, queue="nosuchpartition"))
    result, wall_s = _submit(config, tmp_path / "out", slurm.environment, tmp_path)
    assert result.returncode == 1
    line = stderr_line(result)
    assert line.startswith("campaign: sbatch rejected the worker job (exit 1): ") and "Invalid partition" in line, line
    assert wall_s < STOP_WITHIN_S, wall_s
    assert set(slurm.jobs()) == before                      # nothing was queued
    assert not (tmp_path / "out").exists()


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def _refusal(address: str, security: Security | None) -> str:
    """The error of a ``distributed.Client`` connecting to ``address`` with ``security`` ("" if it connected)."""
    try:
        with Client(address, security=security, timeout="10s"):
            return ""
    except Exception as exc:           # the refusal under test: its type and text are asserted by the caller
        return f"{type(exc).__name__}: {exc}"


def test_running_tls_scheduler_refuses_a_client_without_the_run_certificate(slurm, tmp_path, monkeypatch,
                                                                            record_property):
    """The slurm cluster as campaign submit starts it (in this process): its worker (a real SLURM job)
    computes over TLS; clients without the run's certificate are refused by that scheduler, at once."""
    monkeypatch.setenv("SLURM_CONF", slurm.environment["SLURM_CONF"])
    monkeypatch.chdir(tmp_path)
    with connected_client(_execution(tmp_path, jobs=1), quiet=True) as client:
        address = client.scheduler.address
        assert address.startswith("tls://127.0.0.1:")
        assert client.submit(pow, 3, 4).result(timeout=60) == 81         # the SLURM job's worker, over TLS
        run = client.security
        stranger = Security.temporary()
        listener_log = logging.getLogger("distributed.comm.tcp")     # the scheduler's side of each handshake
        handshakes = _Lines()
        listener_log.addHandler(handshakes)
        level = listener_log.level
        listener_log.setLevel(logging.WARNING)
        start = time.monotonic()
        # no certificate at all: a plain client (tcp:// to the same port) is cut off by the TLS listener
        plain = _refusal(address.replace("tls://", "tcp://"), None)
        # another certificate, trusting the scheduler's CA (so the scheduler decides): it rejects the unknown CA
        other = _refusal(address, Security(require_encryption=True, tls_ca_file=run.tls_ca_file,
                                           tls_client_cert=stranger.tls_client_cert,
                                           tls_client_key=stranger.tls_client_key))
        # another certificate and CA altogether: no handshake either way
        foreign = _refusal(address, stranger)
        elapsed_s = time.monotonic() - start
        time.sleep(0.5)                  # the scheduler logs its refusal on its own event loop
        listener_log.removeHandler(handshakes)
        listener_log.setLevel(level)
        assert client.submit(pow, 2, 10).result(timeout=60) == 1024      # the run's own client still works
    record_property("refusals", [plain, other, foreign, *handshakes.lines])
    # the clients' errors: connection cut during the handshake (the scheduler refused), or the scheduler's
    # certificate not trusted by the stranger
    assert "CommClosedError" in plain and ("Connection reset by peer" in plain or "closed" in plain), plain
    assert re.search(r"TLSV1_ALERT_UNKNOWN_CA|SSLEOFError|Connection reset by peer", other), other
    assert "TLS certificate does not match" in foreign, foreign
    # the scheduler's reasons: a plain-TCP greeting is no TLS, the stranger's certificate fails verification
    refused = [line for line in handshakes.lines if "TLS handshake failed" in line]
    assert any("WRONG_VERSION_NUMBER" in line for line in refused), handshakes.lines
    assert any("CERTIFICATE_VERIFY_FAILED" in line for line in refused), handshakes.lines
    assert elapsed_s < 10.0, elapsed_s              # refused, not timed out (each client allowed 10 s)


def _execution(tmp_path: Path, **fields) -> ExecutionConfig:
    table = tomllib.loads("[execution]\n" + _slurm_table(tmp_path, **fields))["execution"]
    return parse(ExecutionConfig, table, "campaign.toml", prefix="execution")


@pytest.mark.parametrize("fields, expected", [
    # more cores than the node has: squeue reason PartitionConfig, pending for ever
    ({"cores": 64, "memory": "1GiB"}, r"SLURM job (\d+) can never start: squeue reports it PENDING \(PartitionConfig\)"),
    # the job script fails before its worker starts: the job ends, its output's last line is quoted
    ({"prologue": ["echo worker environment is broken; exit 3"]},
     r"SLURM job (\d+) ended \(FAILED\) before its dask worker connected; its output \S+ ends: worker environment is broken"),
])
def test_dead_job_stops_the_run_within_30_s_and_is_cancelled(slurm, tmp_path, monkeypatch, fields, expected):
    """The cluster as campaign submit starts it (in this process: no cases needed)."""
    monkeypatch.setenv("SLURM_CONF", slurm.environment["SLURM_CONF"])
    monkeypatch.chdir(tmp_path)
    start = time.monotonic()
    with pytest.raises(RunStopped) as stopped:
        with connected_client(_execution(tmp_path, jobs=1, **fields), quiet=True):
            pass
    elapsed_s = time.monotonic() - start
    message = str(stopped.value)
    match = re.match(expected, message)
    assert match and message.endswith("nothing was run or changed") and "\n" not in message, message
    assert elapsed_s < STOP_WITHIN_S, elapsed_s
    name, state, _ = slurm.jobs()[match.group(1)]
    assert name == "moc2dimes-worker" and state in ("CANCELLED", "FAILED"), state   # not left in the queue
