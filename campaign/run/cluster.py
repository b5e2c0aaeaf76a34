"""Cluster backends of ``[execution] cluster``: where a campaign's dask workers come from.

``local``       an embedded LocalCluster of single-threaded worker processes (``workers``, ``memory_limit``)
``scheduler``   an existing scheduler (``scheduler = "tls://host:port"`` with the ``tls_*_file`` certificate
                files, or ``"tcp://host:port"``; or ``--scheduler``)
``slurm``       SLURM batch jobs (dask-jobqueue's SLURMCluster; ``[execution.slurm]``; extra ``moc2dimes[slurm]``)
``pbs``         PBS batch jobs (dask-jobqueue's PBSCluster; ``[execution.pbs]``; extra ``moc2dimes[pbs]``)
``kubernetes``  scheduler and worker pods of a DaskCluster resource (dask-kubernetes' operator
                KubeCluster; ``[execution.kubernetes]``; extra ``moc2dimes[kubernetes]``)

Every worker runs one thread (a case is one CPU-bound task; BLAS and OpenCV threads are pinned to 1, the
environment before the worker process starts and :class:`~campaign.run.worker_startup.CaseWorkerSetup` when it has
started), without dask's statistical profiler (:data:`WORKER_DASK_CONFIG`).

**Workers' heap.** Every worker process we start keeps freed frame-sized buffers for reuse and computes in
one malloc arena (:mod:`simulator.heap`; glibc reads the variables when a process starts, so they are in the
environment it starts with, never a user's own malloc setting replaced): the embedded cluster's nannies spawn
(and restart) workers with :func:`case_worker_pre_spawn_environ` in place of dask's 64 KiB trim threshold;
batch jobs export :func:`~simulator.heap.case_process_environment` of the driver's environment before their
workers start; worker pods have :data:`~simulator.heap.CASE_PROCESS_ENVIRONMENT` in their env. Workers
started by someone else (``scheduler``) set the thresholds with ``mallopt`` when they join
(:class:`~campaign.run.worker_startup.CaseWorkerSetup`, dask's trim threshold counting as unset); their
malloc arenas stay as their environment made them.
Batch jobs are submitted and watched until their first worker connects by :mod:`campaign.run.batch_jobs`
(a batch-system failure is one line naming the command and its error); :func:`cluster_description` is
what ``campaign cluster FILE`` prints (job script or DaskCluster resource, nothing submitted); a
Kubernetes worker's dask memory limit keeps a headroom below its pod's limit
(:func:`~campaign.configuration.execution.kubernetes_headroom_bytes`).

**Security.** The slurm, pbs and kubernetes schedulers listen only on ``tls://`` and accept only peers
that present a certificate of the run's certificate authority (:func:`run_certificates`: a per-run
self-signed certificate from ``distributed.security.Security.temporary()``, written for the batch jobs'
workers to a private directory, or the user's CA of ``[execution] tls_*_file``); no plain-TCP listener is
left open. Every dashboard binds ``[execution] dashboard_address`` (default ``127.0.0.1:0``). The job
scripts given to ``sbatch`` / ``qsub`` are written readable only by their owner
(:func:`~campaign.run.batch_jobs.recording_job_class`) and hold certificate paths, never key material;
anything printed passes :func:`elide_key_material`.

The optional packages are imported only for their backend; a missing one is a one-line
:class:`~config_tables.errors.ConfigError` naming the pip extra, raised by
:func:`require_backend` before anything is written.
"""
from __future__ import annotations

import importlib
import json
import logging
import os
import sys
import threading
import weakref
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol, cast

import dask
from dask.distributed import Client, LocalCluster
from distributed.security import Security

from campaign.configuration.execution import BatchJobs, ExecutionConfig, kubernetes_bytes, kubernetes_headroom_bytes
from campaign.run.batch_jobs import (
    SUBMIT_COMMANDS,
    JobRecord,
    recording_job_class,
    require_submit_command,
    wait_for_first_worker,
)
from campaign.run.faults import RunStopped
from campaign.run.interrupts import held, raise_pending, signals_blocked
from campaign.run.security import (
    CERTIFICATE_NAME,
    KEY_NAME,
    RunCertificates,
    elide_key_material,
    file_security,
    run_certificates,
    user_security,
)
from campaign.run.worker_startup import CaseWorkerSetup
from config_tables.errors import ConfigError
from simulator.heap import (
    CASE_PROCESS_ENVIRONMENT,
    DASK_NANNY_TRIM_THRESHOLD,
    case_process_environment,
    users_thresholds,
)

#: backend -> (module it needs, pip distribution, extra of moc2dimes)
OPTIONAL_BACKENDS = {"slurm": ("dask_jobqueue", "dask-jobqueue", "slurm"),
                     "pbs": ("dask_jobqueue", "dask-jobqueue", "pbs"),
                     "kubernetes": ("dask_kubernetes", "dask-kubernetes", "kubernetes")}
SINGLE_THREAD_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: dask settings of the campaign's worker processes. The statistical profiler samples the running task's
#: stack every 10 ms from another thread of the worker (for the dashboard's profile page): measured on
#: 30 Gusev cases in one worker, 25-30 ms more CPU per case (of about 300 ms) with it than without, taken
#: from the cases when every core runs a worker.
WORKER_DASK_CONFIG = {"distributed.worker.profile.enabled": False}
#: dask's periodic housekeeping in every server of the embedded cluster (the scheduler and the nannies in the
#: driver, and each worker): the event-loop health tick (every 20 ms by default, a diagnostic: it warns of a loop
#: blocked for ``tick.limit``, 3 s), the system monitor (psutil CPU, memory, disk and network counters every
#: 500 ms, for the dashboard's graphs) and the worker memory monitor (the worker's and its nanny's RSS every
#: 100 ms: pause at 80 %, terminate at 95 % of ``memory_limit``). With every core running a case these run on
#: the cases' cores: measured on an idle 2-worker cluster, 62 ms of CPU per second in all (driver 32, each worker
#: 15), 3 % of the two cores; 10 ms/s with the intervals below. A worker still pauses or is stopped at its memory
#: limit, within 250 ms of crossing it instead of 100 ms (a case grows its heap over tens of ms).
HOUSEKEEPING_DASK_CONFIG = {"distributed.admin.tick.interval": "1s",
                            "distributed.admin.system-monitor.interval": "2s",
                            "distributed.worker.memory.monitor-interval": "250ms"}
#: and of the embedded cluster (scheduler, nannies, worker processes) only: the housekeeping intervals above;
#: the workers ignore SIGINT, SIGTERM and SIGHUP, which reach the whole process group (Ctrl-C, ``timeout``, a
#: closed terminal); the driver stops them (campaign.run.interrupts)
LOCAL_WORKER_DASK_CONFIG = {**WORKER_DASK_CONFIG, **HOUSEKEEPING_DASK_CONFIG,
                            "distributed.worker.preload": ["campaign.run.interrupts"]}
#: the environment of a worker process that dask starts elsewhere (batch job, pod): one thread, no profiler
WORKER_ENVIRONMENT = {**SINGLE_THREAD_ENVIRONMENT, "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}
WORKER_JOB_NAME = "moc2dimes-worker"
SCHEDULER_PLACEHOLDER = "tls://SCHEDULER-ADDRESS:PORT"
#: where ``campaign cluster`` shows the run's certificate directory (created only when the run starts)
CERTIFICATE_PLACEHOLDER = "RUN-CERTIFICATE-DIRECTORY"
#: the Kubernetes Secret (type kubernetes.io/tls plus ca.crt) the DaskCluster's pods mount, and where
KUBERNETES_TLS_MOUNT = "/etc/moc2dimes/tls"
KUBERNETES_COMM_PORT = 8786
#: distributed's own log records on the driver during a run (the runner reports problems as one line;
#: M2D_DASK_LOG_LEVEL=20 shows them, e.g. to debug a cluster)
DRIVER_LOG_LEVEL = int(os.environ.get("M2D_DASK_LOG_LEVEL", logging.CRITICAL))


@contextmanager
def workers_ignore_stop_signals() -> Iterator[None]:
    """Worker processes started inside never act on SIGINT, SIGTERM or SIGHUP: the driver starts them with
    those signals blocked (:func:`~campaign.run.interrupts.signals_blocked`; the mask is inherited across
    fork and exec).

    Ctrl-C, ``timeout`` and a closed terminal signal the whole process group; only the driver answers
    (:mod:`campaign.run.interrupts`: it drops the remaining tasks, stops the workers through dask, keeps the
    finished cases and prints one line, :func:`campaign.cli.main`) instead of every worker dying mid-write or
    printing a KeyboardInterrupt traceback. A signal to the driver while its workers start is delivered when
    they have started (to its handler), never lost."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with signals_blocked():
        yield


def require_backend(execution: ExecutionConfig, source: str = "[execution]") -> None:
    """Raise a one-line ConfigError when the package of ``execution.cluster`` is not installed."""
    if execution.cluster not in OPTIONAL_BACKENDS:
        return
    module, distribution, extra = OPTIONAL_BACKENDS[execution.cluster]
    try:
        importlib.import_module(module)
    except ImportError:
        raise ConfigError(f"{source}: execution.cluster = {execution.cluster!r} needs {distribution}, which is not "
                          f"installed; allowed: pip install 'moc2dimes[{extra}]', or another cluster") from None


def _previewed_security(execution: ExecutionConfig) -> Security:
    """The Security of the job script ``campaign cluster`` prints before any run: the user's CA files when
    ``[execution]`` names them, else the per-run file names under :data:`CERTIFICATE_PLACEHOLDER` (the run's
    directory does not exist yet; :func:`~campaign.run.security.run_certificates` creates it at submit)."""
    given = user_security(execution)
    if given is not None:
        return given
    certificate, key = f"{CERTIFICATE_PLACEHOLDER}/{CERTIFICATE_NAME}", f"{CERTIFICATE_PLACEHOLDER}/{KEY_NAME}"
    return file_security(certificate, certificate, key)


def default_worker_count() -> int:
    return max(1, os.cpu_count() or 1)


#: the workers' interpreter in a batch job whose ``prologue`` sets up the environment (a venv's activate, ``module
#: load``, ``conda activate``) and whose ``python`` is "": the one that environment puts first on PATH
PROLOGUE_PYTHON = "python3"


def worker_python(jobs: BatchJobs) -> str:
    """The interpreter a batch job's workers run (after the job's ``prologue``): ``[execution.slurm] python``
    (or ``.pbs``) when given; else, with a ``prologue``, :data:`PROLOGUE_PYTHON` as the prologue's environment
    finds it on PATH (the environment the user configured, never a path of the login node's); else the
    driver's own interpreter, by its path (the same path must exist on the compute nodes)."""
    if jobs.python:
        return jobs.python
    return PROLOGUE_PYTHON if jobs.prologue else sys.executable


@dataclass(frozen=True)
class JobShape:
    """How many batch jobs, of how many single-threaded workers (one core each) and how much memory each.

    ``note`` explains a shape other than ``[execution.slurm]`` (or ``.pbs``) ``cores`` and ``memory`` (""
    when none): a worker count (``[execution] workers`` or ``--workers``) that ``cores`` does not divide."""

    jobs: int
    workers_per_job: int
    memory: str
    note: str = ""

    @property
    def workers(self) -> int:
        return self.jobs * self.workers_per_job


def job_shape(execution: ExecutionConfig) -> JobShape:
    """The batch jobs of ``execution``: ``jobs`` x ``cores`` workers, or exactly ``[execution] workers``
    (``--workers``) when given: jobs of ``cores`` workers when ``cores`` divides the count, else jobs of the
    largest divisor of the count below ``cores`` (each asking that many cores and its workers' share of
    ``memory``), with a one-line note saying so. Never more or fewer workers than asked."""
    batch = _batch_jobs(execution)
    wanted = execution.workers
    if not wanted:
        return JobShape(batch.jobs, batch.cores, batch.memory)
    per_job = max(size for size in range(1, min(batch.cores, wanted) + 1) if wanted % size == 0)
    if per_job == batch.cores:
        return JobShape(wanted // per_job, per_job, batch.memory)
    memory = f"{batch.memory_per_worker_bytes * per_job // 2**20}MiB"
    return JobShape(wanted // per_job, per_job, memory,
                    f"{wanted} workers: {wanted // per_job} job(s) of {per_job} worker(s) ({per_job} cores, "
                    f"{memory} each) instead of [execution.{execution.cluster}] cores = {batch.cores} (memory "
                    f"{batch.memory}), which does not divide {wanted}")


def _job_options(execution: ExecutionConfig) -> dict:
    """Keyword arguments of dask-jobqueue's job (and cluster) for ``[execution.slurm]`` / ``[execution.pbs]``
    (the TLS options are the caller's): the job's shape (:func:`job_shape`), its interpreter
    (:func:`worker_python`) after the ``prologue``."""
    jobs: BatchJobs = _batch_jobs(execution)
    shape = job_shape(execution)
    environment = {**WORKER_ENVIRONMENT, **case_process_environment()}   # the heap settings, unless the user's
    prologue = [f"export {name}={value}" for name, value in environment.items()] + list(jobs.prologue)
    # each worker's own dashboard on the same host as the scheduler's (default: the compute node's loopback)
    worker_dashboard = f"{execution.dashboard_address.rsplit(':', 1)[0]}:0"
    return dict(cores=shape.workers_per_job, processes=shape.workers_per_job, memory=shape.memory,
                walltime=jobs.walltime, queue=jobs.queue or None, account=jobs.account or None,
                job_name=WORKER_JOB_NAME, job_extra_directives=list(jobs.job_extra), job_script_prologue=prologue,
                interface=jobs.interface or None, python=worker_python(jobs),
                worker_extra_args=["--dashboard-address", worker_dashboard])


def _job_class(kind: str) -> type:
    # dask-jobqueue is an optional extra (moc2dimes[slurm] / [pbs]): imported only for these backends
    from dask_jobqueue.pbs import PBSJob
    from dask_jobqueue.slurm import SLURMJob

    return SLURMJob if kind == "slurm" else PBSJob


def _batch_jobs(execution: ExecutionConfig) -> BatchJobs:
    return execution.slurm if execution.cluster == "slurm" else execution.pbs


def jobqueue_cluster(execution: ExecutionConfig, record: JobRecord | None = None,
                     certificates: RunCertificates | None = None):
    """The SLURMCluster or PBSCluster of ``execution`` (its scheduler runs here, on ``tls://`` only, its
    dashboard on ``[execution] dashboard_address``; no job submitted yet: :func:`start_cluster` scales it);
    its submissions go to ``record`` when given. Without ``certificates`` a per-run certificate is made
    (:func:`run_certificates`; its directory is removed when the cluster object is collected)."""
    # optional extra, as above
    from dask_jobqueue import PBSCluster, SLURMCluster

    made_here = certificates is None
    if certificates is None:
        certificates = run_certificates(execution, _batch_jobs(execution).certificate_directory)
    Cluster = SLURMCluster if execution.cluster == "slurm" else PBSCluster
    job_class = _job_class(execution.cluster)
    # dask-jobqueue annotates ``job_cls`` as a Job instance; it takes the class (its own default is one)
    job_cls = cast(Any, recording_job_class(job_class, record or JobRecord()))
    cluster = Cluster(**_job_options(execution), job_cls=job_cls, security=certificates.security, protocol="tls://",
                      scheduler_options={"dashboard_address": execution.dashboard_address}, silence_logs="error")
    if made_here:      # the certificates live as long as the cluster (the finalizer holds them)
        weakref.finalize(cluster, partial(RunCertificates.close, certificates))
    return cluster


def batch_job_script(execution: ExecutionConfig, scheduler: str = SCHEDULER_PLACEHOLDER) -> str:
    """The job script ``campaign submit`` would give ``sbatch`` / ``qsub`` for ``execution`` (its first job;
    the scheduler's address, known only when it runs, shown as ``scheduler``; the per-run certificate
    directory as :data:`CERTIFICATE_PLACEHOLDER`; any key material elided). Starts and submits nothing."""
    first_worker = f"{'SLURMCluster' if execution.cluster == 'slurm' else 'PBSCluster'}-0"   # as the cluster names it
    job = _job_class(execution.cluster)(scheduler=scheduler, name=first_worker, protocol="tls://",
                                        security=_previewed_security(execution), **_job_options(execution))
    return elide_key_material(job.job_script())


def kubernetes_worker_memory_limit(pod_memory: str) -> int:
    """Bytes of dask's ``--memory-limit`` in a worker pod of ``pod_memory`` (Kubernetes quantity): the pod's
    memory less :func:`~campaign.configuration.execution.kubernetes_headroom_bytes`, so that dask pauses the
    worker (80 %) and its nanny restarts it (95 %) before the kernel kills the pod at its limit."""
    pod_bytes = kubernetes_bytes(pod_memory)
    return pod_bytes - kubernetes_headroom_bytes(pod_bytes)


def kubernetes_tls_secret_name(execution: ExecutionConfig) -> str:
    """Name of the Kubernetes Secret holding the DaskCluster's TLS files (``ca.crt``, ``tls.crt``, ``tls.key``)."""
    return f"{execution.kubernetes.name}-tls"


def _with_tls(spec: dict, execution: ExecutionConfig) -> None:
    """Make the DaskCluster ``spec`` talk TLS only: both pods mount the Secret
    :func:`kubernetes_tls_secret_name` read-only at :data:`KUBERNETES_TLS_MOUNT` and present its certificate;
    the scheduler listens on ``tls://`` only; the workers' scheduler address is ``tls://``; dashboards bind
    the pod's loopback (``kubectl port-forward`` reaches them), so the scheduler's probes open its comm port."""
    pods = execution.kubernetes
    files = [f"--tls-ca-file={KUBERNETES_TLS_MOUNT}/ca.crt", f"--tls-cert={KUBERNETES_TLS_MOUNT}/tls.crt",
             f"--tls-key={KUBERNETES_TLS_MOUNT}/tls.key"]
    volume = {"name": "tls", "secret": {"secretName": kubernetes_tls_secret_name(execution), "defaultMode": 0o400}}
    mount = {"name": "tls", "mountPath": KUBERNETES_TLS_MOUNT, "readOnly": True}
    dashboard_host = execution.dashboard_address.rsplit(":", 1)[0]
    for role in ("scheduler", "worker"):
        pod = spec["spec"][role]["spec"]
        pod["volumes"] = [volume]
        container = pod["containers"][0]
        container["volumeMounts"] = [mount]
        if role == "scheduler":
            container["args"] = ["dask", "scheduler", "--host", "0.0.0.0", "--protocol", "tls",
                                 "--port", str(KUBERNETES_COMM_PORT),
                                 "--dashboard-address", f"{dashboard_host}:8787", *files]
            for probe in ("readinessProbe", "livenessProbe"):
                container[probe] = {key: value for key, value in container[probe].items() if key != "httpGet"}
                container[probe]["tcpSocket"] = {"port": "tcp-comm"}
            if dashboard_host in ("127.0.0.1", "localhost"):   # nothing outside the pod can reach it anyway
                container["ports"] = [port for port in container["ports"] if port["name"] != "http-dashboard"]
                service = spec["spec"]["scheduler"]["service"]
                service["ports"] = [port for port in service["ports"] if port["name"] != "http-dashboard"]
        else:
            arguments = container["args"]
            position = arguments.index("--dashboard")
            arguments[position:position + 3] = ["--dashboard-address", f"{dashboard_host}:8788"]
            arguments += files
            if dashboard_host in ("127.0.0.1", "localhost"):
                container["ports"] = [port for port in container["ports"] if port["name"] != "http-dashboard"]
            address = f"tls://{pods.name}-scheduler.{pods.namespace}.svc.cluster.local:{KUBERNETES_COMM_PORT}"
            container["env"] = [*container["env"], {"name": "DASK_SCHEDULER_ADDRESS", "value": address}]


def kubernetes_cluster_spec(execution: ExecutionConfig, tls: bool = True) -> dict:
    """The DaskCluster resource (a dict, as applied to Kubernetes) of ``[execution.kubernetes]``:
    namespace, image, one single-threaded worker per pod with the pod's CPU and memory as requests and
    limits, and the worker's memory limit below the pod's (:func:`kubernetes_worker_memory_limit`); with
    ``tls`` (default) scheduler and workers talk TLS only, with the files of the Secret
    :func:`kubernetes_tls_secret_name` (a reference: no key material in the spec)."""
    # dask-kubernetes is an optional extra (moc2dimes[kubernetes]): imported only for that backend
    from dask_kubernetes.operator import make_cluster_spec

    pods = execution.kubernetes
    resources = {"requests": {"cpu": pods.cpu, "memory": pods.memory}, "limits": {"cpu": pods.cpu, "memory": pods.memory}}
    spec = make_cluster_spec(name=pods.name, image=pods.image, n_workers=execution.workers or pods.workers,
                             resources=resources, env={**WORKER_ENVIRONMENT, **CASE_PROCESS_ENVIRONMENT},
                             worker_command="dask worker")
    spec["metadata"]["namespace"] = pods.namespace
    worker = spec["spec"]["worker"]["spec"]["containers"][0]
    worker["args"] += ["--nthreads", "1", "--memory-limit", str(kubernetes_worker_memory_limit(pods.memory))]
    if tls:
        _with_tls(spec, execution)
    return spec


def cluster_description(execution: ExecutionConfig) -> tuple[str, str]:
    """What ``campaign submit`` would hand the batch system or Kubernetes for ``execution``: (text, note).
    The text is the job script (slurm, pbs; the scheduler's address, known only when it runs, as
    :data:`SCHEDULER_PLACEHOLDER`) or the DaskCluster resource as JSON (kubernetes); the note says how many.
    Starts and submits nothing."""
    if execution.cluster in ("slurm", "pbs"):
        shape = job_shape(execution)
        return batch_job_script(execution), (f"{shape.jobs} such job(s) of {shape.workers_per_job} single-threaded "
                                             f"worker(s), submitted with {SUBMIT_COMMANDS[execution.cluster]}"
                                             + (f" ({shape.note})" if shape.note else ""))
    if execution.cluster == "kubernetes":
        spec = kubernetes_cluster_spec(execution)
        pods = execution.kubernetes
        limit = kubernetes_worker_memory_limit(pods.memory)
        return elide_key_material(json.dumps(spec, indent=2)), (
            f"{spec['spec']['worker']['replicas']} worker pod(s) of {pods.memory}; dask --memory-limit "
            f"{limit / 2**20:.0f} MiB (pauses at 80 %); TLS files from Secret {kubernetes_tls_secret_name(execution)!r} "
            "(ca.crt, tls.crt, tls.key)")
    if execution.cluster == "scheduler":
        return f"an existing dask scheduler at {execution.scheduler}", "its workers are started by whoever runs it"
    return (f"an embedded LocalCluster of {execution.workers or default_worker_count()} single-threaded worker "
            f"processes, memory_limit {execution.memory_limit} each"), "no job script: the workers run here"


class Closable(Protocol):
    """A cluster this process started (LocalCluster, a dask-jobqueue or Kubernetes cluster): closed after the run."""

    def close(self) -> Any: ...


class _BatchCluster:
    """A dask-jobqueue cluster and the run's certificate directory: closing it cancels the jobs, then removes
    the directory."""

    def __init__(self, cluster, certificates: RunCertificates):
        self.cluster = cluster
        self.certificates = certificates

    def close(self) -> None:
        try:
            self.cluster.close()
        finally:
            self.certificates.remove()


def _batch_cluster(execution: ExecutionConfig, quiet: bool) -> tuple[Client, Closable]:
    """Submit the jobs and wait for their first worker (campaign.run.batch_jobs: a dead batch job stops
    the run in one line); the jobs are cancelled (and the run's certificate removed) when anything fails."""
    require_submit_command(execution.cluster)
    record = JobRecord()
    jobs = _batch_jobs(execution)
    certificates = run_certificates(execution, jobs.certificate_directory)
    try:
        cluster = jobqueue_cluster(execution, record, certificates)
    except BaseException:
        certificates.remove()
        raise
    closable = _BatchCluster(cluster, certificates)
    shape = job_shape(execution)
    if shape.note and not quiet:
        print(f"campaign: note: {shape.note}", file=sys.stderr, flush=True)
    try:
        cluster.scale(jobs=shape.jobs)
        client = Client(cluster)
        try:
            wait_for_first_worker(cluster, execution.cluster, record, execution.no_workers_timeout_s)
        except BaseException:
            _quietly(client.close)
            raise
    except BaseException:
        _quietly(closable.close)
        raise
    if not quiet:
        print(f"{execution.cluster} jobs: {', '.join(record.submitted)}", flush=True)
    if record.rejected:      # the run goes on with the other jobs' workers, but says so
        print(f"campaign: note: {len(record.rejected)} of {len(cluster.worker_spec)} {execution.cluster} jobs were "
              f"not submitted; first: {record.rejected[0]}", file=sys.stderr, flush=True)
    return client, closable


def _kubernetes_cluster(execution: ExecutionConfig):
    """The KubeCluster of ``execution``; no Kubernetes credentials or API: one line (RunStopped)."""
    # optional extra moc2dimes[kubernetes] (and its kr8s client): imported only for this backend
    import kr8s
    from dask_kubernetes.operator import KubeCluster

    try:
        kr8s.api()      # credentials first: a KubeCluster that fails later leaves an exit-time traceback
        # dask-kubernetes' KubeCluster connects to its scheduler over tcp:// and takes no TLS settings: the
        # cluster it starts talks plain TCP inside the Kubernetes network (docs/campaigns.md, Security)
        print("campaign: warning: the kubernetes backend's scheduler talks plain TCP inside the Kubernetes network "
              "(dask-kubernetes' KubeCluster takes no TLS settings): any pod that reaches its service can run code "
              "as this run; for TLS apply the spec of campaign cluster FILE and use --scheduler tls://",
              file=sys.stderr, flush=True)
        return KubeCluster(custom_cluster_spec=kubernetes_cluster_spec(execution, tls=False),
                           namespace=execution.kubernetes.namespace, shutdown_on_close=True, quiet=True)
    except Exception as exc:   # kr8s and the operator raise ValueError, kr8s.ServerError, OSError ...
        raise RunStopped(f"cannot start the Kubernetes cluster ({_first_line(exc)}); check the credentials "
                         "(KUBECONFIG, ~/.kube/config or the pod's service account), the namespace "
                         f"{execution.kubernetes.namespace!r} and the dask-kubernetes operator; "
                         "nothing was run or changed") from None


def case_worker_pre_spawn_environ(environ: Mapping[str, str] | None = None) -> dict[str, Any]:
    """dask's ``distributed.nanny.pre-spawn-environ`` for the campaign's embedded workers: the configured one
    (a user's dask configuration stands) with the heap settings of :func:`simulator.heap.case_process_environment`
    (glibc's mmap and trim thresholds in place of dask's 64 KiB trim threshold, one malloc arena), except what
    the user set in ``environ`` (default: this process's environment, which the nanny prefers anyway) or in the
    configuration."""
    environ = os.environ if environ is None else environ
    configured = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    # what the nanny would give a worker without us: the environment first, then the configuration
    inherited = {**{name: str(value) for name, value in configured.items() if value is not None}, **environ}
    return {**configured, **case_process_environment(inherited)}


@contextmanager
def case_worker_heap() -> Iterator[None]:
    """Worker processes spawned inside (by a nanny created inside) start with the heap settings of
    :func:`case_worker_pre_spawn_environ`.

    The nanny keeps its pre-spawn environment, so a worker it restarts gets the same. A nanny writes that
    environment into this process's own before it spawns (dask's behaviour): the variables are put back as
    they were when the block ends. dask's own trim threshold left here by an earlier cluster's nanny is taken
    out meanwhile (the nanny would prefer it to its configuration)."""
    saved = {name: os.environ.get(name) for name in CASE_PROCESS_ENVIRONMENT}
    if not users_thresholds(os.environ) and os.environ.get("MALLOC_TRIM_THRESHOLD_") == DASK_NANNY_TRIM_THRESHOLD:
        del os.environ["MALLOC_TRIM_THRESHOLD_"]
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": case_worker_pre_spawn_environ()}):
            yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def start_cluster(execution: ExecutionConfig, quiet: bool = False) -> tuple[Client, Closable | None]:
    """Connect to the cluster of ``execution``; return the client and the cluster object this process
    started (None for an existing scheduler). Prints the dashboard link unless ``quiet``."""
    require_backend(execution)
    for variable, value in SINGLE_THREAD_ENVIRONMENT.items():
        os.environ.setdefault(variable, value)   # one thread per worker process: idle BLAS threads stall on 2 cores
    cluster: Closable | None = None
    if execution.cluster == "scheduler":
        if execution.plain_tcp_to_another_host:
            print(f"campaign: warning: {execution.scheduler} is plain TCP to another host: anyone who can reach that "
                  "port can run code as the scheduler's workers and read or cancel this run; use tls:// with "
                  "[execution] tls_ca_file, tls_cert_file, tls_key_file", file=sys.stderr, flush=True)
        try:
            client = Client(execution.scheduler, timeout=f"{execution.connect_timeout_s}s",
                            security=user_security(execution))
        except (OSError, TimeoutError) as exc:
            raise RunStopped(f"cannot reach the dask scheduler {execution.scheduler} within "
                             f"{execution.connect_timeout_s:g} s ({_first_line(exc)}); start it, check the address, "
                             "or raise [execution] connect_timeout_s; nothing was run or changed") from None
    elif execution.cluster == "local":
        # a stop signal while the workers start is raised once the cluster is whole (below, where it is closed)
        with held(deliver=False), workers_ignore_stop_signals(), dask.config.set(LOCAL_WORKER_DASK_CONFIG), \
                case_worker_heap():
            cluster = LocalCluster(n_workers=execution.workers or default_worker_count(), threads_per_worker=1,
                                   processes=True, memory_limit=execution.memory_limit,
                                   dashboard_address=execution.dashboard_address, host="127.0.0.1", silence_logs=DRIVER_LOG_LEVEL)
    elif execution.cluster in ("slurm", "pbs"):
        client, cluster = _batch_cluster(execution, quiet)
    else:
        cluster = _kubernetes_cluster(execution)
    if cluster is not None and execution.cluster not in ("slurm", "pbs"):
        try:
            raise_pending()
            client = Client(cluster)
        except BaseException:
            cluster.close()
            raise
    try:
        client.register_plugin(CaseWorkerSetup())       # present and future workers
    except BaseException:
        _quietly(client.close)
        if cluster is not None:
            _quietly(cluster.close)
        raise
    if not quiet:
        print(f"dask dashboard: {client.dashboard_link}  scheduler: {client.scheduler.address}  "
              f"cluster: {execution.cluster}", flush=True)
    return client, cluster


@contextmanager
def connected_client(execution: ExecutionConfig, quiet: bool = False) -> Iterator[Client]:
    """:func:`start_cluster` for the duration of a ``with`` block; a cluster started here is closed after
    (batch jobs cancelled, pods deleted)."""
    loggers = [logging.getLogger(name) for name in ["distributed", *logging.root.manager.loggerDict]
               if name == "distributed" or name.startswith("distributed.")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:               # a lost scheduler or worker is reported as one line (campaign.run.dask_runner)
        logger.setLevel(max(logger.level, DRIVER_LOG_LEVEL))
    try:
        client, cluster = start_cluster(execution, quiet)
        try:
            yield client
        finally:
            with held():                # the cluster is closed whole, whatever arrives meanwhile
                _quietly(client.close)
                if cluster is not None:
                    _quietly(cluster.close)
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _quietly(close) -> None:
    """Close a client or cluster whose scheduler may be gone: what matters then is the run's own message."""
    try:
        close()
    except Exception:   # a closing error after a stopped run must not replace its one line
        pass
