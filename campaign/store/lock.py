"""One writer per campaign store: an advisory ``fcntl.flock`` on a lock file beside the store.

The lock file is ``DIR.lock`` next to the store directory ``DIR`` (not inside it), so the store can be
moved aside (``--fresh`` renames it to ``DIR.previous-<UTC time>``) while the lock is held. While it
holds the lock, the writer records who it is in the file, one JSON object: host, pid, command line and
start time (UTC); a refused writer prints that in one line.

The lock is the kernel's ``flock`` on the open file, not the file's existence: the kernel releases it
when the holder's last descriptor closes, which includes the holder being killed (``kill -9``, OOM
killer, a crashed driver). A lock left behind by a killed process is therefore free and the next writer
simply takes it over; the stale holder record it finds is overwritten. The file is never removed
(removing a lock file while another process waits on it would let two writers in).

Deleting ``DIR.lock`` does not let a second writer in: the writer also holds a ``flock`` on the store
directory ``DIR`` itself for the run's life (taken with the file lock when ``DIR`` exists, else as soon as
:meth:`CampaignStore.prepare` creates it and before it writes anything; taken again on the new ``DIR``
after ``--fresh`` moved the old one aside). A second writer that gets a fresh ``DIR.lock`` finds the
directory locked and is refused (or waits with ``--wait``) with a line naming the holder's pid (from
``/proc/locks``). A file system that cannot ``flock`` a directory (some NFS set-ups) falls back to the
lock file alone. On NFS, Linux emulates ``flock`` with POSIX byte-range locks, which the NFS lock
manager shares between hosts.
"""
from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Callable
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


def directory_holder(directory: Path) -> str:
    """"pid N" of the process holding a ``flock`` on ``directory`` (from ``/proc/locks``), else "another
    process"."""
    try:
        inode = os.stat(directory).st_ino
        with open("/proc/locks") as handle:
            lines = handle.read().splitlines()
    except OSError:
        return "another process"
    for line in lines:
        fields = line.split()
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5].rsplit(":", 1)[-1] == str(inode):
            return f"pid {fields[4]}"
    return "another process"


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
        self._directory_descriptor: int | None = None

    @property
    def held(self) -> bool:
        return self._descriptor is not None

    def acquire(self) -> StoreLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        self._flock_or_wait(descriptor, lambda: describe_holder(self.path),
                            lambda holder: f"{self.store_root}: another writer holds its lock {self.path}: {holder}",
                            lambda holder: f"{self.store_root}: waiting for the lock held by {holder}")
        self._descriptor = descriptor
        try:
            self.hold_store_directory()
        except BaseException:
            self.release()
            raise
        record = {"host": socket.gethostname(), "pid": os.getpid(), "command": _command_line(),
                  "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, (json.dumps(record) + "\n").encode(), 0)
        os.fsync(descriptor)
        return self

    def hold_store_directory(self) -> None:
        """Hold the ``flock`` of the store directory (when it exists; again on a new directory of the same
        name after the old one was moved aside). Call it while holding the lock file.

        Raises
        ------
        StoreBusy
            Another process holds the directory's lock (its lock file was removed or replaced), unless
            ``wait``: then this waits for it.
        """
        root = Path(os.path.abspath(self.store_root))
        try:
            descriptor = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
        except (FileNotFoundError, NotADirectoryError):
            return
        if self._directory_descriptor is not None:
            if os.path.samestat(os.fstat(self._directory_descriptor), os.fstat(descriptor)):
                os.close(descriptor)
                return
            self._release_directory()          # the directory we held was moved aside
        try:
            self._flock_or_wait(descriptor, lambda: directory_holder(root),
                                lambda holder: f"{root}: another writer ({holder}) holds the lock of the store "
                                               f"directory itself, although {self.path} was free (it was removed or "
                                               "replaced while held)",
                                lambda holder: f"{root}: waiting for the store directory's lock held by {holder}")
        except OSError:                        # no flock on directories here (some NFS): the file lock alone
            os.close(descriptor)
            return
        self._directory_descriptor = descriptor

    def _flock_or_wait(self, descriptor: int, holder: Callable[[], str], busy: Callable[[str], str],
                       waiting: Callable[[str], str]) -> None:
        """Take the exclusive ``flock`` of ``descriptor``; when another process holds it, raise
        :class:`StoreBusy` (``busy(holder)`` + the --wait hint; the descriptor closed) or, with ``wait``,
        say ``waiting(holder)`` once and poll every :data:`WAIT_POLL_S` seconds."""
        announced = False
        while True:
            try:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return
            except BlockingIOError:
                current = holder()
                if not self.wait:
                    os.close(descriptor)
                    raise StoreBusy(f"{busy(current)}; pass --wait to wait for it") from None
                if not announced and self.on_wait is not None:
                    self.on_wait(waiting(current))
                announced = True
                time.sleep(WAIT_POLL_S)

    def _release_directory(self) -> None:
        if self._directory_descriptor is not None:
            try:
                fcntl.flock(self._directory_descriptor, fcntl.LOCK_UN)
            finally:
                os.close(self._directory_descriptor)
                self._directory_descriptor = None

    def release(self) -> None:
        self._release_directory()
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
