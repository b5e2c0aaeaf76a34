"""The ``[estimator]`` table and ``[[estimators]]`` entries of a campaign file.

``[estimator]`` holds the calibration products every estimator gets, and the reference estimator's
parameters (:class:`dimes_velocity.config.EstimatorConfig` fields; the defaults of every reference
entry)::

    [estimator]
    flat_field = "calibrated"    # "calibrated" (default): mean of flat_field_frames simulated flat
                                 #   exposures minus as many dark ones (simulator.calibration);
                                 # "none": no flat field (estimators correct the design falloff at most);
                                 # "truth": the simulated detector's true response (to measure what
                                 #   calibration costs; no flight system has it)
    flat_field_frames = 16       # flat (and dark) exposures of the calibration, 1..1024 (default 16)
    min_correlation = 0.7        # any EstimatorConfig field

``[[estimators]]`` lists the estimators to run on every case (:mod:`estimators.registry`); without it
the campaign runs the reference estimator alone, named ``dimes``.
"""
from __future__ import annotations

import hashlib
import importlib.util
from dataclasses import dataclass
from pathlib import Path

from flight_interface.tomlfields import Table

FLAT_FIELD_MODES = ("calibrated", "none", "truth")
CALIBRATION_KEYS = ("flat_field", "flat_field_frames")
DEFAULT_FLAT_FIELD_FRAMES = 16


@dataclass(frozen=True)
class CalibrationConfig:
    """How the campaign makes the calibration products (see the module docstring)."""

    flat_field: str = "calibrated"
    flat_field_frames: int = DEFAULT_FLAT_FIELD_FRAMES


def estimator_tables(root: Table, config_dir: Path):
    """Read ``[estimator]`` and ``[[estimators]]``: (CalibrationConfig, reference EstimatorConfig, specs)."""
    from dimes_velocity.config import config_from_table
    from estimators.registry import default_specs, estimator_specs_from_tables

    table = root.table("estimator", required=False)
    calibration = CalibrationConfig(
        flat_field=table.string("flat_field", default="calibrated", choices=FLAT_FIELD_MODES),
        flat_field_frames=table.integer("flat_field_frames", default=DEFAULT_FLAT_FIELD_FRAMES, minimum=1,
                                        maximum=1024))
    reference_parameters = {key: value for key, value in table.data.items() if key not in CALIBRATION_KEYS}
    reference = config_from_table(Table(reference_parameters, table.source, table.path))
    table.ignore(*table.data)
    if root.has("estimators"):
        specs = estimator_specs_from_tables(root.tables("estimators"), reference_parameters, config_dir)
    else:
        specs = default_specs(reference_parameters)
    return calibration, reference, tuple(specs)


def estimator_code_digests(specs) -> dict:
    """sha256 of the code behind each plugged-in estimator outside this repository's packages: a
    python callable's module file, a command's program and script arguments (existing files). Part of
    the configuration hash, so results of a changed plugin are not mixed with the old ones."""
    digests = {}
    for spec in specs:
        files = []
        if spec.kind == "python":
            found = importlib.util.find_spec(spec.callable.split(":")[0])
            if found is not None and found.origin and Path(found.origin).is_file():
                files.append(Path(found.origin))
        elif spec.kind == "command":
            files += [Path(item) for item in spec.argv if "{" not in item and Path(item).is_file()]
        for path in files:
            digests[f"{spec.name}:{path.name}"] = hashlib.sha256(path.read_bytes()).hexdigest()
    return digests
