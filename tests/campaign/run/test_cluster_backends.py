"""Cluster backends of ``[execution] cluster`` (campaign.run.cluster): declarations with one-line errors,
the SLURM / PBS job scripts and the Kubernetes DaskCluster spec as generated (no batch system or
Kubernetes needed), a missing optional package named by its pip extra, and the "scheduler" backend run
for real against `dask scheduler` / `dask worker` processes, giving the same bits as the embedded cluster."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from campaign.cli import main
from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import connected_client
from campaign.run.faults import RunStopped
from config_tables.errors import ConfigError
from config_tables.models import parse
from service_campaigns import REPO, DaskProcesses, campaign_file, campaign_in_process, run_campaign, stderr_line

BATCH = {"queue": "debug", "account": "proj42", "walltime": "02:30:00", "cores": 4, "memory": "8GiB", "jobs": 3,
         "prologue": ["source /opt/moc2dimes/venv/bin/activate"]}


def _execution(data: dict) -> ExecutionConfig:
    return parse(ExecutionConfig, data, "campaign.toml", prefix="execution")


@pytest.mark.parametrize("lines, expected", [
    ('cluster = "sge"', "execution.cluster = 'sge' is not allowed; allowed: local, scheduler, slurm, pbs, kubernetes"),
    ('cluster = "slurm"\n[execution.slurm]\nqeue = "debug"', "execution.slurm.qeue is not a known field; allowed: queue,"),
    ('cluster = "pbs"\n[execution.pbs]\nwalltime = "2h"', "execution.pbs.walltime = '2h' is not a wall time"),
    ('cluster = "kubernetes"', "execution.kubernetes.image is missing"),
    ('cluster = "scheduler"', "execution.scheduler is missing; cluster = \"scheduler\" needs"),
    ('stall_timeout_s = 0', "execution.stall_timeout_s = 0 is out of range; allowed: >= 1"),
    ('cluster = "kubernetes"\n[execution.kubernetes]\nimage = "x"\nmemory = "2 GB"',
     "execution.kubernetes.memory = '2 GB' is not a Kubernetes quantity"),
    ('cluster = "kubernetes"\n[execution.kubernetes]\nimage = "x"\nmemory = "512Mi"',
     "execution.kubernetes.memory = '512Mi' is too small for a worker pod; allowed: at least \"1Gi\""),
])
def test_bad_execution_table_is_one_line_exit_2_nothing_written(tmp_path, capsys, lines, expected):
    path = campaign_file(tmp_path, execution=lines)
    out = tmp_path / "out"
    code = main(["submit", str(path), "--output", str(out), "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 2
    lines_printed = stderr.strip().splitlines()
    assert len(lines_printed) == 1 and str(path) in lines_printed[0] and expected in lines_printed[0], stderr
    assert not out.exists()


def test_scheduler_address_alone_selects_the_scheduler_backend():
    assert _execution({"scheduler": "tcp://127.0.0.1:8786"}).cluster == "scheduler"
    assert _execution({}).cluster == "local"
    with pytest.raises(ConfigError, match="only used with cluster = \"scheduler\""):
        _execution({"cluster": "local", "scheduler": "tcp://127.0.0.1:8786"})


@pytest.mark.parametrize("kind, directives", [
    ("slurm", ["#SBATCH -J moc2dimes-worker", "#SBATCH -p debug", "#SBATCH -A proj42", "#SBATCH -t 02:30:00",
               "#SBATCH --cpus-per-task=4", "#SBATCH --mem=8G", "#SBATCH --qos=low"]),
    ("pbs", ["#PBS -N moc2dimes-worker", "#PBS -q debug", "#PBS -A proj42", "#PBS -l walltime=02:30:00",
             "#PBS -l select=1:ncpus=4:mem=8192MB", "#PBS -l place=scatter"]),
])
@pytest.mark.cluster
def test_batch_job_script_has_the_configured_resources_and_worker_command(kind, directives, tmp_path, monkeypatch):
    from campaign.run.cluster import jobqueue_cluster

    monkeypatch.chdir(tmp_path)               # the run's certificate directory goes here

    extra = ["--qos=low"] if kind == "slurm" else ["-l place=scatter"]
    execution = _execution({"cluster": kind, kind: {**BATCH, "job_extra": extra}})
    cluster = jobqueue_cluster(execution)     # its scheduler runs here; no job is submitted
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    lines = script.splitlines()
    for directive in directives:
        assert directive in lines, script
    assert "export OPENBLAS_NUM_THREADS=1" in lines and "source /opt/moc2dimes/venv/bin/activate" in lines
    [worker] = [line for line in lines if "distributed.cli.dask_worker" in line]
    # the prologue's environment (a venv) is the workers': its python3, never the driver's path (issue 32)
    assert worker.startswith("python3 -m distributed.cli.dask_worker ") and sys.executable not in script
    # 4 single-threaded worker processes per job sharing 8 GiB: 2 GiB each
    for part in ("--nthreads 1", "--nworkers 4", "--memory-limit 2.00GiB"):
        assert part in worker, worker
    assert getattr(execution, kind).memory_per_worker_bytes == 2 * 2**30


def test_kubernetes_spec_has_image_namespace_and_resources():
    from campaign.run.cluster import kubernetes_cluster_spec

    execution = _execution({"cluster": "kubernetes", "kubernetes": {
        "image": "registry.example.org/moc2dimes:0.1", "namespace": "edl-campaigns", "workers": 12,
        "cpu": "1", "memory": "3Gi"}})
    spec = kubernetes_cluster_spec(execution)
    assert spec["kind"] == "DaskCluster" and spec["metadata"] == {"name": "moc2dimes", "namespace": "edl-campaigns"}
    worker_group = spec["spec"]["worker"]
    assert worker_group["replicas"] == 12
    [container] = worker_group["spec"]["containers"]
    assert container["image"] == "registry.example.org/moc2dimes:0.1"
    assert container["resources"] == {"requests": {"cpu": "1", "memory": "3Gi"}, "limits": {"cpu": "1", "memory": "3Gi"}}
    arguments = container["args"]
    assert arguments[:2] == ["dask", "worker"]
    assert arguments[arguments.index("--nthreads") + 1] == "1"
    # dask's limit 10 % below the pod's 3 GiB: dask pauses (80 %) and restarts (95 %) before the pod is killed
    assert arguments[arguments.index("--memory-limit") + 1] == str(3 * 2**30 - int(0.1 * 3 * 2**30))
    assert {"name": "OPENBLAS_NUM_THREADS", "value": "1"} in container["env"]
    [scheduler] = spec["spec"]["scheduler"]["spec"]["containers"]
    assert scheduler["image"] == "registry.example.org/moc2dimes:0.1"
    small = _execution({"cluster": "kubernetes", "kubernetes": {"image": "x", "memory": "1Gi"}})
    [container] = kubernetes_cluster_spec(small)["spec"]["worker"]["spec"]["containers"]
    limit = int(container["args"][container["args"].index("--memory-limit") + 1])
    assert limit == 2**30 - 256 * 2**20          # at least 256 MiB headroom: 768 MiB for dask
    assert 0.8 * limit > 600 * 2**20             # a case (about 600 MiB) fits below the pause threshold
    overridden = _execution({"cluster": "kubernetes", "workers": 5, "kubernetes": {"image": "x"}})
    assert kubernetes_cluster_spec(overridden)["spec"]["worker"]["replicas"] == 5      # [execution] workers wins


@pytest.mark.parametrize("kind, module, extra", [("slurm", "dask_jobqueue", "slurm"),
                                                 ("kubernetes", "dask_kubernetes", "kubernetes")])
def test_missing_optional_package_names_the_pip_extra(tmp_path, kind, module, extra):
    """The package made unimportable in a fresh interpreter (as if not installed): one line, exit 2."""
    table = f'cluster = "{kind}"' + ('\n[execution.kubernetes]\nimage = "x"' if kind == "kubernetes" else "")
    path = campaign_file(tmp_path, execution=table)
    out = tmp_path / "out"
    script = (f"import sys; sys.modules[{module!r}] = None\nfrom campaign.cli import main\n"
              f"sys.exit(main(['submit', {str(path)!r}, '--output', {str(out)!r}, '--no-progress']))")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode == 2
    line = stderr_line(result)
    assert f"pip install 'moc2dimes[{extra}]'" in line and str(path) in line, line
    assert not out.exists()


@pytest.mark.cluster
@pytest.mark.slow
def test_scheduler_backend_runs_for_real_and_gives_the_embedded_clusters_bits(tmp_path, capfd):
    """Both submits are ``campaign.cli.main`` in this process (``campaign_in_process``): the cluster
    processes are what is real here, the driver's interpreter start is not under test. Slow by design (over
    60 s in a loaded suite run): a fresh external scheduler with two workers and then an embedded cluster, since
    the bits of the two backends' own start-ups are what is compared."""
    processes = DaskProcesses(tmp_path, workers=2)
    try:
        external = campaign_file(tmp_path / "external", execution=f'cluster = "scheduler"\nscheduler = "{processes.address}"')
        result = campaign_in_process(capfd, "submit", external, "--output", tmp_path / "external" / "out", "--no-progress")
        assert result.returncode == 0, result.stderr
        assert f"scheduler: {processes.address}  cluster: scheduler" in result.stdout
    finally:
        processes.close()
    embedded = campaign_file(tmp_path / "embedded", execution="workers = 1")
    result = campaign_in_process(capfd, "submit", embedded, "--output", tmp_path / "embedded" / "out", "--no-progress")
    assert result.returncode == 0, result.stderr
    first = pd.read_parquet(tmp_path / "external" / "out" / "results.parquet")
    second = pd.read_parquet(tmp_path / "embedded" / "out" / "results.parquet")
    assert len(first) == 3
    pd.testing.assert_frame_equal(first, second, check_exact=True)


@pytest.mark.parametrize("kind", ["slurm", "pbs"])
def test_campaign_cluster_prints_the_job_script_and_submits_nothing(tmp_path, kind):
    """No batch system on PATH: printing the script needs none, and nothing can have been submitted."""
    table = f'cluster = "{kind}"\nworkers = 6\n[execution.{kind}]\nqueue = "debug"\ncores = 4\nmemory = "8GiB"'
    path = campaign_file(tmp_path, execution=table)
    result = run_campaign("cluster", path, env={"PATH": str(Path(sys.executable).parent)})
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "#!/usr/bin/env bash"
    assert ("#SBATCH -p debug" if kind == "slurm" else "#PBS -q debug") in lines
    [worker] = [line for line in lines if "distributed.cli.dask_worker" in line]
    assert "tls://SCHEDULER-ADDRESS:PORT" in worker and "--nworkers 3" in worker and "--memory-limit 2.00GiB" in worker
    # TLS: the run's certificate and key by path (created when the run starts), no key material
    for part in ("--dashboard-address 127.0.0.1:0", "--protocol tls://", "--tls-ca-file RUN-CERTIFICATE-DIRECTORY/certificate.pem",
                 "--tls-cert RUN-CERTIFICATE-DIRECTORY/certificate.pem", "--tls-key RUN-CERTIFICATE-DIRECTORY/key.pem"):
        assert part in worker, worker
    assert "BEGIN" not in result.stdout and "PRIVATE KEY" not in result.stdout
    submit = "sbatch" if kind == "slurm" else "qsub"
    # exactly 6 workers, cores = 4 does not divide 6: 2 jobs of 3 (not 2 jobs of 4, 8 workers), said in the note
    assert stderr_line(result) == (f"campaign: note: 2 such job(s) of 3 single-threaded worker(s), submitted with "
                                   f"{submit} (6 workers: 2 job(s) of 3 worker(s) (3 cores, 6144MiB each) instead of "
                                   f"[execution.{kind}] cores = 4 (memory 8GiB), which does not divide 6); nothing "
                                   "was submitted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["campaign.toml"]     # no store, no job output


def test_campaign_cluster_prints_the_kubernetes_resource_without_credentials(tmp_path):
    table = 'cluster = "kubernetes"\n[execution.kubernetes]\nimage = "registry.example.org/m2d:1"\nmemory = "4Gi"'
    path = campaign_file(tmp_path, execution=table)
    result = run_campaign("cluster", path, env={"HOME": str(tmp_path), "KUBECONFIG": str(tmp_path / "none")})
    assert result.returncode == 0, result.stderr
    spec = json.loads(result.stdout)
    [container] = spec["spec"]["worker"]["spec"]["containers"]
    assert container["resources"]["limits"]["memory"] == "4Gi"
    limit = int(container["args"][container["args"].index("--memory-limit") + 1])
    assert limit == 4 * 2**30 - int(0.4 * 2**30)      # 10 % of 4 GiB (> 256 MiB) kept above dask's limit
    assert f"dask --memory-limit {limit / 2**20:.0f} MiB" in stderr_line(result)


@pytest.mark.cluster
@pytest.mark.slow
def test_kubernetes_without_credentials_is_one_line_and_writes_nothing(tmp_path):
    path = campaign_file(tmp_path, execution='cluster = "kubernetes"\n[execution.kubernetes]\nimage = "x"\n'
                                             'allow_plain_tcp = true')
    out = tmp_path / "out"
    result = run_campaign("submit", path, "--output", out, "--no-progress", timeout=120,
                          env={"HOME": str(tmp_path), "KUBECONFIG": str(tmp_path / "none")})
    assert result.returncode == 1
    line = stderr_line(result)
    assert line.startswith("campaign: cannot start the Kubernetes cluster (") and "credentials" in line, line
    assert not out.exists()


def test_kubernetes_submit_refuses_plain_tcp_unless_asked(tmp_path):
    """KubeCluster's scheduler speaks plain TCP: submit refuses before anything is written (one line naming the
    field and the TLS way), while ``campaign cluster`` still prints the TLS spec for the user to apply."""
    path = campaign_file(tmp_path, execution='cluster = "kubernetes"\n[execution.kubernetes]\nimage = "x"')
    out = tmp_path / "out"
    result = run_campaign("submit", path, "--output", out, "--no-progress", timeout=120,
                          env={"HOME": str(tmp_path), "KUBECONFIG": str(tmp_path / "none")})
    assert result.returncode == 2
    line = stderr_line(result)
    assert str(path) in line and "plain TCP" in line and "allow_plain_tcp = true" in line, line
    assert "--scheduler tls://" in line and "campaign cluster FILE" in line, line
    assert not out.exists()
    printed = run_campaign("cluster", path, timeout=120)
    assert printed.returncode == 0, printed.stderr
    assert "--protocol" in printed.stdout and "tls" in printed.stdout


@pytest.mark.parametrize("kind, command", [("slurm", "sbatch"), ("pbs", "qsub")])
def test_missing_submit_command_stops_before_any_cluster_starts(monkeypatch, kind, command):
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent))       # no batch system here
    with pytest.raises(RunStopped, match=rf"^cannot submit {kind.upper()} jobs: {command} is not on PATH; .*"
                                         "nothing was run or changed$"):
        with connected_client(_execution({"cluster": kind}), quiet=True):
            pass


# --- security: TLS, certificate files, dashboards (issue 36) ---

def _pem_files(directory: Path, security=None) -> dict[str, str]:
    """A CA certificate (self-signed, also the leaf) and its key as [execution] tls_* files."""
    from distributed.security import Security

    security = security or Security.temporary()
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "ca.pem").write_text(security.tls_ca_file)
    (directory / "key.pem").write_text(security.tls_client_key)
    (directory / "key.pem").chmod(0o600)
    return {"tls_ca_file": str(directory / "ca.pem"), "tls_cert_file": str(directory / "ca.pem"),
            "tls_key_file": str(directory / "key.pem")}


@pytest.mark.parametrize("lines, expected", [
    ('scheduler = "tls://127.0.0.1:8786"', "execution.tls_ca_file is missing; scheduler = 'tls://127.0.0.1:8786' needs"),
    ('tls_ca_file = "nosuch.pem"\ntls_cert_file = "nosuch.pem"\ntls_key_file = "nosuch.pem"',
     "execution.tls_ca_file = 'nosuch.pem' cannot be read (No such file or directory: "),
    ('tls_ca_file = "campaign.toml"', "execution.tls_cert_file is missing; tls_ca_file, tls_cert_file and tls_key_file go together"),
    ('dashboard_address = "0.0.0.0"', "execution.dashboard_address = '0.0.0.0' is not a dashboard address"),
    ('scheduler = "udp://127.0.0.1:8786"', "allowed: \"\" (embedded), tls://host:port or tcp://host:port"),
])
def test_bad_security_fields_are_one_line_exit_2(tmp_path, capsys, lines, expected):
    path = campaign_file(tmp_path, execution=lines)
    code = main(["submit", str(path), "--output", str(tmp_path / "out"), "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 2
    [line] = stderr.strip().splitlines()
    assert expected in line, line
    assert not (tmp_path / "out").exists()


def test_unreadable_key_file_is_refused_at_the_config_edge(tmp_path):
    files = _pem_files(tmp_path / "tls")
    Path(files["tls_key_file"]).chmod(0)
    try:
        readable = open(files["tls_key_file"], "rb").close() is None      # root reads a file of mode 0 anyway
    except OSError:
        readable = False
    if readable:
        pytest.skip("this user reads files of mode 0 (root)")
    with pytest.raises(ConfigError, match=r"execution.tls_key_file = .* cannot be read \(Permission denied"):
        _execution({"cluster": "slurm", **files})


@pytest.mark.parametrize("kind", ["slurm", "pbs"])
def test_job_script_with_the_users_ca_names_the_files_and_holds_no_key(tmp_path, kind):
    from campaign.run.cluster import batch_job_script

    files = _pem_files(tmp_path / "tls")
    script = batch_job_script(_execution({"cluster": kind, **files}))
    [worker] = [line for line in script.splitlines() if "distributed.cli.dask_worker" in line]
    assert worker.split()[3] == "tls://SCHEDULER-ADDRESS:PORT"
    assert f"--tls-ca-file {files['tls_ca_file']}" in worker and f"--tls-key {files['tls_key_file']}" in worker
    assert "BEGIN" not in script


def test_printed_text_never_shows_key_material():
    from distributed.security import Security

    from campaign.run.security import elide_key_material

    temporary = Security.temporary()
    text = elide_key_material(f"--tls-key {temporary.tls_worker_key} --tls-cert {temporary.tls_worker_cert} end")
    assert text == "--tls-key <private key elided>\n --tls-cert <certificate elided>\n end"     # PEM ends in \\n


@pytest.mark.cluster
def test_job_scripts_given_to_the_batch_system_are_readable_by_their_owner_only(tmp_path):
    from dask_jobqueue.slurm import SLURMJob

    from campaign.run.batch_jobs import JobRecord, recording_job_class

    job = recording_job_class(SLURMJob, JobRecord())(scheduler="tls://127.0.0.1:1", name="x", cores=1, memory="1GiB")
    with job.job_file() as path:
        mode = Path(path).stat().st_mode & 0o777
        directory_mode = Path(path).parent.stat().st_mode & 0o777
        assert Path(path).read_text() == job.job_script()
    assert (mode, directory_mode) == (0o600, 0o700)
    assert not Path(path).exists()


@pytest.mark.cluster
def test_batch_scheduler_listens_on_tls_only_and_its_dashboard_on_loopback(tmp_path, monkeypatch):
    from campaign.run.cluster import jobqueue_cluster

    monkeypatch.chdir(tmp_path)
    cluster = jobqueue_cluster(_execution({"cluster": "slurm", "slurm": {"interface": "lo"}}))
    try:
        scheduler = cluster.scheduler
        assert [listener.contact_address.split("://")[0] for listener in scheduler.listeners] == ["tls"]
        assert scheduler.http_server is not None
        assert {socket.getsockname()[0] for socket in scheduler.http_server._sockets.values()} == {"127.0.0.1"}
        [directory] = tmp_path.glob(".moc2dimes-tls-*")             # the run's certificate: private
        assert directory.stat().st_mode & 0o777 == 0o700
        assert {path.name: path.stat().st_mode & 0o777 for path in directory.iterdir()} == {
            "certificate.pem": 0o600, "key.pem": 0o600}
    finally:
        cluster.close()
    del cluster
    import gc
    gc.collect()
    assert not list(tmp_path.glob(".moc2dimes-tls-*"))                # removed with the cluster


def test_kubernetes_spec_carries_the_tls_secret_reference_and_local_dashboards():
    from campaign.run.cluster import kubernetes_cluster_spec

    execution = _execution({"cluster": "kubernetes", "kubernetes": {"image": "x", "name": "edl", "namespace": "ns"}})
    spec = kubernetes_cluster_spec(execution)
    text = json.dumps(spec)
    assert "BEGIN" not in text                                        # a reference, no key material
    for role in ("scheduler", "worker"):
        pod = spec["spec"][role]["spec"]
        assert pod["volumes"] == [{"name": "tls", "secret": {"secretName": "edl-tls", "defaultMode": 0o400}}]
        [container] = pod["containers"]
        assert container["volumeMounts"] == [{"name": "tls", "mountPath": "/etc/moc2dimes/tls", "readOnly": True}]
        for part in ("--tls-ca-file=/etc/moc2dimes/tls/ca.crt", "--tls-cert=/etc/moc2dimes/tls/tls.crt",
                     "--tls-key=/etc/moc2dimes/tls/tls.key"):
            assert part in container["args"], container["args"]
        dashboard = container["args"][container["args"].index("--dashboard-address") + 1]
        assert dashboard.startswith("127.0.0.1:"), dashboard
        assert all(port["name"] != "http-dashboard" for port in container["ports"])
    [scheduler] = spec["spec"]["scheduler"]["spec"]["containers"]
    assert scheduler["args"][scheduler["args"].index("--protocol") + 1] == "tls"
    assert scheduler["readinessProbe"]["tcpSocket"] == {"port": "tcp-comm"} and "httpGet" not in scheduler["readinessProbe"]
    assert [port["name"] for port in spec["spec"]["scheduler"]["service"]["ports"]] == ["tcp-comm"]
    [worker] = spec["spec"]["worker"]["spec"]["containers"]
    assert {"name": "DASK_SCHEDULER_ADDRESS", "value": "tls://edl-scheduler.ns.svc.cluster.local:8786"} in worker["env"]


def test_plain_tcp_to_another_host_warns_in_one_line_naming_the_risk(capsys):
    execution = _execution({"scheduler": "tcp://192.0.2.1:8786", "connect_timeout_s": 1})   # TEST-NET-1: nobody
    with pytest.raises(RunStopped, match="cannot reach the dask scheduler tcp://192.0.2.1:8786"):
        with connected_client(execution, quiet=True):
            pass
    [warning] = capsys.readouterr().err.strip().splitlines()
    assert warning.startswith("campaign: warning: tcp://192.0.2.1:8786 is plain TCP to another host: anyone who "
                              "can reach that port can run code"), warning
    for address in ("tcp://127.0.0.1:8786", "tcp://127.0.1.1:8786", "tcp://localhost:8786", "tcp://[::1]:8786",
                    "tls://10.0.0.1:8786", "inproc://x"):
        assert not _execution({"scheduler": address, **({"tls_ca_file": __file__, "tls_cert_file": __file__,
                                                         "tls_key_file": __file__} if "tls" in address else {})}
                              ).plain_tcp_to_another_host, address
    for address in ("tcp://10.0.0.1:8786", "tcp://login01.cluster:8786", "tcp://[2001:db8::1]:8786"):
        assert _execution({"scheduler": address}).plain_tcp_to_another_host, address


@pytest.mark.cluster
def test_unwritable_certificate_directory_stops_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", f"{tmp_path}:{os.environ['PATH']}")
    (tmp_path / "sbatch").write_text("#!/bin/sh\nexit 1\n")          # on PATH; never reached
    (tmp_path / "sbatch").chmod(0o755)
    execution = _execution({"cluster": "slurm", "slurm": {"certificate_directory": str(tmp_path / "absent")}})
    with pytest.raises(RunStopped, match=r"^cannot write the run's TLS certificate under .*absent \(No such file or "
                                         r"directory\); set \[execution\.slurm\] certificate_directory .*nothing was "
                                         "run or changed$"):
        with connected_client(execution, quiet=True):
            pass


@pytest.mark.cluster
def test_tls_scheduler_is_reached_with_the_certificate_files_of_execution(tmp_path):
    """An external scheduler started as cluster.py starts its own (tls://, Security of PEM files): the
    campaign's client connects with [execution] tls_* and its worker computes; without them it cannot."""
    from dask.distributed import LocalCluster

    from campaign.run.security import user_security

    files = _pem_files(tmp_path / "tls")
    execution_files = _execution({"cluster": "slurm", **files})
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, protocol="tls://", host="127.0.0.1",
                      security=user_security(execution_files), dashboard_address="127.0.0.1:0") as external:
        address = external.scheduler_address
        assert address.startswith("tls://127.0.0.1:")
        with connected_client(_execution({"scheduler": address, **files}), quiet=True) as client:
            assert client.submit(sum, [1, 2, 3]).result(timeout=60) == 6
        with pytest.raises(RunStopped, match=r"cannot reach the dask scheduler tcp://127\.0\.0\.1:\d+ within 2 s"):
            with connected_client(_execution({"scheduler": address.replace("tls://", "tcp://"),
                                              "connect_timeout_s": 2}), quiet=True):
                pass
