"""A real single-node SLURM cluster for the tests (Debian's SLURM 22.05: munged, slurmctld, slurmd).

:func:`install_reason` installs the packages when ``sbatch`` is missing and we are root with apt-get
(``apt-get install --no-install-recommends munge slurmctld slurmd slurm-client``, as CI set-up does);
:class:`SlurmNode` then runs a private cluster under a temporary directory: its own munge key and
socket, its own ``slurm.conf`` (``slurm.conf.template`` beside this file; free ports; a node named
``localhost`` at 127.0.0.1 with this machine's CPUs and memory; no cgroups, no accounting), and the
three daemons in the foreground as child processes, each in its own process group. Clients find it
through ``SLURM_CONF`` (:attr:`SlurmNode.environment`); nothing under /etc or /run is used or changed
beyond the package installation, so several such clusters can run side by side.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

TEMPLATE = Path(__file__).with_name("slurm.conf.template")
PACKAGES = ("munge", "slurmctld", "slurmd", "slurm-client")
READY_TIMEOUT_S = 30.0


def install_reason() -> str:
    """"" when sbatch, slurmctld, slurmd and munged are available (installed now if needed and
    possible), else why SLURM cannot be had here (the reason the tests skip with)."""
    needed = ("sbatch", "squeue", "scontrol", "slurmctld", "slurmd", "munged", "munge")
    if all(_which(name) for name in needed):
        return ""
    if os.geteuid() != 0:
        return "SLURM is not installed and installing it needs root (apt-get install munge slurmctld slurmd slurm-client)"
    if shutil.which("apt-get") is None:
        return "SLURM is not installed and there is no apt-get to install it (Debian's munge slurmctld slurmd slurm-client)"
    environment = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for command in (["apt-get", "update", "-qq"],
                    ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *PACKAGES]):
        result = subprocess.run(command, capture_output=True, text=True, env=environment, timeout=600)
        if result.returncode != 0:
            tail = " ".join(result.stderr.strip().splitlines()[-2:])
            return f"installing SLURM failed: {' '.join(command)} exited {result.returncode}: {tail}"
    missing = [name for name in needed if not _which(name)]
    return f"SLURM installed but {', '.join(missing)} not found" if missing else ""


def _which(name: str) -> str | None:
    return shutil.which(name) or shutil.which(name, path="/usr/sbin:/sbin:/usr/bin")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def node_resources() -> tuple[int, int]:
    """(CPUs, memory MiB) of this machine as slurmd sees them (``slurmd -C``)."""
    text = subprocess.run([_which("slurmd"), "-C"], capture_output=True, text=True, timeout=30).stdout
    cpus = int(re.search(r"\bCPUs=(\d+)", text).group(1))
    memory = int(re.search(r"\bRealMemory=(\d+)", text).group(1))
    return cpus, memory


class SlurmNode:
    """A running single-node SLURM cluster (partition ``debug``, node ``localhost``)."""

    partition = "debug"

    def __init__(self):
        self.root = Path(tempfile.mkdtemp(prefix="m2d-slurm-"))
        self.root.chmod(0o711)                  # munged (user munge) must reach its socket below
        self.processes: list[subprocess.Popen] = []
        self.cpus, memory_mib = node_resources()
        self.memory_mib = min(memory_mib, 16384)
        try:
            self._start()
        except BaseException:
            self.stop()
            raise

    @property
    def environment(self) -> dict[str, str]:
        return {"SLURM_CONF": str(self.root / "slurm.conf")}

    def run(self, *command: str, check: bool = True) -> subprocess.CompletedProcess:
        """A SLURM client command against this cluster."""
        result = subprocess.run([_which(command[0]), *command[1:]], capture_output=True, text=True, timeout=30,
                                env={**os.environ, **self.environment})
        if check and result.returncode != 0:
            raise RuntimeError(f"{' '.join(command)} exited {result.returncode}: {result.stderr.strip()}")
        return result

    def jobs(self) -> dict[str, tuple[str, str, str]]:
        """Job id -> (name, state, reason) of every job squeue still knows (finished ones included)."""
        text = self.run("squeue", "-h", "-t", "all", "-o", "%i|%j|%T|%r").stdout
        return {parts[0]: (parts[1], parts[2], parts[3])
                for parts in (line.split("|") for line in text.splitlines()) if len(parts) == 4}

    def _start(self) -> None:
        munge_dir = self.root / "munge"
        munge_dir.mkdir(mode=0o711)
        key = munge_dir / "munge.key"
        key.write_bytes(os.urandom(1024))
        key.chmod(0o400)
        shutil.chown(munge_dir, "munge", "munge")
        shutil.chown(key, "munge", "munge")
        for name in ("state", "spool", "logs"):
            (self.root / name).mkdir()
        text = TEMPLATE.read_text().format(
            root=self.root, socket=munge_dir / "munge.socket", controller_port=_free_port(), node_port=_free_port(),
            cpus=self.cpus, memory_mib=self.memory_mib, partition=self.partition)
        (self.root / "slurm.conf").write_text(text)
        self._daemon(["setpriv", "--reuid=munge", "--regid=munge", "--init-groups", _which("munged"), "-F",
                      f"--socket={munge_dir / 'munge.socket'}", f"--key-file={key}",
                      f"--pid-file={munge_dir / 'munged.pid'}", f"--log-file={munge_dir / 'munged.log'}",
                      f"--seed-file={munge_dir / 'munged.seed'}"], "munged")
        self._wait(lambda: (munge_dir / "munge.socket").exists(), "munged did not create its socket")
        self._daemon([_which("slurmctld"), "-D", "-i"], "slurmctld")
        self._wait(lambda: "UP" in self.run("scontrol", "ping", check=False).stdout, "slurmctld does not answer ping")
        self._daemon([_which("slurmd"), "-D", "-N", "localhost"], "slurmd")
        self._wait(lambda: self.run("sinfo", "-h", "-o", "%T", check=False).stdout.strip() == "idle",
                   "the node does not become idle")

    def _daemon(self, command: list[str], name: str) -> None:
        log = (self.root / "logs" / f"{name}.out").open("w")
        self.processes.append(subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=self.root,
                                               env={**os.environ, **self.environment}, start_new_session=True))
        log.close()

    def _wait(self, ready, what: str) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            if any(process.poll() is not None for process in self.processes):
                break
            if ready():
                return
            time.sleep(0.1)
        logs = " | ".join(f"{path.name}: {' '.join(path.read_text(errors='replace').split()[-30:])}"
                          for path in sorted((self.root / "logs").glob("*.out")))
        raise RuntimeError(f"SLURM set-up: {what} within {READY_TIMEOUT_S:g} s; {logs}")

    def stop(self) -> None:
        """Cancel every job, stop the daemons (ours, by process group) and remove the directory."""
        if self.processes:
            try:
                self.run("scancel", "--full", "-u", "root", check=False)   # every job of this private cluster
            except subprocess.TimeoutExpired:
                pass                                                     # the daemons are stopped below anyway
        for process in reversed(self.processes):
            try:
                os.killpg(process.pid, signal.SIGTERM)
            except ProcessLookupError:
                continue
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
        self.processes.clear()
        shutil.rmtree(self.root, ignore_errors=True)
