"""Build estimators from their specs and run one on a case's inputs, whatever happens.

:func:`build_estimator` turns an :class:`~estimators.entries.EstimatorSpec` into an object with
``estimate(inputs) -> EstimatorOutput``; :func:`run_estimator` runs it on read-only inputs
(:func:`estimators.contract.read_only_inputs`) and never raises: a contract violation, any exception
(``SystemExit`` and ``KeyboardInterrupt`` included), a non-zero exit or a timeout becomes an
:class:`EstimatorRun` with ``output = None``, ``failure = "estimator_failed"`` and a one-line ``error``;
an implausible answer (:func:`estimators.contract.check_plausible`) the same with ``failure = "implausible"``.

*Set-up* is not a case's failure: building an estimator (importing a python plug-in's module, a
reference estimator's parameters, a command's program that is missing or not executable in this
process's machine) raises :class:`EstimatorSetupError` from :func:`build_estimator`, and a command
whose program cannot be started (``ENOENT``, ``EACCES``, ``ENOEXEC``) raises it from
:func:`run_estimator`: the campaign stops the run instead of recording failed rows.
"""
from __future__ import annotations

import copy
import importlib
import os
import shutil
import sys
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path

from dimes_velocity.config import estimator_config_from_data
from dimes_velocity.estimator import estimate_velocity
from estimators.command import CommandEstimator, ProgramNotRunnable
from estimators.contract import (
    ContractViolation,
    EstimatorInputs,
    EstimatorOutput,
    ImplausibleOutput,
    check_plausible,
    read_only_inputs,
    validate_output,
)
from estimators.entries import EstimatorSpec

CRASH_MESSAGE_CHARS = 2000
"""A plug-in's exception message is stored up to this many characters; the file and line where it raised,
after it, always whole."""


class ReferenceEstimator:
    """The reference DIMES estimator (:mod:`dimes_velocity`) behind the contract.

    Parameters
    ----------
    name : str
        The estimator's name (results' ``estimator`` column).
    parameters : dict
        :class:`~dimes_velocity.config.EstimatorConfig` fields.

    Raises
    ------
    ConfigError
        A parameter that is not an EstimatorConfig field or out of range.
    """

    def __init__(self, name: str, parameters: dict):
        self.name = name
        self.config = estimator_config_from_data(dict(parameters), f"estimator {name}", "parameters")

    def estimate(self, inputs: EstimatorInputs) -> EstimatorOutput:
        """Run :func:`dimes_velocity.estimator.estimate_velocity` on a case.

        Parameters
        ----------
        inputs : EstimatorInputs
            The case's inputs.

        Returns
        -------
        EstimatorOutput
            The velocity, validity, reason, per-feature metrics and stated uncertainty.
        """
        result = estimate_velocity(list(inputs.images), inputs.measurements, inputs.camera, self.config,
                                   inputs.calibration.flat_field)
        features = tuple({"brightness_dn": float(f.brightness_dn), "contrast_dn": float(f.contrast_dn),
                          "correlation": float(f.correlation), "status": str(f.status)} for f in result.features)
        return EstimatorOutput(velocity_east_mps=float(result.velocity_east_mps),
                               velocity_north_mps=float(result.velocity_north_mps), valid=bool(result.valid),
                               reason=str(result.reason), features=features,
                               velocity_uncertainty_mps=float(result.velocity_uncertainty_mps))


class PythonEstimator:
    """A ``package.module:function`` called in this process with the case's :class:`EstimatorInputs`.

    Parameters
    ----------
    name : str
        The estimator's name (results' ``estimator`` column).
    target : str
        ``package.module:function``; the module is imported here.
    parameters : dict
        Handed to the function as ``inputs.parameters`` (a deep copy per case).
    """

    def __init__(self, name: str, target: str, parameters: dict):
        module_name, function_name = target.split(":")
        self.name = name
        self.function = getattr(importlib.import_module(module_name), function_name)
        self.parameters = dict(parameters)

    def estimate(self, inputs: EstimatorInputs) -> EstimatorOutput:
        """Call the function on a case.

        Parameters
        ----------
        inputs : EstimatorInputs
            The case's inputs.

        Returns
        -------
        EstimatorOutput
            The function's answer, validated (:func:`estimators.contract.validate_output`).
        """
        return validate_output(self.function(replace(inputs, parameters=copy.deepcopy(self.parameters))))


class EstimatorSetupError(Exception):
    """An estimator cannot be loaded or started in this process.

    One line: estimator, error, fix. Not a case's failure: the campaign stops the run and records nothing for the
    cases it could not run.
    """


def setup_fix(spec: EstimatorSpec) -> str:
    """What makes ``spec`` loadable on a worker (the last part of a set-up error's line).

    Parameters
    ----------
    spec : EstimatorSpec
        The estimator.

    Returns
    -------
    str
        The advice, one line.
    """
    if spec.kind == "python":
        module = spec.callable.split(":")[0]
        return (f"make {module!r} and what it imports importable on every worker: a module file or package "
                "outside site-packages is shipped to the workers by the campaign, its dependencies must be "
                "installed there (see docs/estimators.md, where a plug-in module may live)")
    if spec.kind == "command":
        return (f"install {spec.argv[0]!r} at that path (or on PATH) with execute permission on every worker, "
                "or use {config_dir} on a file system the workers share")
    return "fix the estimator's parameters"


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:300]


def build_estimator(spec: EstimatorSpec):
    """The estimator object of a spec (built once per worker process by the campaign).

    Parameters
    ----------
    spec : EstimatorSpec
        The estimator.

    Returns
    -------
    ReferenceEstimator or PythonEstimator or CommandEstimator
        An object with ``estimate(inputs) -> EstimatorOutput`` (an isolated python callable is a
        :class:`~estimators.command.CommandEstimator` running :mod:`estimators.run_python`).

    Raises
    ------
    EstimatorSetupError
        When the estimator cannot be built here: a python module that does not import (or lacks the
        callable), bad reference parameters, a command program that is missing or not executable.
    """
    try:
        return _build(spec)
    except EstimatorSetupError:
        raise
    except BaseException as exc:  # noqa: B036 -- a plug-in's import may raise anything, SystemExit included
        raise EstimatorSetupError(f"estimator {spec.name}: cannot be set up: {_describe(exc)}; "
                                  f"{setup_fix(spec)}") from None


def _build(spec: EstimatorSpec):
    if spec.kind == "reference":
        return ReferenceEstimator(spec.name, spec.parameters)
    if spec.kind == "python" and not spec.isolate:
        return PythonEstimator(spec.name, spec.callable, spec.parameters)
    if spec.kind == "python":
        # imported here too: a module this process cannot import is a set-up error, not a failed row per
        # case; its root (a directory or a shipped zip) goes on the child interpreter's PYTHONPATH
        PythonEstimator(spec.name, spec.callable, spec.parameters)
        argv = ("{python}", "-m", "estimators.run_python", spec.callable, "--measurements", "{measurements}",
                "--camera", "{camera}", "--flat-field", "{flat_field}", "--parameters", "{parameters}",
                "--output", "{output}", "{images}")
        return CommandEstimator(spec.name, argv, spec.timeout_s, "npy", "npy", spec.parameters,
                                python_path=module_root(spec.callable.split(":")[0]))
    check_program(spec.argv[0])
    return CommandEstimator(spec.name, spec.argv, spec.timeout_s, spec.image_format, spec.flat_field_format,
                            spec.parameters)


def module_root(module_name: str) -> tuple[str, ...]:
    """The sys.path entry an (imported) module was found under.

    Parameters
    ----------
    module_name : str
        Dotted name of a module already imported.

    Returns
    -------
    tuple of str
        Its file's directory, up one level per dot of the name (a directory or a zip archive); ``()``
        for a module without a file.
    """
    found = getattr(sys.modules.get(module_name), "__file__", None)
    if not found:
        return ()
    path = Path(found)
    levels = module_name.count(".") + (1 if path.name == "__init__.py" else 0)
    return (str(path.parents[levels]),)


def check_program(program: str) -> None:
    """Check that ``program`` (argv[0] of a command) runs here.

    Parameters
    ----------
    program : str
        ``{python}``, a program on PATH or the path of an executable file.

    Raises
    ------
    FileNotFoundError
        Not on PATH and no such file.
    PermissionError
        A file without execute permission.
    """
    if program == "{python}" or shutil.which(program) is not None:
        return
    path = Path(program)
    if not path.is_file():
        raise FileNotFoundError(f"{program!r} is not an executable file or a program on PATH on this machine")
    if not os.access(path, os.X_OK):
        raise PermissionError(f"{program!r} is not executable (no execute permission)")


@dataclass(frozen=True)
class EstimatorRun:
    """One estimator's outcome on one case: its output, or why there is none.

    Parameters
    ----------
    name : str
        The estimator's name.
    output : EstimatorOutput or None
        The checked answer; None when the run failed.
    error : str
        The failure's one-line message (``""`` when none).
    elapsed_ms : float
        Wall time of the run (ms).
    failure : str, optional
        The row's reason when the run failed: ``estimator_failed`` or ``implausible``; ``""`` otherwise.
    """

    name: str
    output: EstimatorOutput | None
    error: str
    elapsed_ms: float
    failure: str = ""


def run_estimator(name: str, estimator, inputs: EstimatorInputs,
                  max_horizontal_speed_mps: float | None = None) -> EstimatorRun:
    """Run ``estimator`` on read-only ``inputs`` and check its answer's plausibility.

    Any failure is returned as the run's ``failure`` and ``error``, never raised: whatever the plug-in
    raises, ``SystemExit`` and ``KeyboardInterrupt`` included, ends here and the worker goes on.

    Parameters
    ----------
    name : str
        The estimator's name, in error messages.
    estimator : object
        An object of :func:`build_estimator`.
    inputs : EstimatorInputs
        The case's inputs (handed over read-only).
    max_horizontal_speed_mps : float or None, optional
        Bound on a valid answer's horizontal speed (m/s); None: no bound.

    Returns
    -------
    EstimatorRun
        The output or the failure, and the wall time.

    Raises
    ------
    EstimatorSetupError
        Only when a command's program cannot be started at all: that is set-up, not the case.
    """
    started = time.perf_counter()
    failure = "estimator_failed"
    try:
        output = estimator.estimate(read_only_inputs(inputs))
        output = check_plausible(validate_output(output), max_horizontal_speed_mps)
        error, failure = "", ""
    except ProgramNotRunnable as exc:
        raise EstimatorSetupError(f"estimator {name}: cannot be set up: {exc}; install the program with execute "
                                  "permission on every worker") from None
    except ImplausibleOutput as exc:
        output, error, failure = None, f"estimator {name}: implausible: {exc}"[:500], "implausible"
    except ContractViolation as exc:
        output, error = None, f"estimator {name}: {exc}"
    except BaseException as exc:  # noqa: B036 -- the plug-in's own crash or exit: recorded, never re-raised
        where = traceback.format_exc(limit=-1).splitlines()
        location = next((line.strip() for line in reversed(where) if line.strip().startswith("File ")), "")
        what = f"{type(exc).__name__}: {exc}" if isinstance(exc, Exception) else repr(exc)
        if len(what) > CRASH_MESSAGE_CHARS:      # a huge message is shortened, never the file and line after it
            what = f"{what[:CRASH_MESSAGE_CHARS]}... ({len(what) - CRASH_MESSAGE_CHARS} more characters)"
        output, error = None, f"estimator {name}: crashed: {what} | {location}"
    return EstimatorRun(name, output, error, 1e3 * (time.perf_counter() - started), failure)
