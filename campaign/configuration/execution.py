"""The ``[execution]`` table: where and how a campaign's cases run (never part of the configuration hash).

``cluster`` picks the backend (:mod:`campaign.run.cluster`):

- ``"local"`` (default): an embedded LocalCluster of ``workers`` single-threaded processes;
- ``"scheduler"``: an existing dask scheduler at ``scheduler = "tls://host:port"`` (certificate files in
  ``tls_ca_file``, ``tls_cert_file``, ``tls_key_file``) or ``"tcp://host:port"`` (its workers are started
  by whoever runs it);
- ``"slurm"`` / ``"pbs"``: batch jobs through dask-jobqueue, settings in ``[execution.slurm]`` /
  ``[execution.pbs]`` (extra ``moc2dimes[slurm]`` / ``moc2dimes[pbs]``);
- ``"kubernetes"``: worker pods through the dask-kubernetes operator, settings in
  ``[execution.kubernetes]`` (extra ``moc2dimes[kubernetes]``).

The slurm, pbs and kubernetes backends talk TLS (a per-run certificate, or the user's CA in the
``tls_*_file`` fields); every dashboard binds ``dashboard_address`` (default 127.0.0.1, this machine only).

The watch fields (``stall_timeout_s``, ``no_workers_timeout_s``, ``paused_timeout_s``) decide when the
driver stops a run that cannot progress (:mod:`campaign.run.dask_runner`): it then keeps every finished case,
prints one line naming the cause and exits 1; the next ``submit`` runs the unfinished cases.

``cases_per_task`` sets how many cases one dask task runs (0: chosen from the cases and workers,
:func:`campaign.run.dask_runner.cases_per_task`). ``case_mode = "no_op"`` is a test of the orchestration
only: cases are planned, dispatched and written through the real store as rows of the declared schema, but
nothing is rendered or estimated (every row ``valid = false``, ``reason = "no_op"``, no truth). It is the
one ``[execution]`` field in the configuration hash (a no-op store can never be resumed as a real
campaign, nor the reverse), the manifest records it, and ``table`` / ``report`` head their output with
:data:`NO_OP_BANNER`.
"""
from __future__ import annotations

import ipaddress
import re
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, ValidationInfo, field_validator, model_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, StringList, _relative_to_file

SCHEDULER_SCHEMES = ("tcp://", "tls://", "inproc://")
#: host:port for tcp/tls (port 1-65535; host a name, IPv4 or [IPv6]), anything non-empty after inproc://
SCHEDULER_ADDRESS = re.compile(r"^(?:(?:tcp|tls)://(?:[A-Za-z0-9_.-]+|\[[0-9A-Fa-f:.]+\]):"
                               r"(?:[1-9]\d{0,3}|[1-5]\d{4}|6[0-4]\d{3}|65[0-4]\d{2}|655[0-2]\d|6553[0-5])|inproc://.+)$")
#: dashboard address: "host:port" or ":port" (every interface), port 0 = any free port
DASHBOARD_ADDRESS = re.compile(r"^(?:[A-Za-z0-9_.-]+|\[[0-9A-Fa-f:.]+\])?:\d{1,5}$")
LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "[::1]")
MIN_MEMORY_LIMIT_BYTES = 2**20
#: Backends a campaign runs on ([execution] cluster).
Cluster = Literal["local", "scheduler", "slurm", "pbs", "kubernetes"]
#: What a case does ([execution] case_mode): "compute" (render and estimate) or "no_op" (orchestration test).
CaseMode = Literal["compute", "no_op"]
NO_OP_REASON = "no_op"
"""The ``reason`` of every row of a no-op case."""
NO_OP_BANNER = ("NO-OP RUN ([execution] case_mode = \"no_op\", an orchestration test): nothing was rendered or "
                "estimated; these rows are not results")
CASES_PER_TASK_LIMIT = 100_000
"""Largest ``[execution] cases_per_task`` accepted."""
WALLTIME = re.compile(r"^(\d+-)?\d{1,3}:\d{2}(:\d{2})?$")
KUBERNETES_QUANTITY = re.compile(r"^\d+(\.\d+)?(m|k|M|G|T|Ki|Mi|Gi|Ti)?$")
KUBERNETES_NAME = re.compile(r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$")
_QUANTITY_FACTORS = {"": 1, "m": 1e-3, "k": 10**3, "M": 10**6, "G": 10**9, "T": 10**12,
                     "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}
#: memory a worker pod keeps above dask's --memory-limit: this fraction of the pod's memory, at least
#: KUBERNETES_HEADROOM_MIN_BYTES (the nanny process, interpreter and libraries outside dask's accounting)
KUBERNETES_HEADROOM_FRACTION = 0.10
KUBERNETES_HEADROOM_MIN_BYTES = 256 * 2**20
#: smallest worker pod: dask's limit then leaves a case (about 550 MiB) below the 80 % pause threshold
KUBERNETES_MIN_POD_BYTES = 2**30


def kubernetes_bytes(quantity: str) -> int:
    """Bytes of a Kubernetes memory quantity ("2Gi", "512Mi", "1G", "1000")."""
    match = re.match(r"^(\d+(?:\.\d+)?)(\D*)$", quantity)
    if match is None or match.group(2) not in _QUANTITY_FACTORS:
        raise ValueError(f"{quantity!r} is not a Kubernetes quantity")
    return int(float(match.group(1)) * _QUANTITY_FACTORS[match.group(2)])


def kubernetes_headroom_bytes(pod_bytes: int) -> int:
    """Memory of a worker pod of ``pod_bytes`` kept above dask's ``--memory-limit`` (bytes)."""
    return max(int(KUBERNETES_HEADROOM_FRACTION * pod_bytes), KUBERNETES_HEADROOM_MIN_BYTES)


def _readable_file(value: Any, info: ValidationInfo) -> Any:
    """A certificate or key file (relative to the TOML file's directory) that exists and can be read."""
    if value is None or value == "":
        return ""
    path = _relative_to_file(str(value), info)
    try:
        with open(path, "rb") as handle:
            handle.read(1)
    except OSError as exc:
        raise FieldProblem("", f"= {str(value)!r} cannot be read ({exc.strerror}: {path}); allowed: a PEM file "
                           "you can read") from None
    return str(path)


#: A PEM file of [execution] (certificate authority, certificate, private key): must be readable; "" = none.
ReadableFile = Annotated[str, BeforeValidator(_readable_file)]


def scheduler_host(address: str) -> str:
    """The host part of a ``tcp://`` / ``tls://`` scheduler address ("" for others)."""
    if not address.startswith(("tcp://", "tls://")):
        return ""
    return address.split("://", 1)[1].rsplit(":", 1)[0]


def _memory_size(value: str) -> str:
    from dask.utils import parse_bytes

    try:
        size = parse_bytes(value) if value.strip() else 0
    except (ValueError, TypeError, OverflowError):
        size = 0
    if size < MIN_MEMORY_LIMIT_BYTES:
        raise FieldProblem("", f"= {value!r} is not a memory size; allowed: e.g. \"1.5GiB\", \"800MiB\", "
                           "\"2GB\" (>= 1 MiB)")
    return value


class BatchJobs(ConfigModel):
    """``[execution.slurm]`` / ``[execution.pbs]``: the batch jobs that run the workers (dask-jobqueue).

    Each job runs ``cores`` single-threaded worker processes sharing ``memory``; the driver (where
    ``campaign submit`` runs) hosts the scheduler, so it must be reachable from the compute nodes."""

    queue: str = ""
    """Partition (SLURM -p) or queue (PBS -q); "" = the site's default."""
    account: str = ""
    """Account charged (SLURM -A, PBS -A); "" = the user's default."""
    walltime: str = "01:00:00"
    """Wall-time limit of one job, "HH:MM:SS" (SLURM also "D-HH:MM:SS")."""
    cores: int = Field(4, ge=1, le=1024)
    """Cores per job = single-threaded worker processes per job."""
    memory: str = "8GiB"
    """Memory per job, shared by its workers (a case needs about 550 MiB per worker)."""
    jobs: int = Field(1, ge=1, le=10000)
    """Jobs submitted (workers = jobs x cores); ``[execution] workers`` > 0 overrides the worker count."""
    job_extra: StringList = ()
    """Extra scheduler directives, one per entry, e.g. ["--qos=normal"] (SLURM) or ["-l place=scatter"] (PBS)."""
    prologue: StringList = ()
    """Shell lines run in the job before the worker starts, e.g. ["source /home/me/venv/bin/activate"]."""
    interface: str = ""
    """Network interface the scheduler and workers talk on, e.g. "ib0"; "" = the host name's address."""
    python: str = ""
    """Python interpreter of the workers, run after the prologue (a path, or a name the prologue's PATH finds);
    "" = "python3" of the prologue's environment when there is a prologue, else the driver's own by its path
    (which must then exist on the compute nodes)."""
    certificate_directory: str = ""
    """Directory on a file system the compute nodes share, where a run's own TLS certificate and key are
    written for its workers (a private sub-directory, readable only by you, removed after the run);
    "" = the working directory. Unused with [execution] tls_ca_file."""

    @field_validator("walltime")
    @classmethod
    def _walltime(cls, value: str) -> str:
        if not WALLTIME.match(value):
            raise FieldProblem("", f"= {value!r} is not a wall time; allowed: \"HH:MM:SS\" or \"D-HH:MM:SS\"")
        return value

    @field_validator("memory")
    @classmethod
    def _memory(cls, value: str) -> str:
        return _memory_size(value)

    @property
    def memory_per_worker_bytes(self) -> int:
        from dask.utils import parse_bytes

        return parse_bytes(self.memory) // self.cores


class KubernetesPods(ConfigModel):
    """``[execution.kubernetes]``: a DaskCluster resource of the dask-kubernetes operator (scheduler and
    worker pods); the operator must be installed in the Kubernetes cluster."""

    image: str = ""
    """Container image holding moc2dimes and its dependencies (required), e.g. "registry/moc2dimes:0.1"."""
    namespace: str = "default"
    """Namespace of the DaskCluster and its pods."""
    name: str = "moc2dimes"
    """Name of the DaskCluster resource (DNS label)."""
    workers: int = Field(2, ge=1, le=10000)
    """Worker pods (one single-threaded worker each); ``[execution] workers`` > 0 overrides it."""
    cpu: str = "1"
    """CPU request and limit of one worker pod (Kubernetes quantity, e.g. "1", "500m")."""
    memory: str = "2Gi"
    """Memory request and limit of one worker pod (Kubernetes quantity, e.g. "2Gi", at least 1Gi); dask's
    --memory-limit is 10 % (at least 256 MiB) lower, so dask pauses the worker before the pod is killed."""
    allow_plain_tcp: bool = False
    """Let ``campaign submit`` start the DaskCluster itself although its scheduler then speaks plain TCP inside
    the Kubernetes network (dask-kubernetes' KubeCluster takes no TLS settings): only in a namespace no one
    else can reach. Default false: submit refuses, and the TLS way is the spec ``campaign cluster FILE``
    prints, applied with its Secret, then ``campaign submit --scheduler tls://...``."""

    @field_validator("cpu", "memory")
    @classmethod
    def _quantity(cls, value: str) -> str:
        if not KUBERNETES_QUANTITY.match(value):
            raise FieldProblem("", f"= {value!r} is not a Kubernetes quantity; allowed: e.g. \"1\", \"500m\", \"2Gi\"")
        return value

    @field_validator("memory")
    @classmethod
    def _pod_memory(cls, value: str) -> str:
        if kubernetes_bytes(value) < KUBERNETES_MIN_POD_BYTES:
            raise FieldProblem("", f"= {value!r} is too small for a worker pod; allowed: at least \"1Gi\" (a case "
                               "needs about 550 MiB below dask's pause threshold, and 10 % is kept as headroom)")
        return value

    @field_validator("namespace", "name")
    @classmethod
    def _dns_label(cls, value: str) -> str:
        if not KUBERNETES_NAME.match(value):
            raise FieldProblem("", f"= {value!r} is not a Kubernetes name; allowed: lower-case letters, digits "
                               "and '-', at most 63 characters")
        return value


class ExecutionConfig(ConfigModel):
    """``[execution]``: the dask cluster a campaign runs on (command-line flags override it)."""

    cluster: Cluster = "local"
    """Backend: "local" (embedded), "scheduler" (existing scheduler at `scheduler`), "slurm", "pbs",
    "kubernetes" (default "local"; "scheduler" when only `scheduler` is given)."""
    scheduler: str = ""
    """Address of an existing scheduler ("tls://host:port" or "tcp://host:port"), for cluster = "scheduler"."""
    tls_ca_file: ReadableFile = ""
    """PEM certificate authority the scheduler and workers trust (with tls_cert_file and tls_key_file):
    needed for a "tls://" scheduler; for slurm/pbs/kubernetes it replaces the per-run certificate."""
    tls_cert_file: ReadableFile = ""
    """PEM certificate (signed by tls_ca_file) this run's client, scheduler and workers present."""
    tls_key_file: ReadableFile = ""
    """PEM private key of tls_cert_file (never printed or logged)."""
    dashboard_address: str = "127.0.0.1:0"
    """Where the dashboard of a scheduler started here listens: "127.0.0.1:0" (default: this machine
    only, any free port; reach it from elsewhere through an SSH tunnel), ":8787" opts in to every interface."""
    workers: int = Field(0, ge=0, le=1024)
    """Worker processes (0 = local: one per core; slurm/pbs: jobs x cores; kubernetes: its `workers`)."""
    retries: int = Field(1, ge=0, le=10)
    """Attempts after the first for a case whose computation raises."""
    memory_limit: str = "1.5GiB"
    """Memory limit per worker of the embedded cluster, e.g. "1.5GiB", "800MiB" (a case needs about 550 MiB)."""
    connect_timeout_s: float = Field(30.0, ge=1.0, le=3600.0)
    """Give up connecting to an existing scheduler (cluster = "scheduler") after this long (s)."""
    stall_timeout_s: float = Field(900.0, ge=1.0, le=7 * 86400.0)
    """Stop the run when no case has finished for this long while workers are up (s)."""
    no_workers_timeout_s: float = Field(300.0, ge=1.0, le=7 * 86400.0)
    """Stop the run when the scheduler has had no worker for this long (s); for slurm/pbs/kubernetes it
    must cover the wait for jobs or pods to start (a rejected job, or a SLURM job that ended or can never
    start, stops the run at once: campaign.run.batch_jobs)."""
    paused_timeout_s: float = Field(20.0, ge=1.0, le=86400.0)
    """Stop the run when every worker has been paused at its memory limit, with no case finishing, for this long (s)."""
    cases_per_task: int = Field(0, ge=0, le=CASES_PER_TASK_LIMIT)
    """Cases one dask task runs, one after the other (0 = automatic: a few tasks per worker, at most 64 cases
    per task when computing, 2000 for no-op cases); a task writes its finished cases to the store at least
    every 10 s and when it ends."""
    case_mode: CaseMode = "compute"
    """"compute" (default), or "no_op": an orchestration test that renders and estimates nothing and writes
    rows marked reason = "no_op" (part of the configuration hash; table and report say so on top)."""
    slurm: BatchJobs = BatchJobs()
    """SLURM jobs (cluster = "slurm")."""
    pbs: BatchJobs = BatchJobs()
    """PBS jobs (cluster = "pbs")."""
    kubernetes: KubernetesPods = KubernetesPods()
    """Kubernetes pods (cluster = "kubernetes")."""

    @model_validator(mode="before")
    @classmethod
    def _scheduler_implies_cluster(cls, data):
        if isinstance(data, dict) and data.get("scheduler") and "cluster" not in data:
            return {**data, "cluster": "scheduler"}
        return data

    @field_validator("scheduler")
    @classmethod
    def _address(cls, value: str) -> str:
        if value and not (value.startswith(SCHEDULER_SCHEMES) and SCHEDULER_ADDRESS.match(value)):
            raise FieldProblem("", f"= {value!r} is not a scheduler address; allowed: \"\" (embedded), "
                               "tls://host:port or tcp://host:port")
        return value

    @field_validator("dashboard_address")
    @classmethod
    def _dashboard(cls, value: str) -> str:
        if not DASHBOARD_ADDRESS.match(value) or int(value.rsplit(":", 1)[1]) > 65535:
            raise FieldProblem("", f"= {value!r} is not a dashboard address; allowed: \"127.0.0.1:0\" (default), "
                               "\"host:port\" or \":port\" (every interface)")
        return value

    @field_validator("memory_limit")
    @classmethod
    def _memory(cls, value: str) -> str:
        return _memory_size(value)

    @model_validator(mode="after")
    def _backend_is_complete(self):
        if self.cluster == "scheduler" and not self.scheduler:
            raise FieldProblem("scheduler", "is missing; cluster = \"scheduler\" needs scheduler = \"tcp://host:port\"")
        if self.cluster != "scheduler" and self.scheduler:
            raise FieldProblem("scheduler", f"= {self.scheduler!r} is only used with cluster = \"scheduler\"; "
                               f"allowed: \"\" with cluster = {self.cluster!r}")
        files = {"tls_ca_file": self.tls_ca_file, "tls_cert_file": self.tls_cert_file, "tls_key_file": self.tls_key_file}
        if any(files.values()) and not all(files.values()):
            missing = next(name for name, path in files.items() if not path)
            raise FieldProblem(missing, "is missing; tls_ca_file, tls_cert_file and tls_key_file go together")
        if self.scheduler.startswith("tls://") and not self.tls_ca_file:
            raise FieldProblem("tls_ca_file", f"is missing; scheduler = {self.scheduler!r} needs tls_ca_file, "
                               "tls_cert_file and tls_key_file (PEM files of the scheduler's certificate authority)")
        if self.cluster == "kubernetes" and not self.kubernetes.image:
            raise FieldProblem("kubernetes.image", "is missing; cluster = \"kubernetes\" needs the container image "
                               "that holds moc2dimes, e.g. \"registry.example.org/moc2dimes:0.1\"")
        return self

    @property
    def plain_tcp_to_another_host(self) -> bool:
        """True when the scheduler is a ``tcp://`` address of a host other than this machine's loopback
        (``localhost``, 127.0.0.0/8, ::1)."""
        if not self.scheduler.startswith("tcp://"):
            return False
        host = scheduler_host(self.scheduler)
        if host in LOOPBACK_HOSTS:
            return False
        try:
            return not ipaddress.ip_address(host.strip("[]")).is_loopback
        except ValueError:          # a host name other than localhost
            return True

    @property
    def memory_limit_bytes(self) -> int:
        from dask.utils import parse_bytes

        return parse_bytes(self.memory_limit)

    def with_overrides(self, scheduler: str | None = None, workers: int | None = None) -> ExecutionConfig:
        """This configuration with the command line's ``--scheduler`` (cluster "scheduler") and
        ``--workers`` applied: a validated copy (the table's checks hold for the result too)."""
        update: dict = {}
        if scheduler:
            update.update(cluster="scheduler", scheduler=scheduler)
        if workers:
            update["workers"] = workers
        if not update:
            return self
        return ExecutionConfig.model_validate({**self.model_dump(exclude_unset=True), **update})


def no_op_banner(manifest: dict) -> str | None:
    """:data:`NO_OP_BANNER` when a store's manifest records ``[execution] case_mode = "no_op"``, else None."""
    execution = (manifest.get("config") or {}).get("execution") or {}
    return NO_OP_BANNER if execution.get("case_mode") == "no_op" else None
