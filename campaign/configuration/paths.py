"""Paths given on the command line or in a campaign file, checked before anything is opened or written.

Every check answers with a one-line :class:`~config_tables.errors.ConfigError` naming the flag (or
file and field), the path and what is allowed:

* an empty path (``--output ""`` would otherwise mean the working directory);
* a name longer than the file system takes (255 bytes per name, 4095 in all on Linux);
* an input that is not a regular file: a FIFO (opening it would block until a writer comes), a character
  or block device (``/dev/zero`` never ends), a socket, or a symbolic link to nothing;
* an output directory that is a file, a dangling symbolic link, below a file, or on a read-only or
  unwritable file system (checked on its nearest existing ancestor with ``access(2)``, which reports
  ``EROFS`` even for root).

:func:`special_kind` uses ``stat``/``lstat`` only, never ``open``.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from config_tables.errors import ConfigError

NAME_MAX_BYTES = 255     # one name (Linux, most file systems)
PATH_MAX_BYTES = 4095    # a whole path

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def special_kind(path: str | Path) -> str | None:
    """What ``path`` is when it is neither a regular file nor a directory ("a FIFO (named pipe)", "a
    character device", "a block device", "a socket", "a symbolic link to a missing path"); None for a
    regular file, a directory or a path that does not exist. Never opens the path."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "a symbolic link to a missing path" if os.path.islink(path) else None
    except (OSError, ValueError):
        return None         # ELOOP, ENAMETOOLONG, NUL byte, ...: the reader's own message names it
    return next((name for test, name in _KINDS if test(mode)), None)


def check_path_text(path: str | Path, label: str) -> None:
    """Refuse an empty path and names too long for the file system."""
    text = os.fspath(path)
    if text == "":
        raise ConfigError(f"{label} = '' is empty; allowed: a path")
    encoded = os.fsencode(text)
    longest = max((len(part) for part in encoded.split(b"/")), default=0)
    if longest > NAME_MAX_BYTES or len(encoded) > PATH_MAX_BYTES:
        raise ConfigError(f"{label} = {text[:40]!r}... ({len(encoded)} bytes, longest name {longest}) is too long; "
                          f"allowed: names of at most {NAME_MAX_BYTES} bytes, {PATH_MAX_BYTES} bytes in all")


def check_input_file(path: str | Path, label: str) -> None:
    """An input file: a sensible path that is not a special file (see :func:`special_kind`)."""
    check_path_text(path, label)
    kind = special_kind(path)
    if kind is not None:
        raise ConfigError(f"{label} = {os.fspath(path)!r} is {kind}; allowed: a regular file")


def check_output_dir(path: str | Path, label: str) -> None:
    """A directory to create or write into: a sensible path, a directory if it exists, and its nearest
    existing ancestor a writable directory."""
    check_path_text(path, label)
    kind = special_kind(path)
    target = Path(path)
    if kind is not None or (target.exists() and not target.is_dir()):
        raise ConfigError(f"{label} = {os.fspath(path)!r} is {kind or 'a file'}; allowed: a directory (new or existing)")
    existing = target if target.exists() else next((parent for parent in target.absolute().parents
                                                    if os.path.lexists(parent)), Path("/"))
    if not existing.is_dir():
        raise ConfigError(f"{label} = {os.fspath(path)!r} lies below {str(existing)!r}, which is not a directory; "
                          "allowed: a directory (new or existing)")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ConfigError(f"{label} = {os.fspath(path)!r}: {str(existing)!r} is read-only or not writable; allowed: "
                          "a directory you can write to")
