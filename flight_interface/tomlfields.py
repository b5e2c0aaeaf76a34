"""Read typed, range-checked fields out of parsed TOML tables.

Every error is a :class:`ConfigError` whose message is one line naming the file, the dotted field
path and what is allowed, e.g.::

    sitedata/cameras/mer_a.toml: geometry.focal_length_m = -0.01 is out of range; allowed: > 0

Configuration is data: the core never parses text, it receives the typed objects built here.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, Sequence

import numpy as np


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range (one-line message)."""


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file, turning I/O and syntax errors into :class:`ConfigError`."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None


class Table:
    """A view on one TOML table that remembers where it came from (file and dotted path)."""

    def __init__(self, data: dict[str, Any], source: str, path: str = ""):
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: {path or '<root>'} must be a table; got {type(data).__name__}")
        self.data = data
        self.source = source
        self.path = path
        self._read: set[str] = set()
        self._children: list[Table] = []

    def _name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def fail(self, key: str, message: str) -> ConfigError:
        return ConfigError(f"{self.source}: {self._name(key)} {message}")

    def has(self, key: str) -> bool:
        return key in self.data

    def _get(self, key: str, default: Any) -> Any:
        self._read.add(key)
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            raise self.fail(key, "is missing")
        return default

    def table(self, key: str, required: bool = True) -> "Table":
        value = self._get(key, _REQUIRED if required else {})
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a table; got {type(value).__name__}")
        child = Table(value, self.source, self._name(key))
        self._children.append(child)
        return child

    def tables(self, key: str) -> list["Table"]:
        """An array of tables (``[[key]]``), each remembering its index in error messages."""
        value = self._get(key, _REQUIRED)
        if not isinstance(value, list) or not value or not all(isinstance(item, dict) for item in value):
            raise self.fail(key, "must be a non-empty array of tables ([[...]])")
        children = [Table(item, self.source, f"{self._name(key)}[{index}]") for index, item in enumerate(value)]
        self._children.extend(children)
        return children

    def ignore(self, *keys: str) -> None:
        """Mark keys as known without reading them (they are read elsewhere)."""
        self._read.update(keys)

    def reject_unknown(self) -> None:
        """Raise for the first key (here or in any sub-table read through this one) that nothing read."""
        unknown = sorted(set(self.data) - self._read)
        if unknown:
            known = ", ".join(sorted(self._read)) or "none"
            raise ConfigError(f"{self.source}: unknown key {self._name(unknown[0])!r}; allowed here: {known}")
        for child in self._children:
            child.reject_unknown()

    def number(self, key: str, default: Any = None, *, minimum: float | None = None,
               maximum: float | None = None, exclusive_minimum: bool = False,
               exclusive_maximum: bool = False) -> float:
        value = self._get(key, _REQUIRED if default is None else default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"must be a number; got {type(value).__name__} {value!r}")
        value = float(value)
        allowed = _describe_range(minimum, maximum, exclusive_minimum, exclusive_maximum)
        if not math.isfinite(value):
            raise self.fail(key, f"= {value} is not finite; allowed: {allowed}")
        too_low = minimum is not None and (value <= minimum if exclusive_minimum else value < minimum)
        too_high = maximum is not None and (value >= maximum if exclusive_maximum else value > maximum)
        if too_low or too_high:
            raise self.fail(key, f"= {value:g} is out of range; allowed: {allowed}")
        return value

    def integer(self, key: str, default: Any = None, *, minimum: int | None = None,
                maximum: int | None = None) -> int:
        value = self._get(key, _REQUIRED if default is None else default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"must be an integer; got {type(value).__name__} {value!r}")
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            raise self.fail(key, f"= {value} is out of range; allowed: {_describe_range(minimum, maximum)}")
        return value

    def boolean(self, key: str, default: Any = None) -> bool:
        value = self._get(key, _REQUIRED if default is None else default)
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false; got {value!r}")
        return value

    def string(self, key: str, default: Any = None, *, choices: Sequence[str] | None = None) -> str:
        value = self._get(key, _REQUIRED if default is None else default)
        if not isinstance(value, str):
            raise self.fail(key, f"must be a string; got {type(value).__name__} {value!r}")
        if choices is not None and value not in choices:
            raise self.fail(key, f"= {value!r} is not allowed; allowed: {', '.join(choices)}")
        return value

    def vector(self, key: str, length: int, default: Any = None, *, unit_norm: bool = False) -> np.ndarray:
        value = self._get(key, _REQUIRED if default is None else default)
        if (not isinstance(value, list) or len(value) != length
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise self.fail(key, f"must be a list of {length} numbers; got {value!r}")
        array = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(array)):
            raise self.fail(key, f"must be finite; got {value!r}")
        if unit_norm and abs(np.linalg.norm(array) - 1.0) > 1e-6:
            raise self.fail(key, f"must be a unit vector (norm 1 within 1e-6); norm is {np.linalg.norm(array):.9g}")
        return array

    def path_value(self, key: str, base_dir: Path, default: Any = None) -> Path:
        """A path relative to the TOML file's directory."""
        text = self.string(key, default)
        path = Path(text)
        return path if path.is_absolute() else (base_dir / path)


_REQUIRED = object()


def _describe_range(minimum, maximum, exclusive_minimum=False, exclusive_maximum=False) -> str:
    parts = []
    if minimum is not None:
        parts.append(f"{'>' if exclusive_minimum else '>='} {minimum:g}")
    if maximum is not None:
        parts.append(f"{'<' if exclusive_maximum else '<='} {maximum:g}")
    return " and ".join(parts) if parts else "any finite number"
