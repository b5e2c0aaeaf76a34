"""Everything a case needs besides its plan row, loaded once per process: :class:`CampaignInputs` (the
site's :class:`~campaign.case.site.SiteInputs` plus calibration products, estimators and the plausibility
bound) and :func:`campaign_inputs`, the one way a process gets them (workers, ``campaign export``, the
report's gallery, benchmarks).

Big read-only inputs (camera, trajectory set, terrain strips, calibration, estimators) are kept in
:data:`PROCESS_INPUTS` (campaigns by configuration hash; the files they share by source, in
:data:`campaign.case.site.PROCESS_SHARED`); dask tasks carry only a small context and one plan row.

The flat-field calibration is drawn once per campaign from ``SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))``
(a stream no case uses) and cached per process, read-only at its source; each ``[[estimators]]`` entry is
built once per process.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from campaign.case.process_tuning import tune_once
from campaign.case.site import PROCESS_SHARED, SharedInputs, SiteInputs
from campaign.configuration.campaign_file import CampaignConfig
from estimators.entries import EstimatorSpec
from estimators.plugins import build_estimator
from flight_interface.calibration import CalibrationProducts
from simulator.calibration import simulate_flat_field, true_flat_field

FLAT_FIELD_STREAM = 0xF1A7   # spawn key of the flat-field calibration's noise stream
#: Margin (m/s) above the trajectory set's fastest horizontal speed: a valid answer at or above the sum is
#: ``implausible`` (no estimator can be that far off on a real descent; the reference stays within ~30 m/s
#: of the truth by its 25 m/s bias search range).
PLAUSIBLE_SPEED_MARGIN_MPS = 100.0


def read_only_array(array: np.ndarray) -> np.ndarray:
    """``array`` itself, made read-only (for arrays cached per process and handed to every estimator)."""
    array.setflags(write=False)
    return array


class CampaignInputs(SiteInputs):
    """Camera, trajectory set, terrain, calibration products and estimators of one campaign, loaded once per
    process (through the process's :class:`~campaign.case.site.SharedInputs`).

    Attributes
    ----------
    built_estimators : list of (EstimatorSpec, estimator) or None
        The campaign's estimators once built in this process (:meth:`estimators`).
    max_horizontal_speed_mps : float
        The plausibility bound of a valid answer (m/s): the fastest horizontal speed of any profile of the
        trajectory set, at any time, plus :data:`PLAUSIBLE_SPEED_MARGIN_MPS`.
    """

    def __init__(self, config: CampaignConfig, shared: SharedInputs = PROCESS_SHARED):
        super().__init__(config, shared)
        self.built_estimators: list[tuple[EstimatorSpec, Any]] | None = None   # built on first use
        fastest = max((float(np.hypot(p.velocity_mps[:, 0], p.velocity_mps[:, 1]).max()) for p in self.profiles),
                      default=0.0)
        self.max_horizontal_speed_mps = fastest + PLAUSIBLE_SPEED_MARGIN_MPS

    def calibration(self) -> CalibrationProducts:
        """The campaign's calibration products (``[estimator] flat_field``), made once per process."""
        calibration = self.config.calibration
        if calibration.flat_field == "none":
            return CalibrationProducts(None, "none")
        effects = self.config.scene.camera_effects.model_copy(update={"dark_current_scale": 1.0})   # the detector on the ground
        camera_path = Path(self.config.site.camera_path)
        stat = camera_path.stat()
        if calibration.flat_field == "truth":
            flat = self.shared.get("flat_truth", (str(camera_path), stat.st_size, stat.st_mtime_ns, effects),
                                   lambda _: read_only_array(true_flat_field(self.camera, effects)))
            return CalibrationProducts(flat, "truth")
        frames, seed = calibration.flat_field_frames, self.config.seed
        key = (str(camera_path), stat.st_size, stat.st_mtime_ns, effects, frames, seed)
        flat = self.shared.get("flat_calibrated", key, lambda _: read_only_array(simulate_flat_field(
            self.camera, frames, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))),
            effects)))
        return CalibrationProducts(flat, f"calibrated: {frames} frames")

    def estimators(self) -> list[tuple[EstimatorSpec, Any]]:
        """(spec, estimator object) of every configured estimator, built on first use."""
        if self.built_estimators is None:
            self.built_estimators = [(spec, build_estimator(spec)) for spec in self.config.estimators]
        return self.built_estimators


@dataclass
class ProcessInputs:
    """The campaigns' inputs a process keeps between cases.

    Attributes
    ----------
    campaigns : dict
        Configuration hash -> the campaign's :class:`CampaignInputs`.
    shared : SharedInputs
        Inputs shared by the campaigns (or sweep points) the process serves, by source.
    """

    campaigns: dict[str, CampaignInputs] = field(default_factory=dict)
    shared: SharedInputs = PROCESS_SHARED


PROCESS_INPUTS = ProcessInputs()
"""The inputs of this process (the only instance outside tests)."""


def campaign_inputs(config: CampaignConfig, cache: ProcessInputs = PROCESS_INPUTS) -> CampaignInputs:
    """The campaign's inputs in this process (created on first use; the process is tuned for cases once)."""
    tune_once()
    if config.config_hash not in cache.campaigns:
        cache.campaigns[config.config_hash] = CampaignInputs(config, cache.shared)
    return cache.campaigns[config.config_hash]
