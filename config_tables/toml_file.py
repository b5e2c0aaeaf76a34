"""Reading a TOML file: any I/O, encoding or syntax problem is a one-line :class:`ConfigError`.

Uses only the standard library (``tomllib``): validating the parsed tables is :mod:`config_tables.models`.
"""
from __future__ import annotations

import stat
import tomllib
from pathlib import Path
from typing import Any

from config_tables.errors import ConfigError


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file; any I/O, encoding or syntax problem is a one-line :class:`ConfigError`.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict
        The parsed tables.

    Raises
    ------
    ConfigError
        One line naming the file and the problem.
    """
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode) and not path.is_dir():   # a FIFO would block, /dev/zero never ends
            raise ConfigError(f"{path}: is not a regular file (a FIFO, device or socket); allowed: a TOML file")
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except RecursionError:
        raise ConfigError(f"{path}: arrays or inline tables nested too deeply; allowed: the tables of its schema") from None
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory; allowed: a TOML file") from None
    except PermissionError:
        raise ConfigError(f"{path}: cannot be read (permission denied)") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: is not UTF-8 text (byte {exc.start}); allowed: a UTF-8 TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None

