"""Several estimators per case: rendering happens once, each extra estimator costs only its own time.

A fixed set of Gusev cases (one or two per class, the campaign's seeds and fidelity) is run the way a
campaign worker runs it (:func:`campaign.case.compute.compute_case`), once with the reference estimator alone
(``sitedata/gusev.toml``) and once with the reference plus the phase-correlation example
(``sitedata/examples/compare_estimators.toml``), and, on the same case inputs, the rendering alone and
each estimator alone. Times are process CPU ms (one thread; less sensitive to other load on the
machine than wall time, which is given too), medians over cases x ``REPEATS``, the configurations
interleaved. ``extra_minus_phase_correlation_ms`` is the case-time difference minus the
phase-correlation estimator's own time: about 0 when rendering is not repeated (a repeated render would
add ``render_ms``).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REPEATS = 3


def _resources(path: Path):
    from campaign.case.inputs import campaign_inputs
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.planning import plan_campaign

    config = load_campaign_config(path, cases_scale=0.011)          # gcp 2, gdcp 1, gkep 1
    _, plan = plan_campaign(config)
    resources = campaign_inputs(config)
    resources.calibration()                                         # made once per worker, as in a campaign
    resources.estimators()
    return resources, plan


def _timed(function, *args):
    """(result, cpu ms, wall ms) of one call."""
    cpu, wall = time.process_time(), time.perf_counter()
    result = function(*args)
    return result, 1e3 * (time.process_time() - cpu), 1e3 * (time.perf_counter() - wall)


def run() -> list[dict]:
    from campaign.case.compute import compute_case, simulate_case_inputs
    from campaign.case.inputs import PlanRow
    from estimators.contract import EstimatorInputs

    single, plan = _resources(REPO / "sitedata" / "gusev.toml")
    double, plan_double = _resources(REPO / "sitedata" / "examples" / "compare_estimators.toml")
    assert plan.equals(plan_double), "both configurations must plan the same cases"
    cpu: dict[str, list] = {}
    wall: dict[str, list] = {}

    def record(key: str, cpu_ms: float, wall_ms: float) -> None:
        cpu.setdefault(key, []).append(cpu_ms)
        wall.setdefault(key, []).append(wall_ms)

    for row in plan.to_dict("records"):
        compute_case(single, PlanRow.from_record(row))           # warm: terrain strip, caches
        compute_case(double, PlanRow.from_record(row))
        for _ in range(REPEATS):
            _, cpu_ms, wall_ms = _timed(compute_case, single, PlanRow.from_record(row))
            record("case_reference_only", cpu_ms, wall_ms)
            _, cpu_ms, wall_ms = _timed(compute_case, double, PlanRow.from_record(row))
            record("case_reference+phase_correlation", cpu_ms, wall_ms)
            case, cpu_ms, wall_ms = _timed(simulate_case_inputs, double, PlanRow.from_record(row))
            record("render", cpu_ms, wall_ms)
            inputs = EstimatorInputs(tuple(image.dn for image in case.images),
                                     np.array([m.time_s for m in case.measurements.images]), case.measurements,
                                     double.camera, double.calibration())
            for spec, estimator in double.estimators():
                _, cpu_ms, wall_ms = _timed(estimator.estimate, inputs)
                record(spec.name, cpu_ms, wall_ms)
    median = {key: float(np.median(values)) for key, values in cpu.items()}
    extra = (np.array(cpu["case_reference+phase_correlation"]) - np.array(cpu["case_reference_only"]))
    return [{
        "name": "estimators/per_case_cpu", "cases": len(plan), "repeats": REPEATS,
        "render_ms": median["render"], "reference_ms": median["dimes"],
        "phase_correlation_ms": median["phase_correlation"],
        "case_reference_only_ms": median["case_reference_only"],
        "case_two_estimators_ms": median["case_reference+phase_correlation"],
        "extra_ms": float(np.median(extra)),
        "extra_minus_phase_correlation_ms": float(np.median(extra)) - median["phase_correlation"],
        "case_reference_only_wall_ms": float(np.median(wall["case_reference_only"])),
        "case_two_estimators_wall_ms": float(np.median(wall["case_reference+phase_correlation"])),
    }]
