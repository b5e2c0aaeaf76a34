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

``[[estimators]]`` lists the estimators to run on every case (:mod:`estimators.entries`); without it
the campaign runs the reference estimator alone, named ``dimes``. The ``[estimator]`` table is declared
once, by :class:`EstimatorTable` (:class:`CalibrationConfig` fields plus the reference's
:class:`~dimes_velocity.config.EstimatorConfig` fields).
"""
from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path
from typing import Literal

from pydantic import Field

from config_tables.models import ConfigModel
from dimes_velocity.config import EstimatorConfig
from estimators.entries import default_specs, estimator_specs

DEFAULT_FLAT_FIELD_FRAMES = 16


class CalibrationConfig(ConfigModel):
    """How the campaign makes the calibration products (see the module docstring)."""

    flat_field: Literal["calibrated", "none", "truth"] = "calibrated"
    """"calibrated": mean of flat_field_frames simulated flat exposures minus as many dark ones; "none": no
    flat field; "truth": the simulated detector's true response (no flight system has it)."""
    flat_field_frames: int = Field(DEFAULT_FLAT_FIELD_FRAMES, ge=1, le=1024)
    """Flat (and dark) exposures of the calibration."""


CALIBRATION_KEYS = tuple(CalibrationConfig.model_fields)


class EstimatorTable(CalibrationConfig, EstimatorConfig):
    """``[estimator]`` of a campaign file: the calibration products and the reference estimator's
    parameters (the defaults of every reference entry of ``[[estimators]]``)."""

    def calibration(self) -> CalibrationConfig:
        return CalibrationConfig(**{key: getattr(self, key) for key in CALIBRATION_KEYS})

    def reference(self) -> EstimatorConfig:
        """The reference estimator's configuration (its defaults where the table gives none)."""
        return EstimatorConfig(**self.reference_parameters())

    def reference_parameters(self) -> dict:
        """The EstimatorConfig fields the table gives explicitly."""
        return {key: getattr(self, key) for key in self.model_fields_set if key not in CALIBRATION_KEYS}


def estimator_tables(table: EstimatorTable, entries: list | None, source: str):
    """(CalibrationConfig, reference EstimatorConfig, specs) of a campaign's validated ``[estimator]``
    and ``[[estimators]]`` (errors in a reference entry's merged parameters name ``source``)."""

    reference_parameters = table.reference_parameters()
    specs = (estimator_specs(entries, reference_parameters, source) if entries is not None
             else default_specs(reference_parameters))
    return table.calibration(), table.reference(), tuple(specs)


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
