"""External-command estimators: a program reads image files and a measurements JSON, writes a result JSON.

So a compiled flight estimator runs unchanged: for every case the campaign writes the inputs into a
fresh working directory, runs ``argv`` (no shell) with the placeholders replaced, waits at most
``timeout_s`` and reads the result file (the output JSON of :mod:`estimators.contract`).

Placeholders (each a whole argument or part of one)
----------------------------------------------------
``{images}``        the image files in time order, as separate arguments (only as a whole argument)
``{image1}`` ...    one image file (``{image1}``, ``{image2}``, ``{image3}``)
``{measurements}``  measurements JSON (schema: :mod:`file_formats.measurements_json`)
``{output}``        where the program must write its result JSON
``{camera}``        the camera TOML as designed, written into the case directory without the simulator-only
                    ``radiometry.prnu_seed`` (:mod:`estimators.camera_view`; absolute path)
``{flat_field}``    the flat-field file (``flat_field_format``), or ``none`` when there is none
``{parameters}``    JSON file with the entry's ``parameters`` table
``{workdir}``       the case's working directory (also the program's current directory)
``{python}``        the Python interpreter running the campaign worker
``{config_dir}``    the campaign file's directory (expanded when the configuration is read)

Image files: ``image_format`` ``png`` (16-bit grey), ``npy``, or ``raw`` (little-endian uint16, no
header, ``camera.binned_shape``). Failures (one line each, recorded as the estimator's failed result):
``timeout: no result within T s`` (the program's whole process group is killed), ``exit status N: <last
line of stderr>``, ``killed by signal NAME``, ``wrote no result file``, ``result file is not valid
JSON``, and any contract violation of the result. A program that cannot be started at all (missing,
not executable, not a program: ``ENOENT``, ``EACCES``, ``ENOEXEC``) raises :class:`ProgramNotRunnable`
instead: that is the worker's set-up, not the case (:mod:`estimators.plugins`).
"""
from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from estimators.camera_view import write_design_camera
from estimators.contract import ContractViolation, EstimatorInputs, EstimatorOutput, validate_output
from file_formats.flat_field_files import save_flat_field
from file_formats.measurements_json import measurements_to_dict

PLACEHOLDER = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")
NAMES = ("images", "measurements", "output", "camera", "flat_field", "parameters", "workdir", "python")
IMAGE_NAME = re.compile(r"^image([1-9][0-9]*)$")
FLAT_SUFFIX = {"npy": ".npy", "tiff": ".tif", "fits": ".fits"}
IMAGE_SUFFIX = {"png": ".png", "npy": ".npy", "raw": ".raw"}
STDERR_TAIL = 300
#: errno values of a program that cannot be started at all (set-up, not a case's failure)
NOT_RUNNABLE_ERRNOS = frozenset({errno.ENOENT, errno.EACCES, errno.ENOEXEC, errno.ENOTDIR})


class ProgramNotRunnable(Exception):
    """The command's program cannot be started on this machine (one line: program and why)."""


def check_template(argv: list[str]) -> str:
    """Check a command template's placeholders.

    Parameters
    ----------
    argv : list of str
        Program and arguments, with placeholders.

    Returns
    -------
    str
        ``''`` when ``argv`` uses only known placeholders (``{images}`` only as a whole argument),
        else why not (one line, starting with the argument's index).
    """
    for position, item in enumerate(argv):
        for name in PLACEHOLDER.findall(item):
            if name not in NAMES and not IMAGE_NAME.match(name):
                return (f"[{position}] = {item!r} uses an unknown placeholder {{{name}}}; allowed: "
                        + ", ".join(f"{{{n}}}" for n in (*NAMES, "image1", "image2", "image3")))
        if "{images}" in item and item != "{images}":
            return f"[{position}] = {item!r}: {{images}} must be a whole argument (it expands to one argument per image)"
    return ""


def write_inputs(directory: Path, inputs: EstimatorInputs, image_format: str, flat_field_format: str) -> dict:
    """Write a case's inputs into ``directory``.

    Parameters
    ----------
    directory : Path
        An existing, empty directory.
    inputs : EstimatorInputs
        The case's inputs.
    image_format : str
        ``png``, ``npy`` or ``raw``.
    flat_field_format : str
        ``npy``, ``tiff`` or ``fits``.

    Returns
    -------
    dict
        Placeholder name -> value (paths as strings; ``images`` a list of them).
    """
    images = []
    for index, image in enumerate(inputs.images, start=1):
        path = directory / f"image{index}{IMAGE_SUFFIX[image_format]}"
        data = np.asarray(image)
        if image_format == "png":
            if not cv2.imwrite(str(path), data.astype(np.uint16)):
                raise OSError(f"{path}: cannot write PNG")
        elif image_format == "npy":
            np.save(path, data)
        else:
            data.astype("<u2").tofile(path)
        images.append(str(path))
    measurements = directory / "measurements.json"
    measurements.write_text(json.dumps(measurements_to_dict(inputs.measurements), indent=1))
    parameters = directory / "parameters.json"
    parameters.write_text(json.dumps(dict(inputs.parameters), indent=1))
    flat = "none"
    if inputs.calibration.flat_field is not None:
        flat = str(save_flat_field(directory / f"flat_field{FLAT_SUFFIX[flat_field_format]}",
                                   inputs.calibration.flat_field))
    values = {"images": images, "measurements": str(measurements), "output": str(directory / "result.json"),
              "camera": str(write_design_camera(directory / "camera.toml", inputs.camera).resolve()), "flat_field": flat,
              "parameters": str(parameters), "workdir": str(directory), "python": sys.executable}
    values.update({f"image{index}": path for index, path in enumerate(images, start=1)})
    return values


def expand(argv: tuple | list, values: dict) -> list[str]:
    """The command line for one case (``{images}`` becomes one argument per image).

    Parameters
    ----------
    argv : tuple or list of str
        Program and arguments, with placeholders.
    values : dict
        Placeholder values (:func:`write_inputs`).

    Returns
    -------
    list of str
        The command.

    Raises
    ------
    ContractViolation
        A placeholder without a value (e.g. ``{image3}`` of a two-image case).
    """
    command: list[str] = []
    for item in argv:
        if item == "{images}":
            command.extend(values["images"])
            continue

        def replace(match: re.Match) -> str:
            name = match.group(1)
            if name not in values or name == "images":
                raise ContractViolation(f"argument {item!r}: no value for {{{name}}} "  # noqa: B023 - runs in this iteration
                                        f"({len(values['images'])} images)")
            return str(values[name])

        command.append(PLACEHOLDER.sub(replace, item))
    return command


class CommandEstimator:
    """Runs an external program per case (see the module docstring).

    Parameters
    ----------
    name : str
        The estimator's name (results' ``estimator`` column).
    argv : tuple of str
        Program and arguments, with placeholders.
    timeout_s : float
        Wall-time limit per case (s).
    image_format : str, optional
        ``png`` (16-bit), ``npy`` or ``raw``.
    flat_field_format : str, optional
        ``npy``, ``tiff`` or ``fits``.
    parameters : dict or None, optional
        Written to ``{parameters}`` (JSON).
    python_path : tuple of str, optional
        Entries put before PYTHONPATH for the program.
    """

    def __init__(self, name: str, argv: tuple, timeout_s: float, image_format: str = "png",
                 flat_field_format: str = "npy", parameters: dict | None = None,
                 python_path: tuple[str, ...] = ()):
        self.name = name
        #: entries put before PYTHONPATH for the program (where an isolated python plug-in was found)
        self.python_path = tuple(python_path)
        self.parameters = dict(parameters or {})
        self.argv = tuple(argv)
        self.timeout_s = float(timeout_s)
        self.image_format = image_format
        self.flat_field_format = flat_field_format

    def estimate(self, inputs: EstimatorInputs) -> EstimatorOutput:
        """Write the inputs into a fresh directory, run the program there and read its result.

        Parameters
        ----------
        inputs : EstimatorInputs
            The case's inputs (their ``parameters`` replaced by the estimator's).

        Returns
        -------
        EstimatorOutput
            The validated result file.

        Raises
        ------
        ContractViolation
            The program failed, timed out, or wrote no valid result.
        """
        directory = Path(tempfile.mkdtemp(prefix=f"estimator-{self.name}-"))
        try:
            values = write_inputs(directory, replace(inputs, parameters=self.parameters), self.image_format,
                                  self.flat_field_format)
            command = expand(self.argv, values)
            self._run(command, directory)
            output = Path(values["output"])
            if not output.is_file():
                raise ContractViolation(f"wrote no result file ({output.name}; the {{output}} argument)")
            try:
                data = json.loads(output.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise ContractViolation(f"result file is not valid JSON ({exc})") from None
            return validate_output(data)
        finally:
            shutil.rmtree(directory, ignore_errors=True)

    def _run(self, command: list[str], directory: Path) -> None:
        environment = None
        if self.python_path:
            environment = {**os.environ, "PYTHONPATH": os.pathsep.join(
                [*self.python_path, *filter(None, [os.environ.get("PYTHONPATH")])])}
        try:
            process = subprocess.Popen(command, cwd=directory, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.PIPE, start_new_session=True, env=environment)
        except OSError as exc:
            if exc.errno in NOT_RUNNABLE_ERRNOS:
                raise ProgramNotRunnable(f"cannot start {command[0]!r}: {exc.strerror or exc}") from None
            raise ContractViolation(f"cannot start {command[0]!r}: {exc.strerror or exc}") from None
        try:
            _, stderr = process.communicate(timeout=self.timeout_s)
        except subprocess.TimeoutExpired:
            _kill_group(process)
            process.communicate()
            raise ContractViolation(f"timeout: no result within {self.timeout_s:g} s (process group killed)") from None
        except BaseException:
            _kill_group(process)
            raise
        if process.returncode < 0:
            raise ContractViolation(f"killed by signal {signal.Signals(-process.returncode).name}"
                                    f"{_tail(stderr)}")
        if process.returncode != 0:
            raise ContractViolation(f"exit status {process.returncode}{_tail(stderr)}")


def _kill_group(process: subprocess.Popen) -> None:
    """Kill the program and everything it started (its own session, so its own process group)."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _tail(stderr: bytes) -> str:
    lines = [line.strip() for line in stderr.decode("utf-8", "replace").splitlines() if line.strip()]
    return f": {lines[-1][:STDERR_TAIL]}" if lines else ""
