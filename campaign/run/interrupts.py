"""What ends a campaign run from outside, and how it ends: the same way for every stop signal.

``SIGINT`` (Ctrl-C), ``SIGTERM`` (``timeout``, ``kill``, cron, systemd, SLURM's ``scancel``) and ``SIGHUP``
(the terminal closed) end ``campaign submit`` and ``campaign sweep`` alike (:func:`stop_signals`, installed
by :func:`campaign.cli.main` around every command):

- the first signal raises :class:`Interrupted` (a :class:`KeyboardInterrupt`) in the main thread, so the run
  unwinds as it does for Ctrl-C: the remaining tasks are dropped, the cluster is closed (worker processes
  stopped and joined), the temporary files of writes the stop cut short are removed from ``cases/``
  (:func:`remove_temporary_files`) and the store locks released; later signals while it unwinds are
  absorbed (no second traceback in the middle of closing the cluster);
- parts that must not be cut in half defer a signal to their end (:func:`held`): starting the cluster (a
  half-started LocalCluster would leave processes and semaphores behind, which Python's resource_tracker
  then reports as "leaked semaphore objects") and compacting ``results.parquet``;
- the worker processes of an embedded cluster never act on these signals themselves (they reach the whole
  process group): they start with them blocked (:func:`signals_blocked`: the mask is inherited across fork
  and exec) and the driver stops them through dask;
- :func:`campaign.cli.main` prints one line, e.g. ``campaign: interrupted (SIGTERM); 12 finished case files
  kept in runs/gusev (...); `campaign submit my.toml --output runs/gusev` again computes the missing ones``
  (:func:`resume_command`: the user's own command line, re-quoted) and exits ``128 + signal``
  (:func:`exit_code`: 130 SIGINT, 143 SIGTERM, 129 SIGHUP).

A signal whose disposition was ``SIG_IGN`` when the command started stays ignored (``nohup campaign submit``
keeps running when the terminal closes; a background job of a non-interactive shell ignores SIGINT).
"""
from __future__ import annotations

import os
import shlex
import shutil
import signal
import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
TEMPORARY_PREFIX = ".tmp-"      # campaign.store.case_files.TEMPORARY_PREFIX (not imported: kept import-light)


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived: raised in the main thread (the first one only); ``signal_number`` says which."""

    def __init__(self, signal_number: int):
        super().__init__(signal_number)
        self.signal_number = signal_number

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signal_number).name


class _State:
    """The stop signals' state of this process (module singleton :data:`_STATE`)."""

    def __init__(self) -> None:
        self.installed = False
        self.holds = 0                   # nesting depth of held()
        self.pending: int | None = None  # a signal received while held, not raised yet
        self.raised = False              # the one Interrupted of this command was raised


_STATE = _State()


def _on_signal(signal_number: int, frame) -> None:
    if _STATE.raised or _STATE.pending is not None:
        return                          # the run is already unwinding (or will at the end of the held part)
    if _STATE.holds:
        _STATE.pending = signal_number
        return
    _STATE.raised = True
    raise Interrupted(signal_number)


@contextmanager
def stop_signals() -> Iterator[None]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` in the main thread (module
    docstring); a signal ignored when the block starts stays ignored. Outside the main thread: nothing."""
    if threading.current_thread() is not threading.main_thread() or _STATE.installed:
        yield
        return
    previous = {}
    for number in STOP_SIGNALS:
        handler = signal.getsignal(number)
        if handler is not signal.SIG_IGN:
            previous[number] = signal.signal(number, _on_signal)
    _STATE.installed, _STATE.holds, _STATE.pending, _STATE.raised = True, 0, None, False
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler if handler is not None else signal.SIG_DFL)
        _STATE.installed = False


@contextmanager
def held(deliver: bool = True) -> Iterator[None]:
    """A stop signal arriving inside the block is raised when the block ends (when it ends normally: an
    exception of the block itself wins), or, with ``deliver`` false, by the caller's :func:`raise_pending`
    (e.g. once what the block started is under a ``try`` that closes it); without :func:`stop_signals`
    installed, nothing changes."""
    if not _STATE.installed or threading.current_thread() is not threading.main_thread():
        yield
        return
    _STATE.holds += 1
    try:
        yield
    finally:
        _STATE.holds -= 1
    if deliver:
        raise_pending()


def raise_pending() -> None:
    """Raise :class:`Interrupted` now for a signal deferred by :func:`held` (outside every held block)."""
    if _STATE.pending is not None and not _STATE.holds and not _STATE.raised:
        number, _STATE.pending = _STATE.pending, None
        _STATE.raised = True
        raise Interrupted(number)


def interrupting() -> bool:
    """True once this command was interrupted (e.g. a progress bar then draws no last line)."""
    return _STATE.raised or _STATE.pending is not None


@contextmanager
def signals_blocked() -> Iterator[None]:
    """The stop signals blocked in this thread for the block: every thread and process started inside
    inherits the blocked mask (across fork and exec), so the worker processes of an embedded cluster never
    act on a signal sent to the whole process group; a signal to this process is delivered when the block
    ends (to the handler of :func:`stop_signals`)."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def ignore_stop_signals() -> None:
    """Ignore SIGINT, SIGTERM and SIGHUP in this process (an embedded cluster's worker: the driver stops it
    through dask); outside the main thread nothing can be changed, and nothing is."""
    if threading.current_thread() is threading.main_thread():
        for number in STOP_SIGNALS:
            signal.signal(number, signal.SIG_IGN)


def dask_setup(worker) -> None:
    """dask's worker preload hook (``distributed.worker.preload = ["campaign.run.interrupts"]``, set for the
    embedded cluster by :mod:`campaign.run.cluster`): the worker ignores the stop signals from its start."""
    ignore_stop_signals()


def exit_code(exc: BaseException) -> int:
    """The exit code of an interrupted command: 128 + the signal's number (130 for a plain KeyboardInterrupt)."""
    return 128 + (exc.signal_number if isinstance(exc, Interrupted) else signal.SIGINT)


def signal_label(exc: BaseException) -> str:
    """``" (SIGTERM)"`` for a signal other than SIGINT, else ``""``."""
    if isinstance(exc, Interrupted) and exc.signal_number != signal.SIGINT:
        return f" ({exc.signal_name})"
    return ""


def program_words(argv: list[str] | None = None, orig_argv: list[str] | None = None) -> list[str]:
    """How the user started this program, as words to run again: ``campaign`` for the installed command
    found on PATH (the path as given otherwise), ``python -m campaign.cli`` (the interpreter and its options
    as typed, from ``sys.orig_argv``) for the module."""
    argv = sys.argv if argv is None else argv
    orig_argv = list(getattr(sys, "orig_argv", [])) if orig_argv is None else orig_argv
    program = argv[0] if argv else "campaign"
    if program.endswith(".py") or program in ("-m", "-c", ""):
        # python [options] -m campaign.cli ARGS: orig_argv ends with ARGS (argv[1:])
        arguments = len(argv) - 1
        prefix = orig_argv[:len(orig_argv) - arguments] if arguments else orig_argv
        if prefix and "-m" in prefix:
            return prefix
        return [sys.executable, "-m", "campaign.cli"]
    name = os.path.basename(program)
    found = shutil.which(name)
    if found is not None and (os.path.realpath(found) == os.path.realpath(program) or _pyenv_shim(found)):
        return [name]
    return [program]


def _pyenv_shim(path: str) -> bool:
    """True for a pyenv shim (``$PYENV_ROOT/shims/NAME``), which runs the same installed command by its name."""
    root = os.environ.get("PYENV_ROOT")
    return root is not None and root != "" and \
        os.path.dirname(os.path.abspath(path)) == os.path.join(os.path.abspath(root), "shims")


def resume_command(arguments: list[str] | None) -> str:
    """The command line that runs this command again, re-quoted (``shlex.join``): the program as the user
    started it (:func:`program_words`) and ``arguments`` (default: ``sys.argv[1:]``, the user's own; a caller
    of :func:`campaign.cli.main` with an explicit list gets ``campaign`` and that list)."""
    if arguments is None:
        return shlex.join([*program_words(), *sys.argv[1:]])
    return shlex.join(["campaign", *arguments])


def remove_temporary_files(stores: Iterable[Path | str]) -> int:
    """Remove the temporary files (``.tmp-*``) that writes cut short by a stop left in the stores' ``cases/``
    and ``examples/`` (call with the stores locked and their workers stopped); return how many were removed."""
    removed = 0
    for directory in (Path(store) / part for store in stores for part in ("cases", "examples")):
        try:
            entries = list(os.scandir(directory))
        except OSError:
            continue
        for entry in entries:
            if entry.name.startswith(TEMPORARY_PREFIX):
                try:
                    os.unlink(entry.path)
                    removed += 1
                except FileNotFoundError:
                    pass
    return removed
