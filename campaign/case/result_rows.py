"""A case's result rows: one per estimator, each its plan row, how the case ran, the estimator's answer and
the case's truth, as the columns :mod:`campaign.store.result_schema` declares (:meth:`ResultRow.columns`;
:func:`case_rows` is the one place that assembles them)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from campaign.case.compute import CaseTruth, EstimatorResult
from campaign.case.inputs import PlanRow
from campaign.store.result_schema import CASE_FILE_SCHEMA, SENSOR_PREFIX


@dataclass(frozen=True)
class CaseRun:
    """How a case ran on its worker (varies from run to run).

    Attributes
    ----------
    attempts : int
        Attempts used (at most ``retries + 1``).
    worker : str
        ``host:pid`` of the worker process.
    t_case_ms : float
        Wall time of the whole case, retries included (ms).
    """

    attempts: int
    worker: str
    t_case_ms: float


@dataclass(frozen=True)
class ResultRow:
    """One result row: a case's plan row, how it ran, one estimator's answer and the case's truth (None when
    the case's simulation failed). Its columns are :data:`campaign.store.result_schema.RESULT_COLUMNS`."""

    plan: PlanRow
    campaign_seed: int
    run: CaseRun
    estimate: EstimatorResult
    truth: CaseTruth | None

    def columns(self) -> dict[str, Any]:
        """Column name -> value (lists for the per-image and per-feature columns)."""
        plan, estimate, truth = self.plan, self.estimate, self.truth
        values: dict[str, Any] = {
            "case_id": plan.case_id, "class_name": plan.class_name, "terrain_name": plan.terrain_name,
            "profile_index": plan.profile_index, "profile_name": plan.profile_name, "heading_rad": plan.heading_rad,
            "offset_east_m": plan.offset_east_m, "offset_north_m": plan.offset_north_m,
            "footprint_inside": plan.footprint_inside, "campaign_seed": self.campaign_seed,
            "attempts": self.run.attempts, "worker": self.run.worker, "t_case_ms": self.run.t_case_ms,
            "estimator": estimate.estimator, "status": estimate.status, "error": estimate.error,
            "estimate_velocity_east_mps": estimate.estimate_velocity_east_mps,
            "estimate_velocity_north_mps": estimate.estimate_velocity_north_mps,
            "valid": estimate.valid, "reason": estimate.reason, "velocity_error_mps": estimate.velocity_error_mps,
            "velocity_uncertainty_mps": estimate.velocity_uncertainty_mps,
            "feature_brightness": _listed(estimate.feature_brightness),
            "feature_contrast": _listed(estimate.feature_contrast),
            "feature_correlation": _listed(estimate.feature_correlation),
            "feature_status": _listed(estimate.feature_status),
            "t_estimator_ms": estimate.t_estimator_ms,
        }
        case_columns = ("truth_velocity_east_mps", "truth_velocity_north_mps", "wind_east_mps", "wind_north_mps",
                        "altitude_image1_m", "altitude_image3_m", "attitude_floor_mps", "heat_shield_in_view",
                        "outside_terrain_fraction", "t_scene_ms", "t_camera_ms", "t_sensors_ms")
        if truth is None:                          # the simulation failed: every case column is null
            values.update({name: None for name in CASE_FILE_SCHEMA.names if name not in values})
        else:
            values.update({name: _listed(getattr(truth, name)) for name in case_columns})
            values.update({f"{SENSOR_PREFIX}{name}": value for name, value in truth.sensor_errors.items()})
        return values


def _listed(value: Any) -> Any:
    """A tuple as a list (an Arrow list value); anything else unchanged."""
    return list(value) if isinstance(value, tuple) else value


def case_rows(plan: PlanRow, campaign_seed: int, estimates: Sequence[EstimatorResult], truth: CaseTruth | None, *,
              attempts: int, worker: str, t_case_ms: float) -> list[dict[str, Any]]:
    """The result rows of one case as their columns (:meth:`ResultRow.columns`), one per estimator (in
    ``estimates`` order); ``attempts``, ``worker`` and ``t_case_ms`` say how it ran (:class:`CaseRun`)."""
    run = CaseRun(attempts=attempts, worker=worker, t_case_ms=t_case_ms)
    return [ResultRow(plan, campaign_seed, run, estimate, truth).columns() for estimate in estimates]
