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
:mod:`estimators.command`.
"""
from __future__ import annotations

import importlib
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flight_interface.tomlfields import Table

KINDS = ("reference", "python", "command")
DEFAULT_NAME = "dimes"
DEFAULT_TIMEOUT_S = 60.0
IMAGE_FORMATS = ("png", "npy", "raw")
FLAT_FIELD_FORMATS = ("npy", "tiff", "fits")
NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
CALLABLE_PATTERN = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


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
    """The estimator list of a campaign without ``[[estimators]]``: the reference estimator alone."""
    return [EstimatorSpec(name=DEFAULT_NAME, kind="reference", parameters=dict(reference_parameters))]


def estimator_specs_from_tables(tables: list[Table], reference_parameters: dict, config_dir: Path) -> list[EstimatorSpec]:
    """Validate ``[[estimators]]`` tables into specs (errors name the file and ``estimators[i].field``).

    Parameters
    ----------
    tables : list of Table
        The ``estimators`` array of tables.
    reference_parameters : dict
        The ``[estimator]`` table's reference-estimator parameters (defaults of every reference entry).
    config_dir : Path
        Directory of the campaign file (``{config_dir}`` in command templates).
    """
    specs: list[EstimatorSpec] = []
    for table in tables:
        name = table.string("name")
        if not NAME_PATTERN.match(name):
            raise table.fail("name", f"= {name!r} is not allowed; allowed: 1-64 letters, digits, '_', '.', '-'")
        if any(spec.name == name for spec in specs):
            raise table.fail("name", f"= {name!r} is used twice; allowed: a name unique among [[estimators]]")
        kind = table.string("kind", choices=KINDS)
        parameters = table.table("parameters", required=False)
        parameters.ignore(*parameters.data)          # handed to the estimator, which checks them
        if kind == "reference":
            merged = {**reference_parameters, **parameters.data}
            check_reference_parameters(Table(merged, table.source, f"{table.path}.parameters"))
            spec = EstimatorSpec(name=name, kind=kind, parameters=merged)
        elif kind == "python":
            target = table.string("callable")
            check_callable(target, table)
            isolate = table.boolean("isolate", default=False)
            timeout = table.number("timeout_s", default=DEFAULT_TIMEOUT_S, minimum=0.0, maximum=86400.0,
                                   exclusive_minimum=True)
            spec = EstimatorSpec(name=name, kind=kind, parameters=_plain(parameters.data), callable=target,
                                 isolate=isolate, timeout_s=timeout)
        else:
            spec = EstimatorSpec(
                name=name, kind=kind, parameters=_plain(parameters.data), argv=_command_argv(table, config_dir),
                timeout_s=table.number("timeout_s", default=DEFAULT_TIMEOUT_S, minimum=0.0, maximum=86400.0,
                                       exclusive_minimum=True),
                image_format=table.string("image_format", default="png", choices=IMAGE_FORMATS),
                flat_field_format=table.string("flat_field_format", default="npy", choices=FLAT_FIELD_FORMATS))
        table.reject_unknown()
        specs.append(spec)
    return specs


def check_reference_parameters(table: Table) -> None:
    """Raise ConfigError (file and field) unless ``table`` holds valid reference-estimator parameters."""
    from dimes_velocity.config import config_from_table

    config_from_table(table)


def check_callable(target: str, table: Table) -> None:
    """``package.module:function`` must import and name a callable."""
    if not CALLABLE_PATTERN.match(target):
        raise table.fail("callable", f"= {target!r} is not allowed; allowed: 'package.module:function'")
    module_name, function_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # an ImportError or the module's own error: one line either way
        raise table.fail("callable", f"= {target!r}: module {module_name!r} cannot be imported "
                                     f"({type(exc).__name__}: {exc})") from None
    if not callable(getattr(module, function_name, None)):
        raise table.fail("callable", f"= {target!r}: {module_name} has no callable {function_name!r}")


def _command_argv(table: Table, config_dir: Path) -> tuple:
    from .command import check_template

    if not table.has("argv"):
        raise table.fail("argv", "is missing (a list: program, then arguments with placeholders)")
    argv = table._get("argv", None)
    if not isinstance(argv, list) or not argv or not all(isinstance(item, str) and item for item in argv):
        raise table.fail("argv", f"must be a non-empty list of non-empty strings; got {argv!r}")
    argv = [item.replace("{config_dir}", str(config_dir.resolve())) for item in argv]
    problem = check_template(argv)
    if problem:
        raise table.fail("argv", problem)
    program = argv[0]
    if program != "{python}" and shutil.which(program) is None and not Path(program).is_file():
        raise table.fail("argv", f"[0] = {program!r} is not an executable file or a program on PATH")
    return tuple(argv)


def _plain(data: Any) -> Any:
    """TOML values as JSON types (dates become strings)."""
    if isinstance(data, dict):
        return {str(key): _plain(value) for key, value in data.items()}
    if isinstance(data, list):
        return [_plain(value) for value in data]
    if isinstance(data, (str, int, float, bool)) or data is None:
        return data
    return str(data)
