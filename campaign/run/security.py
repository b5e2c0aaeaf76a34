"""Transport security of the cluster backends: the run's TLS certificate (a per-run self-signed one in a
private directory, or the user's CA from ``[execution]``), key material kept out of anything printed, and
the refusal to start a cluster whose scheduler would speak plain TCP beyond this machine unasked
(docs/campaigns.md, "Security: what a cluster exposes")."""
from __future__ import annotations

import os
import re
import shutil
import tempfile
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from distributed.security import Security

from campaign.configuration.execution import ExecutionConfig
from campaign.run.batch_jobs import NOTHING_RUN
from campaign.run.faults import RunStopped
from config_tables.errors import ConfigError

CERTIFICATE_NAME = "certificate.pem"
KEY_NAME = "key.pem"
#: a PEM block (certificate or key) in text about to be printed
PEM_BLOCK = re.compile(r"-----BEGIN ([A-Z0-9 ]+)-----.*?-----END \1-----", re.DOTALL)


def require_secure_transport(execution: ExecutionConfig, source: str = "[execution]") -> None:
    """Raise a one-line ConfigError when ``campaign submit`` would start a cluster whose scheduler speaks
    plain TCP beyond this machine without the user having said so: the kubernetes backend (dask-kubernetes'
    KubeCluster takes no TLS settings) unless ``[execution.kubernetes] allow_plain_tcp = true``."""
    if execution.cluster == "kubernetes" and not execution.kubernetes.allow_plain_tcp:
        raise ConfigError(f"{source}: execution.cluster = 'kubernetes' would run the scheduler over plain TCP "
                          "(dask-kubernetes' KubeCluster takes no TLS settings): anyone reaching its service could "
                          "run code as this run; allowed: apply the TLS spec of `campaign cluster FILE` with its "
                          "Secret and submit with --scheduler tls://HOST:PORT, or set [execution.kubernetes] "
                          "allow_plain_tcp = true in a namespace no one else can reach")


def elide_key_material(text: str) -> str:
    """``text`` with every PEM block (certificate, private key) replaced by a marker naming its kind."""
    return PEM_BLOCK.sub(lambda match: f"<{match.group(1).lower()} elided>", text)


@dataclass
class RunCertificates:
    """The TLS credentials of one run: ``security`` names PEM files (scheduler, workers and this client all
    present the certificate and trust the CA); ``remove`` deletes the per-run directory (no-op for the user's CA)."""

    security: Security
    directory: Path | None
    remove: Callable[[], Any]

    def close(self) -> None:
        self.remove()


def file_security(ca_file: str, cert_file: str, key_file: str) -> Security:
    """A Security that requires TLS everywhere, every role presenting ``cert_file``/``key_file`` and trusting
    ``ca_file`` (PEM file names: no key material in memory or on a command line)."""
    return Security(require_encryption=True, tls_ca_file=ca_file,
                    tls_client_cert=cert_file, tls_client_key=key_file,
                    tls_scheduler_cert=cert_file, tls_scheduler_key=key_file,
                    tls_worker_cert=cert_file, tls_worker_key=key_file)


def user_security(execution: ExecutionConfig) -> Security | None:
    """The Security of ``[execution] tls_ca_file / tls_cert_file / tls_key_file`` (None when not given)."""
    if not (execution.tls_ca_file and execution.tls_cert_file and execution.tls_key_file):
        return None
    return file_security(str(execution.tls_ca_file), str(execution.tls_cert_file), str(execution.tls_key_file))


def _write_private(path: Path, text: str) -> None:
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "w") as handle:
        handle.write(text)


def run_certificates(execution: ExecutionConfig, directory: str = "") -> RunCertificates:
    """TLS credentials of a run: the user's CA when ``[execution]`` names one, else a new self-signed
    certificate and key (``Security.temporary()``, RSA 2048, valid one year, the CA of nobody else) written to
    a new private directory (mode 0700, files 0600) under ``directory`` ("" = the working directory), where
    the batch jobs' workers read them; :attr:`RunCertificates.remove` deletes it."""
    given = user_security(execution)
    if given is not None:
        return RunCertificates(given, None, lambda: None)
    temporary = Security.temporary()
    worker = temporary.get_tls_config_for_role("worker")
    parent = Path(directory).expanduser() if directory else Path.cwd()
    try:
        private = Path(tempfile.mkdtemp(prefix=".moc2dimes-tls-", dir=parent))        # mode 0700
    except OSError as exc:
        raise RunStopped(f"cannot write the run's TLS certificate under {parent} ({exc.strerror}); set "
                         f"[execution.{execution.cluster}] certificate_directory to a directory you can write "
                         f"that the compute nodes share; {NOTHING_RUN}") from None
    remove = partial(shutil.rmtree, private, ignore_errors=True)
    try:
        _write_private(private / CERTIFICATE_NAME, worker["cert"])
        _write_private(private / KEY_NAME, worker["key"])
    except BaseException:
        remove()
        raise
    certificate, key = str(private / CERTIFICATE_NAME), str(private / KEY_NAME)
    certificates = RunCertificates(file_security(certificate, certificate, key), private, remove)
    certificates.remove = weakref.finalize(certificates, remove)      # once, at the latest when collected
    return certificates
