"""Cluster backends of ``[execution] cluster``: where a campaign's dask workers come from.

``local``       an embedded LocalCluster of single-threaded worker processes (``workers``, ``memory_limit``)
``scheduler``   an existing scheduler (``scheduler = "tcp://host:port"`` or ``--scheduler``)
``slurm``       SLURM batch jobs (dask-jobqueue's SLURMCluster; ``[execution.slurm]``; extra ``moc2dimes[slurm]``)
``pbs``         PBS batch jobs (dask-jobqueue's PBSCluster; ``[execution.pbs]``; extra ``moc2dimes[pbs]``)
``kubernetes``  scheduler and worker pods of a DaskCluster resource (dask-kubernetes' operator
                KubeCluster; ``[execution.kubernetes]``; extra ``moc2dimes[kubernetes]``)

Every worker runs one thread (a case is one CPU-bound task; BLAS and OpenCV threads are pinned to 1).
The optional packages are imported only for their backend; a missing one is a one-line
:class:`~flight_interface.tomlfields.ConfigError` naming the pip extra, raised by
:func:`require_backend` before anything is written.
"""
from __future__ import annotations

import importlib
import logging
import os
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from dask.distributed import Client, LocalCluster

from campaign.configuration.execution import BatchJobs, ExecutionConfig
from campaign.run.faults import RunStopped
from flight_interface.tomlfields import ConfigError

#: backend -> (module it needs, pip distribution, extra of moc2dimes)
OPTIONAL_BACKENDS = {"slurm": ("dask_jobqueue", "dask-jobqueue", "slurm"),
                     "pbs": ("dask_jobqueue", "dask-jobqueue", "pbs"),
                     "kubernetes": ("dask_kubernetes", "dask-kubernetes", "kubernetes")}
SINGLE_THREAD_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
WORKER_JOB_NAME = "moc2dimes-worker"
#: distributed's own log records on the driver during a run (the runner reports problems as one line;
#: M2D_DASK_LOG_LEVEL=20 shows them, e.g. to debug a cluster)
DRIVER_LOG_LEVEL = int(os.environ.get("M2D_DASK_LOG_LEVEL", logging.CRITICAL))
_QUANTITY_FACTORS = {"": 1, "k": 10**3, "M": 10**6, "G": 10**9, "T": 10**12,
                     "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}


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


def default_worker_count() -> int:
    return max(1, os.cpu_count() or 1)


def jobqueue_cluster(execution: ExecutionConfig):
    """The SLURMCluster or PBSCluster of ``execution`` (its scheduler runs here; no job submitted yet:
    ``cluster.job_script()`` shows the script, :func:`start_cluster` scales it)."""
    jobs: BatchJobs = execution.slurm if execution.cluster == "slurm" else execution.pbs
    # dask-jobqueue is an optional extra (moc2dimes[slurm] / [pbs]): imported only for these backends
    if execution.cluster == "slurm":
        from dask_jobqueue import SLURMCluster as Cluster
    else:
        from dask_jobqueue import PBSCluster as Cluster
    prologue = [f"export {name}={value}" for name, value in SINGLE_THREAD_ENVIRONMENT.items()] + list(jobs.prologue)
    return Cluster(cores=jobs.cores, processes=jobs.cores, memory=jobs.memory, walltime=jobs.walltime,
                   queue=jobs.queue or None, account=jobs.account or None, job_name=WORKER_JOB_NAME,
                   job_extra_directives=list(jobs.job_extra), job_script_prologue=prologue,
                   interface=jobs.interface or None, python=jobs.python or sys.executable,
                   scheduler_options={"dashboard_address": ":0"}, silence_logs="error")


def kubernetes_bytes(quantity: str) -> int:
    """Bytes of a Kubernetes memory quantity ("2Gi", "512Mi", "1G", "1000")."""
    number, suffix = re.match(r"^(\d+(?:\.\d+)?)(\D*)$", quantity).groups()
    return int(float(number) * _QUANTITY_FACTORS[suffix])


def kubernetes_cluster_spec(execution: ExecutionConfig) -> dict:
    """The DaskCluster resource (a dict, as applied to Kubernetes) of ``[execution.kubernetes]``:
    namespace, image, one single-threaded worker per pod with the pod's CPU and memory as requests and
    limits, and the worker's memory limit equal to the pod's."""
    # dask-kubernetes is an optional extra (moc2dimes[kubernetes]): imported only for that backend
    from dask_kubernetes.operator import make_cluster_spec

    pods = execution.kubernetes
    resources = {"requests": {"cpu": pods.cpu, "memory": pods.memory}, "limits": {"cpu": pods.cpu, "memory": pods.memory}}
    spec = make_cluster_spec(name=pods.name, image=pods.image, n_workers=execution.workers or pods.workers,
                             resources=resources, env=dict(SINGLE_THREAD_ENVIRONMENT), worker_command="dask worker")
    spec["metadata"]["namespace"] = pods.namespace
    worker = spec["spec"]["worker"]["spec"]["containers"][0]
    worker["args"] += ["--nthreads", "1", "--memory-limit", str(kubernetes_bytes(pods.memory))]
    return spec


def start_cluster(execution: ExecutionConfig, quiet: bool = False) -> tuple[Client, object | None]:
    """Connect to the cluster of ``execution``; return the client and the cluster object this process
    started (None for an existing scheduler). Prints the dashboard link unless ``quiet``."""
    require_backend(execution)
    for variable, value in SINGLE_THREAD_ENVIRONMENT.items():
        os.environ.setdefault(variable, value)   # one thread per worker process: idle BLAS threads stall on 2 cores
    cluster = None
    if execution.cluster == "scheduler":
        try:
            client = Client(execution.scheduler, timeout=f"{execution.connect_timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise RunStopped(f"cannot reach the dask scheduler {execution.scheduler} within "
                             f"{execution.connect_timeout_s:g} s ({_first_line(exc)}); start it, check the address, "
                             "or raise [execution] connect_timeout_s; nothing was run or changed") from None
    elif execution.cluster == "local":
        cluster = LocalCluster(n_workers=execution.workers or default_worker_count(), threads_per_worker=1,
                               processes=True, memory_limit=execution.memory_limit, dashboard_address="127.0.0.1:0",
                               host="127.0.0.1", silence_logs=DRIVER_LOG_LEVEL)
    elif execution.cluster in ("slurm", "pbs"):
        cluster = jobqueue_cluster(execution)
        jobs = execution.slurm if execution.cluster == "slurm" else execution.pbs
        if execution.workers:
            cluster.scale(n=execution.workers)
        else:
            cluster.scale(jobs=jobs.jobs)
    else:
        # optional extra moc2dimes[kubernetes], as above
        from dask_kubernetes.operator import KubeCluster

        cluster = KubeCluster(custom_cluster_spec=kubernetes_cluster_spec(execution),
                              namespace=execution.kubernetes.namespace, shutdown_on_close=True, quiet=True)
    if cluster is not None:
        try:
            client = Client(cluster)
        except BaseException:
            cluster.close()
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
    except Exception:   # noqa: BLE001 - a closing error after a stopped run must not replace its one line
        pass
