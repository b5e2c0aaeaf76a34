"""One writer per campaign store: an advisory ``fcntl.flock`` on a lock file beside the store.

The lock file is ``DIR.lock`` next to the store directory ``DIR`` (not inside it), so the store can be
moved aside (``--fresh`` renames it to ``DIR.previous-<UTC time>``) while the lock is held. While it
holds the lock, the writer records who it is in the file, one JSON object: host, pid, command line and
start time (UTC); a refused writer prints that in one line.

The lock is the kernel's ``flock`` on the open file, not the file's existence: the kernel releases it
when the holder's last descriptor closes, which includes the holder being killed (``kill -9``, OOM
killer, a crashed driver). A lock left behind by a killed process is therefore free and the next writer
simply takes it over; the stale holder record it finds is overwritten. The file is never removed
(removing a lock file while another process waits on it would let two writers in). On NFS, Linux
emulates ``flock`` with POSIX byte-range locks, which the NFS lock manager shares between hosts.
"""
from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from pathlib import Path

WAIT_POLL_S = 0.2


class StoreBusy(RuntimeError):
    """Another process holds the store's lock (one-line message naming it); exit code 1."""


def lock_path_for(store_root: Path) -> Path:
    """``DIR.lock`` beside the store directory ``DIR``."""
    store_root = Path(os.path.abspath(store_root))      # "." and "" name the working directory
    return store_root.with_name(store_root.name + ".lock")


def _command_line() -> str:
    try:
        with open("/proc/self/cmdline", "rb") as handle:
            parts = handle.read().split(b"\0")
        return " ".join(part.decode(errors="replace") for part in parts if part)
    except OSError:
        return " ".join([sys.executable, *sys.argv])


def describe_holder(lock_path: Path) -> str:
    """The holder recorded in a lock file, as text ("an unknown process" while it is being written)."""
    try:
        holder = json.loads(Path(lock_path).read_text() or "null")
    except (OSError, ValueError):
        holder = None
    if not isinstance(holder, dict):
        return "an unknown process (it has not recorded itself yet)"
    return (f"pid {holder.get('pid', '?')} on {holder.get('host', '?')} since {holder.get('started', '?')} "
            f"({holder.get('command', '?')})")


class StoreLock:
    """The exclusive lock of one store; use as a context manager.

    Parameters
    ----------
    store_root
        The store directory (it need not exist; its parent is created).
    wait
        Block until the lock frees instead of raising :class:`StoreBusy`.
    on_wait
        Called once with a one-line message when ``wait`` is set and the lock is busy.
    """

    def __init__(self, store_root: str | Path, wait: bool = False, on_wait=None):
        self.store_root = Path(store_root)
        self.path = lock_path_for(self.store_root)
        self.wait = wait
        self.on_wait = on_wait
        self._descriptor: int | None = None

    def acquire(self) -> StoreLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        announced = False
        while True:
            try:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                holder = describe_holder(self.path)
                if not self.wait:
                    os.close(descriptor)
                    raise StoreBusy(f"{self.store_root}: another writer holds its lock {self.path}: {holder}; "
                                    "pass --wait to wait for it") from None
                if not announced and self.on_wait is not None:
                    self.on_wait(f"{self.store_root}: waiting for the lock held by {holder}")
                announced = True
                time.sleep(WAIT_POLL_S)
        self._descriptor = descriptor
        record = {"host": socket.gethostname(), "pid": os.getpid(), "command": _command_line(),
                  "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, (json.dumps(record) + "\n").encode(), 0)
        os.fsync(descriptor)
        return self

    def release(self) -> None:
        if self._descriptor is None:
            return
        try:
            os.ftruncate(self._descriptor, 0)   # no stale holder record once released
        finally:
            fcntl.flock(self._descriptor, fcntl.LOCK_UN)
            os.close(self._descriptor)
            self._descriptor = None

    def __enter__(self) -> StoreLock:
        return self.acquire()

    def __exit__(self, *exc_info) -> None:
        self.release()
