"""A campaign file built on a base file: ``base = "gusev"`` or ``base = "../sites/mine.toml"``.

A campaign (or site) TOML may name, at its top level, the file it builds on::

    base = "gusev"                      # a shipped site: sitedata/gusev.toml of the installed package
    # base = "../gusev.toml"            # or a TOML file, relative to the file that writes the line

    [campaign]
    output_dir = "runs/mine"            # only what differs from the base

The file's tables are laid over its base's (:func:`layered_data`), and a base may have a base of its own
(at most :data:`MAX_BASES` deep; a chain that comes back to one of its files is refused). Merging:

* a table (``[name]``, ``[a.b]`` or an inline ``{...}``) merges key by key, at every depth: the file's
  keys replace the base's, the base's other keys stay;
* an array (``[1, 2]``, and an array of tables such as ``[[site.classes]]`` or ``[[estimators]]``) and every
  other value is replaced whole: an array is never merged element by element;
* a key cannot be removed, only given another value.

A value without ``/`` and without the ``.toml`` suffix names a *shipped* site (:func:`shipped_sites`: the
stems of ``sitedata/*.toml`` in the installed package, e.g. ``gusev``, ``meridiani``); any other value is
a path, relative to the directory of the file that writes it.

Every relative path resolves against the file that wrote it: before a base's tables are laid under the
file's, the base's relative file names (:data:`BASE_RELATIVE_PATHS`: ``site.camera``,
``site.trajectory_set``, a file terrain's ``path`` and ``sidecar``, a python estimator's ``path``,
``{config_dir}`` in a command's ``argv``, the ``[execution]`` PEM files) are made absolute against the
base's own directory. ``[campaign] output_dir`` is relative to the working directory in any file.

Errors are one line naming the file that wrote the field at fault (:meth:`LayeredData.attribute`), the
field and what is allowed, e.g. ``sitedata/gusev.toml (base of mine.toml): site.classes[0].cases = -1 is
out of range; allowed: >= 0 and <= 1000000``.
"""
from __future__ import annotations

import copy
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import sitedata
from campaign.configuration.paths import check_input_file
from config_tables.errors import ConfigError
from config_tables.toml_file import load_toml

BASE_KEY = "base"
#: Bases below one file at most (a base of a base ... ).
MAX_BASES = 16
#: Directory of the shipped sites (``sitedata/gusev.toml`` ...), in the installed package.
SHIPPED_SITE_DIR = Path(sitedata.__file__).resolve().parent
#: The file names of a base that are relative to the base's directory (made absolute before merging).
BASE_RELATIVE_PATHS = ("site.camera", "site.trajectory_set", "site.classes[].terrain.path",
                       "site.classes[].terrain.sidecar", "estimators[].path", "estimators[].argv {config_dir}",
                       "execution.tls_ca_file", "execution.tls_cert_file", "execution.tls_key_file")
_FIELD_AT_START = re.compile(r"[A-Za-z_][\w.\[\]-]*")


def shipped_sites() -> list[str]:
    """Names a ``base`` may give for a shipped site: the stems of ``sitedata/*.toml`` (sorted)."""
    return sorted(path.stem for path in SHIPPED_SITE_DIR.glob("*.toml"))


def _names_shipped_site(value: str) -> bool:
    return "/" not in value and os.sep not in value and not value.endswith(".toml")


def resolve_base(value: Any, writer: Path, label: str) -> Path:
    """The file a ``base = value`` written in ``writer`` names (module docstring).

    Parameters
    ----------
    value : Any
        The ``base`` value as parsed.
    writer : Path
        The file that writes it (a relative base is relative to its directory).
    label : str
        Names ``writer`` in errors.

    Returns
    -------
    Path
        The base file (relative to the working directory when ``writer`` is).

    Raises
    ------
    ConfigError
        Not a string, an unknown shipped name, a missing file, or a special file (FIFO, device, ...).
    """
    directory = writer.parent
    allowed = (f"allowed: a shipped site ({', '.join(shipped_sites())}) or a TOML file, relative to "
               f"{str(directory) if str(directory) != '.' else 'the working directory'}")
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{label}: {BASE_KEY} = {value!r} is not a file name; {allowed}")
    if _names_shipped_site(value):
        if value in shipped_sites():
            return SHIPPED_SITE_DIR / f"{value}.toml"
        raise ConfigError(f"{label}: {BASE_KEY} = {value!r} is not a shipped site; {allowed}")
    path = Path(value) if Path(value).is_absolute() else Path(os.path.normpath(directory / value))
    check_input_file(path, f"{label}: {BASE_KEY}")
    if not path.is_file():
        raise ConfigError(f"{label}: {BASE_KEY} = {value!r}: no such file {path}; {allowed}")
    return path


def _absolute(value: Any, directory: Path) -> Any:
    if isinstance(value, str) and value and not Path(value).is_absolute():
        return os.path.abspath(directory / value)
    return value


def rebased(data: dict, directory: Path) -> dict:
    """A deep copy of a base file's ``data`` whose relative file names (:data:`BASE_RELATIVE_PATHS`) are
    absolute against ``directory``, the base file's directory. Values of the wrong type are left for the
    tables' own checks."""
    result = copy.deepcopy(data)
    site = result.get("site")
    if isinstance(site, dict):
        for key in ("camera", "trajectory_set"):
            if key in site:
                site[key] = _absolute(site[key], directory)
        classes = site.get("classes")
        for entry in classes if isinstance(classes, list) else []:
            terrain = entry.get("terrain") if isinstance(entry, dict) else None
            if isinstance(terrain, dict):
                for key in ("path", "sidecar"):
                    if key in terrain:
                        terrain[key] = _absolute(terrain[key], directory)
    estimators = result.get("estimators")
    for entry in estimators if isinstance(estimators, list) else []:
        if not isinstance(entry, dict):
            continue
        if "path" in entry:
            entry["path"] = _absolute(entry["path"], directory)
        if isinstance(entry.get("argv"), list):
            config_dir = os.path.abspath(directory)
            entry["argv"] = [item.replace("{config_dir}", config_dir) if isinstance(item, str) else item
                             for item in entry["argv"]]
    execution = result.get("execution")
    if isinstance(execution, dict):
        for key in ("tls_ca_file", "tls_cert_file", "tls_key_file"):
            if key in execution:
                execution[key] = _absolute(execution[key], directory)
    return result


def _merge(under: dict, over: dict, writer: Path, written_by: dict[str, Path], prefix: str = "") -> dict:
    """``over`` laid on ``under`` (tables key by key, everything else replaced); ``written_by`` records, for
    every key ``over`` sets, the file that wrote it."""
    merged = dict(under)
    for key, value in over.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value, writer, written_by, dotted)
        else:
            for name in [name for name in written_by if name == dotted or name.startswith((f"{dotted}.", f"{dotted}["))]:
                del written_by[name]            # a replaced array or value: nothing below it is the base's any more
            merged[key] = value
            written_by[dotted] = writer
    return merged


def _record(data: dict, writer: Path, written_by: dict[str, Path], prefix: str = "") -> None:
    for key, value in data.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict):
            _record(value, writer, written_by, dotted)
        else:
            written_by[dotted] = writer


@dataclass(frozen=True)
class LayeredData:
    """A campaign file's data with its bases laid under it.

    Attributes
    ----------
    data : dict
        The merged tables, without ``base``; the bases' relative file names made absolute.
    path : Path
        The file itself (its own relative paths resolve against its directory, as without a base).
    label : str
        Names the file in errors.
    chain : tuple of Path
        The file, then its base, the base's base, ...
    written_by : dict
        Dotted field (``site.classes``, ``estimator.min_correlation``) -> the file that wrote it.
    """

    data: dict
    path: Path
    label: str
    chain: tuple[Path, ...] = ()
    written_by: dict[str, Path] = field(default_factory=dict)

    def writer_of(self, dotted: str) -> Path:
        """The file that wrote ``dotted`` (or the table or array holding it): the file itself by default."""
        name = dotted
        while name:
            if name in self.written_by:
                return self.written_by[name]
            cut = max(name.rfind("."), name.rfind("["))
            name = name[:cut] if cut > 0 else ""
        return self.path

    def attribute(self, error: ConfigError) -> ConfigError:
        """``error`` (``"<label>: <field> ..."``) naming the base file that wrote the field, when a base did:
        ``"<base> (base of <label>): <field> ..."``; other errors unchanged."""
        text = str(error)
        if len(self.chain) < 2 or not text.startswith(f"{self.label}: "):
            return error
        rest = text[len(self.label) + 2:]
        found = _FIELD_AT_START.match(rest)
        if found is None:
            return error
        writer = self.writer_of(found.group(0).rstrip("."))
        if writer == self.path:
            return error
        return ConfigError(f"{writer} (base of {self.label}): {rest}")


def layered_data(data: dict, path: Path, label: str) -> LayeredData:
    """``data`` (parsed from ``path``) with the chain of its ``base`` files laid under it (module docstring).

    Parameters
    ----------
    data : dict
        The parsed file (a ``base`` key, if any, at the top level).
    path : Path
        The file ``data`` came from: its ``base`` is relative to its directory.
    label : str
        Names the file in errors.

    Returns
    -------
    LayeredData
        ``data`` itself (without ``base``) when it names no base.

    Raises
    ------
    ConfigError
        One line: a base that is not a file or shipped site, a cycle, a chain deeper than :data:`MAX_BASES`,
        or a base file that cannot be read.
    """
    if BASE_KEY not in data:
        return LayeredData(data, path, label, (path,))
    layers = [({key: value for key, value in data.items() if key != BASE_KEY}, path)]
    chain, current, writer, writer_label = [path], data, path, label
    while BASE_KEY in current:
        base = resolve_base(current[BASE_KEY], writer, writer_label)
        cycle = [seen for seen in chain if seen.resolve() == base.resolve()]
        if cycle:
            names = " -> ".join(str(item) for item in [*chain[chain.index(cycle[0]):], base])
            raise ConfigError(f"{writer_label}: {BASE_KEY} = {current[BASE_KEY]!r} makes a cycle ({names}); allowed: "
                              "a chain of bases that never comes back to one of its files")
        if len(chain) > MAX_BASES:
            raise ConfigError(f"{writer_label}: {BASE_KEY} = {current[BASE_KEY]!r} makes a chain of more than "
                              f"{MAX_BASES} bases; allowed: at most {MAX_BASES}")
        current = load_toml(base)
        chain.append(base)
        layers.append((rebased({key: value for key, value in current.items() if key != BASE_KEY}, base.parent), base))
        writer, writer_label = base, str(base)
    written_by: dict[str, Path] = {}
    bottom, bottom_file = layers[-1]
    _record(bottom, bottom_file, written_by)
    merged = bottom
    for layer, layer_file in reversed(layers[:-1]):
        merged = _merge(merged, layer, layer_file, written_by)
    return LayeredData(merged, path, label, tuple(chain),
                       {name: writer for name, writer in written_by.items() if writer != path})
