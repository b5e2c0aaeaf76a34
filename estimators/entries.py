"""``[[estimators]]`` entries -> :class:`EstimatorSpec` (validated at the configuration edge) -> estimators.

A campaign file lists the estimators to compare; every one runs on the same rendered images and
sensor draws of each case::

    [[estimators]]
    name = "dimes"                      # unique; the results' `estimator` column
    kind = "reference"                  # the reference DIMES estimator
    [estimators.parameters]             # EstimatorConfig fields over the [estimator] table's
    min_correlation = 0.75

    [[estimators]]
    name = "phase_correlation"
    kind = "python"
    callable = "estimators.phase_correlation:estimate"   # package.module:function
    isolate = false                     # true: run in its own process, with timeout_s (default false)
    [estimators.parameters]             # passed as inputs.parameters
    min_response = 0.05

    [[estimators]]
    name = "flight_c"
    kind = "command"
    argv = ["{config_dir}/bin/dimes_flight", "{images}", "{measurements}", "{output}"]
    timeout_s = 30                      # default 60
    image_format = "raw"                # png (16-bit, default), npy, raw (little-endian uint16, no header)
    flat_field_format = "fits"          # npy (default), tiff, fits

Without ``[[estimators]]`` a campaign runs one estimator, ``name = "dimes"``, ``kind = "reference"``,
with the ``[estimator]`` table's parameters. Command placeholders are listed in
:mod:`estimators.command`. An entry is declared once, by :class:`ReferenceEntry`, :class:`PythonEntry` or
:class:`CommandEntry` (chosen by ``kind``); ``campaign schema campaign_file`` prints them.
"""
from __future__ import annotations

import contextlib
import contextvars
import importlib
import os
import re
import shutil
import sys
import sysconfig
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, InputPath
from dimes_velocity.config import estimator_config_from_data
from estimators.command import check_template

DEFAULT_NAME = "dimes"
DEFAULT_TIMEOUT_S = 60.0
NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
CALLABLE_PATTERN = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")
Timeout = Annotated[float, Field(gt=0.0, le=86400.0)]
ImageFormat = Literal["png", "npy", "raw"]
FlatFieldFormat = Literal["npy", "tiff", "fits"]
#: False while :func:`plugin_imports_deferred` is active: a python entry's module is not imported at validation
IMPORT_PLUGINS = contextvars.ContextVar("IMPORT_PLUGINS", default=True)


class _Entry(ConfigModel):
    name: str
    """Unique among [[estimators]]: the results' ``estimator`` column (1-64 letters, digits, '_', '.', '-')."""
    parameters: dict[str, Any] = {}
    """reference: EstimatorConfig fields over the [estimator] table's; otherwise handed to the estimator."""

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        if not NAME_PATTERN.match(value):
            raise FieldProblem("", f"= {value!r} is not allowed; allowed: 1-64 letters, digits, '_', '.', '-'")
        return value


class ReferenceEntry(_Entry):
    """The reference DIMES estimator (:mod:`dimes_velocity`)."""

    kind: Literal["reference"]
    """``reference``."""


class PythonEntry(_Entry):
    """A python callable ``package.module:function`` given the case's inputs."""

    kind: Literal["python"]
    """``python``."""
    path: InputPath | None = None
    """Directory the callable's module is imported from, relative to the campaign file ("." = beside it),
    searched before sys.path; default: sys.path alone (PYTHONPATH, the working directory under
    ``python -m``, installed packages)."""
    callable: str
    """``package.module:function`` (must import and name a callable)."""
    isolate: bool = False
    """Run it in its own process, with timeout_s (crash-proof)."""
    timeout_s: Timeout = DEFAULT_TIMEOUT_S
    """Wall-time limit per case of an isolated callable (s)."""

    @field_validator("path")
    @classmethod
    def _directory(cls, path: Path | None) -> Path | None:
        if path is not None and not path.is_dir():
            raise FieldProblem("", f"= {str(path)!r} is not a directory; allowed: the directory of the callable's "
                               "module, relative to the campaign file (\".\" = beside it)")
        return path

    @field_validator("callable")
    @classmethod
    def _importable(cls, target: str, info: ValidationInfo) -> str:
        check_callable(target, info.data.get("path"))
        return target


class CommandEntry(_Entry):
    """An external program run on files (placeholders: :mod:`estimators.command`)."""

    kind: Literal["command"]
    """``command``."""
    argv: Annotated[list[str], Field(min_length=1)]
    """Program, then arguments with placeholders; ``{config_dir}`` is the campaign file's directory."""
    timeout_s: Timeout = DEFAULT_TIMEOUT_S
    """Wall-time limit per case (s)."""
    image_format: ImageFormat = "png"
    """png (16-bit), npy, raw (little-endian uint16, no header)."""
    flat_field_format: FlatFieldFormat = "npy"
    """npy, tiff, fits: the ``{flat_field}`` file's format."""

    @field_validator("argv")
    @classmethod
    def _runnable(cls, argv: list[str], info: ValidationInfo) -> list[str]:

        if not all(argv):
            raise FieldProblem("", f"must be a non-empty list of non-empty strings; got {argv!r}")
        config_dir = Path((info.context or {}).get("base_dir", "."))
        argv = [item.replace("{config_dir}", str(config_dir.resolve())) for item in argv]
        problem = check_template(argv)
        if problem:
            raise FieldProblem("", problem)
        program = argv[0]
        if program != "{python}" and shutil.which(program) is None and not Path(program).is_file():
            raise FieldProblem("", f"[0] = {program!r} is not an executable file or a program on PATH")
        return argv


#: One ``[[estimators]]`` entry, by ``kind``.
EstimatorEntry = Annotated[ReferenceEntry | PythonEntry | CommandEntry, Field(discriminator="kind")]


def unique_names(entries: list) -> list:
    """Validator of the ``[[estimators]]`` array: names unique.

    Parameters
    ----------
    entries : list
        The validated entries (:data:`EstimatorEntry`).

    Returns
    -------
    list
        ``entries`` itself.

    Raises
    ------
    FieldProblem
        Naming the first entry whose name is used twice.
    """
    seen: set[str] = set()
    for index, entry in enumerate(entries):
        if entry.name in seen:
            raise FieldProblem(f"[{index}].name", f"= {entry.name!r} is used twice; allowed: a name unique among "
                               "[[estimators]]")
        seen.add(entry.name)
    return entries


@dataclass(frozen=True)
class EstimatorSpec:
    """One estimator of a campaign (picklable: it travels to the workers with the configuration).

    Attributes
    ----------
    name : str
        Unique name, the ``estimator`` column of the results.
    kind : str
        ``reference``, ``python`` or ``command``.
    parameters : dict
        For ``reference``: EstimatorConfig fields (the ``[estimator]`` table's, overridden by the
        entry's); otherwise the entry's ``parameters`` table, handed to the estimator as is.
    callable : str
        ``package.module:function`` (python).
    isolate : bool
        Run a python callable in its own process (timeout, crash-proof).
    argv : tuple of str
        Command template (command), ``{config_dir}`` already expanded.
    timeout_s : float
        Wall-time limit of a command (or isolated callable) per case.
    image_format, flat_field_format : str
        File formats written for a command.
    """

    name: str
    kind: str
    parameters: dict = field(default_factory=dict)
    callable: str = ""
    isolate: bool = False
    argv: tuple = ()
    timeout_s: float = DEFAULT_TIMEOUT_S
    image_format: str = "png"
    flat_field_format: str = "npy"


def default_specs(reference_parameters: dict) -> list[EstimatorSpec]:
    """The estimator list of a campaign without ``[[estimators]]``: the reference estimator alone.

    Parameters
    ----------
    reference_parameters : dict
        The ``[estimator]`` table's EstimatorConfig fields.

    Returns
    -------
    list of EstimatorSpec
        One spec, ``name = "dimes"``, ``kind = "reference"``.
    """
    return [EstimatorSpec(name=DEFAULT_NAME, kind="reference", parameters=dict(reference_parameters))]


def estimator_specs(entries: list, reference_parameters: dict, source: str) -> list[EstimatorSpec]:
    """Specs of validated ``[[estimators]]`` entries.

    Parameters
    ----------
    entries : list
        The validated entries (:data:`EstimatorEntry`), in file order.
    reference_parameters : dict
        The ``[estimator]`` table's EstimatorConfig fields; a reference entry's parameters override them.
    source : str
        The campaign file, named in errors.

    Returns
    -------
    list of EstimatorSpec
        One spec per entry, in order; other kinds' parameters as JSON types.

    Raises
    ------
    ConfigError
        A reference entry's parameter that is not a valid EstimatorConfig field, naming ``source`` and
        ``estimators[i].parameters.<field>``.
    """
    specs = []
    for index, entry in enumerate(entries):
        if entry.kind == "reference":
            merged = {**reference_parameters, **entry.parameters}
            estimator_config_from_data(merged, source, f"estimators[{index}].parameters")
            specs.append(EstimatorSpec(name=entry.name, kind="reference", parameters=merged))
        elif entry.kind == "python":
            specs.append(EstimatorSpec(name=entry.name, kind="python", parameters=_plain(entry.parameters),
                                       callable=entry.callable, isolate=entry.isolate, timeout_s=entry.timeout_s))
        else:
            specs.append(EstimatorSpec(name=entry.name, kind="command", parameters=_plain(entry.parameters),
                                       argv=tuple(entry.argv), timeout_s=entry.timeout_s,
                                       image_format=entry.image_format, flat_field_format=entry.flat_field_format))
    return specs


@contextlib.contextmanager
def plugin_imports_deferred():
    """Within the block, validating a python entry checks only the form of ``callable``, not that it imports.

    ``campaign check-estimators`` reports a module that does not import as a set-up violation of that
    estimator (exit 1) instead of refusing the file.

    Yields
    ------
    None
        Nothing; the check is restored when the block ends.
    """
    token = IMPORT_PLUGINS.set(False)
    try:
        yield
    finally:
        IMPORT_PLUGINS.reset(token)


def check_callable(target: str, directory: Path | None = None) -> None:
    """Check that ``package.module:function`` imports and names a callable.

    ``directory`` (a python entry's ``path``) is put first on ``sys.path`` (also within
    :func:`plugin_imports_deferred`, which checks only the form of ``target``), so the module is imported
    from there, here and by every later import in this process (the workers get the module shipped:
    :mod:`campaign.run.plugin_setup`).

    Parameters
    ----------
    target : str
        ``package.module:function``.
    directory : Path or None, optional
        The directory the module is imported from (searched before ``sys.path``).

    Raises
    ------
    FieldProblem
        A malformed target, a module that cannot be imported (saying where it was looked for), a module
        imported from elsewhere than ``directory``, or no such callable in it.
    """
    if not CALLABLE_PATTERN.match(target):
        raise FieldProblem("", f"= {target!r} is not allowed; allowed: 'package.module:function'")
    if directory is not None:
        searched = str(Path(directory).resolve())
        if searched not in sys.path:
            sys.path.insert(0, searched)
            importlib.invalidate_caches()
    if not IMPORT_PLUGINS.get():
        return
    module_name, function_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # an ImportError or the module's own error: one line either way
        raise FieldProblem("", f"= {target!r}: module {module_name!r} cannot be imported "
                               f"({type(exc).__name__}: {' '.join(str(exc).split())}){_where_looked(exc, module_name, directory)}") from None
    origin = getattr(module, "__file__", None)
    if directory is not None and origin and not Path(origin).resolve().is_relative_to(Path(directory).resolve()):
        raise FieldProblem("", f"= {target!r}: module {module_name!r} is imported from {origin}, not from path "
                               f"{str(directory)!r} (a module of that name was imported first); allowed: a module "
                               "name no other imported module has")
    if not callable(getattr(module, function_name, None)):
        raise FieldProblem("", f"= {target!r}: {module_name} has no callable {function_name!r}")


def _where_looked(exc: Exception, module_name: str, directory: Path | None) -> str:
    """How a plug-in module is found, for a module that was not found (empty for the module's own error)."""
    missing = getattr(exc, "name", None)
    if not isinstance(exc, ModuleNotFoundError) or not missing or not (
            module_name == missing or module_name.startswith(f"{missing}.")):
        return ""
    installed = {sysconfig.get_paths()[key] for key in ("stdlib", "platstdlib", "purelib", "platlib")}
    own = [entry or "." for entry in sys.path
           if os.path.isdir(entry or ".") and not any(entry.startswith(root) for root in installed)]
    first = f"in path {str(directory)!r} of this entry, then " if directory is not None else ""
    return (f"; a plug-in module is looked for {first}in the directories of sys.path ({', '.join(own) or 'none'}: "
            "PYTHONPATH, and the working directory under `python -m`) and the installed packages; allowed: "
            "path = \"DIR\" in this [[estimators]] entry (DIR relative to the campaign file, \".\" = beside it), "
            "the module's directory on PYTHONPATH, or the module pip-installed")


def _plain(data: Any) -> Any:
    """TOML values as JSON types (dates become strings)."""
    if isinstance(data, dict):
        return {str(key): _plain(value) for key, value in data.items()}
    if isinstance(data, list):
        return [_plain(value) for value in data]
    if isinstance(data, (str, int, float, bool)) or data is None:
        return data
    return str(data)
