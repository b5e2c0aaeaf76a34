"""``campaign check-estimators FILE [--cases N]``: every declared estimator on a few planned cases, on the
driver and on a dask worker, against the contract; writes no store.

For each of the first N planned cases (one class after another: case 0 of every class, then case 1, ...)
the case's images, measurements and calibration products are simulated and every ``[[estimators]]`` entry
runs on them twice: in this process (the driver) and in a worker process of a one-worker LocalCluster
(or of ``--scheduler``), after the plug-ins' code was shipped to it exactly as ``campaign submit`` ships
it (:mod:`campaign.run.plugin_setup`). An estimator *violates* the contract when

- it cannot be set up (module does not import, program missing or not executable, bad parameters), on
  the driver or on the worker;
- its answer breaks the output contract or is implausible (:func:`estimators.plugins.run_estimator`:
  the row a campaign would record ``failed``), including a write into a read-only input;
- an input differs after it ran (SHA-256 of the images, times, flat field, measurements and parameters:
  a plug-in that made an input writable again and changed it);
- the driver's and the worker's answers differ (valid flag, reason, velocities and uncertainty, compared
  exactly: the same code on the same inputs must give the same bits).

It prints per estimator the inputs it gets (names, shapes, dtypes, units), its answer per case, its
wall time on the driver and the worker, then one line per violation; :func:`check_estimators` returns the
violation count (the command exits 1 when there is any, 0 when every estimator passes).
"""
from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from campaign.case.compute import estimator_inputs, simulate_case_inputs
from campaign.case.inputs import PlanRow, campaign_inputs
from campaign.configuration.campaign_file import CampaignConfig
from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import connected_client
from campaign.run.planning import plan_campaign
from campaign.run.plugin_setup import PluginSetupError, ship_plugin_code, worker_address
from estimators.contract import EstimatorInputs, EstimatorOutput
from estimators.entries import EstimatorSpec
from estimators.plugins import EstimatorRun, EstimatorSetupError, build_estimator, run_estimator
from file_formats.measurements_json import measurements_to_dict

DEFAULT_CASES = 2
#: unit of an input field, by the end of its name (SI, as everywhere in the code)
UNIT_SUFFIXES = (("_mps", "m/s"), ("_radps", "rad/s"), ("_m", "m"), ("_s", "s"), ("_quat", "unit quaternion w, x, y, z"),
                 ("_world", "unit vector, world frame x east, y north, z up"))


@dataclass(frozen=True)
class CaseOutcome:
    """One estimator on one case in one process: its run, and the inputs it changed (names)."""

    run: EstimatorRun
    changed_inputs: tuple[str, ...]


@dataclass(frozen=True)
class ProcessOutcome:
    """Every estimator on the checked cases in one process (the driver or a worker)."""

    where: str                                   # "driver" or "worker tcp://..."
    setup_errors: dict[str, str]                 # estimator -> one line
    outcomes: dict[str, list[CaseOutcome]]       # estimator -> one per case, in case order


def checked_cases(plan, count: int) -> list[dict]:
    """The first ``count`` plan records taken class after class (case 0 of each class, then case 1, ...)."""
    records = plan.to_dict("records")
    records.sort(key=lambda record: (int(record["case_in_class"]), int(record["class_index"])))
    return records[:count]


def input_digests(inputs: EstimatorInputs) -> dict[str, str]:
    """SHA-256 of every input an estimator could change (names as in :class:`EstimatorInputs`)."""
    def digest(data: bytes) -> str:
        return hashlib.sha256(data).hexdigest()

    flat = inputs.calibration.flat_field
    digests = {f"images[{index}]": digest(np.ascontiguousarray(image).tobytes()) for index, image in enumerate(inputs.images)}
    digests["image_times_s"] = digest(np.ascontiguousarray(inputs.image_times_s).tobytes())
    digests["calibration.flat_field"] = digest(b"" if flat is None else np.ascontiguousarray(flat).tobytes())
    digests["measurements"] = digest(json.dumps(measurements_to_dict(inputs.measurements), sort_keys=True).encode())
    digests["parameters"] = digest(json.dumps(dict(inputs.parameters), sort_keys=True, default=str).encode())
    return digests


def run_checks(config: CampaignConfig, records: list[dict], where: str = "") -> ProcessOutcome:
    """Build every estimator of ``config`` in this process and run it on the cases of ``records`` (a set-up
    error is recorded, not raised); the same function runs on the driver and, as a task, on the worker."""
    resources = campaign_inputs(config)
    built: list[tuple[EstimatorSpec, object]] = []
    setup_errors: dict[str, str] = {}
    for spec in config.estimators:
        try:
            built.append((spec, build_estimator(spec)))
        except EstimatorSetupError as exc:
            setup_errors[spec.name] = str(exc)
    outcomes: dict[str, list[CaseOutcome]] = {spec.name: [] for spec, _ in built}
    for record in records:
        shared = estimator_inputs(resources, simulate_case_inputs(resources, PlanRow.from_record(record)))
        before = input_digests(shared)
        for spec, estimator in built:
            try:
                run = run_estimator(spec.name, estimator, shared, resources.max_horizontal_speed_mps)
            except EstimatorSetupError as exc:          # a command's program could not be started
                setup_errors[spec.name] = str(exc)
                continue
            after = input_digests(shared)
            outcomes[spec.name].append(CaseOutcome(run, tuple(name for name in before if before[name] != after[name])))
            before = after               # a change is charged to the estimator that made it
    return ProcessOutcome(where or f"worker {worker_address()}", setup_errors, outcomes)


def _unit(name: str) -> str:
    return next((unit for suffix, unit in UNIT_SUFFIXES if name.endswith(suffix)), "")


def _array_text(name: str, value, unit: str = "") -> str:
    unit = unit or _unit(name)
    if isinstance(value, np.ndarray):
        return f"{name}: {value.shape} {value.dtype}{', ' + unit if unit else ''}"
    return f"{name}: {type(value).__name__}{', ' + unit if unit else ''}"


def describe_inputs(inputs: EstimatorInputs, spec: EstimatorSpec) -> list[str]:
    """Lines naming what ``spec``'s estimator gets: names, shapes, dtypes and units."""
    images = inputs.images
    lines = [f"images: {len(images)} x {images[0].shape} {images[0].dtype}, DN as read out (read-only)",
             _array_text("image_times_s", inputs.image_times_s)]
    first = inputs.measurements.images[0]
    per_image = "; ".join(_array_text(item.name, getattr(first, item.name)) for item in fields(first)
                          if getattr(first, item.name) is not None)
    lines.append(f"measurements.images: {len(inputs.measurements.images)} x ({per_image})")
    lines.append(_array_text("measurements.sun_direction_world", inputs.measurements.sun_direction_world))
    lines.append(f"camera: {inputs.camera.name} ({inputs.camera.source}), binned shape {inputs.camera.binned_shape}")
    flat = inputs.calibration.flat_field
    lines.append("calibration.flat_field: none" if flat is None else
                 _array_text("calibration.flat_field", flat, f"relative response ({inputs.calibration.flat_field_source})"))
    lines.append(f"parameters: {json.dumps(spec.parameters, default=str, sort_keys=True)[:200]}")
    if spec.kind == "command":
        lines.append(f"as files: images {spec.image_format}, flat field {spec.flat_field_format}, measurements JSON; "
                     f"argv {list(spec.argv)}")
    elif spec.kind == "python" and spec.isolate:
        lines.append("as files (isolate = true): images npy, flat field npy, measurements JSON, in its own process")
    return lines


def _answer(output: EstimatorOutput | None) -> tuple:
    if output is None:
        return ()
    return (output.valid, output.reason, output.velocity_east_mps, output.velocity_north_mps,
            output.velocity_uncertainty_mps)


def _same(first: tuple, second: tuple) -> bool:
    def equal(a, b) -> bool:
        if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
            return True
        return a == b

    return len(first) == len(second) and all(equal(a, b) for a, b in zip(first, second))


def _answer_text(run: EstimatorRun) -> str:
    if run.output is None:
        return f"FAILED ({run.failure}): {run.error}"
    out = run.output
    velocity = ("none" if out.velocity_east_mps is None or out.velocity_north_mps is None
                else f"({out.velocity_east_mps:.4g}, {out.velocity_north_mps:.4g}) m/s east, north")
    uncertainty = "" if out.velocity_uncertainty_mps is None else f", uncertainty {out.velocity_uncertainty_mps:.3g} m/s"
    return f"valid {out.valid}, reason {out.reason}, velocity {velocity}{uncertainty}, {len(out.features)} features"


def violations_of(spec: EstimatorSpec, driver: ProcessOutcome, worker: ProcessOutcome, case_ids: list[int]) -> list[str]:
    """One line per contract violation of ``spec``'s estimator (module docstring)."""
    found = []
    for side in (driver, worker):
        if spec.name in side.setup_errors:
            found.append(f"set-up on the {side.where}: {side.setup_errors[spec.name]}")
    for side in (driver, worker):
        for case_id, outcome in zip(case_ids, side.outcomes.get(spec.name, [])):
            if outcome.run.output is None:
                found.append(f"case {case_id} on the {side.where}: {outcome.run.error}")
            if outcome.changed_inputs:
                found.append(f"case {case_id} on the {side.where}: changed its inputs {', '.join(outcome.changed_inputs)} "
                             "(inputs are read-only: copy what you need to change)")
    pairs = zip(case_ids, driver.outcomes.get(spec.name, []), worker.outcomes.get(spec.name, []))
    for case_id, on_driver, on_worker in pairs:
        if not _same(_answer(on_driver.run.output), _answer(on_worker.run.output)):
            found.append(f"case {case_id}: driver and worker answers differ: driver {_answer(on_driver.run.output)}, "
                         f"worker {_answer(on_worker.run.output)}")
    return found


def _worker_execution(config: CampaignConfig, scheduler: str | None) -> ExecutionConfig:
    """Where the worker side runs: the ``--scheduler`` given, with the campaign's ``[execution]`` certificate
    files (a ``tls://`` scheduler needs them), else a one-worker LocalCluster."""
    if scheduler:
        return config.execution.with_overrides(scheduler=scheduler)
    return ExecutionConfig.model_validate({"cluster": "local", "workers": 1})


def check_estimators(config: CampaignConfig, cases: int = DEFAULT_CASES, scheduler: str | None = None,
                     out: Callable[[str], None] = print) -> int:
    """Run the check (module docstring), print the report with ``out``; return the number of violations.

    Parameters
    ----------
    config : CampaignConfig
        The campaign (loaded within :func:`estimators.entries.plugin_imports_deferred`, so that a module
        that does not import is reported here rather than refusing the file).
    cases : int
        Planned cases to run every estimator on (>= 1).
    scheduler : str, optional
        ``tcp://host:port`` or ``tls://host:port`` (with the ``[execution]`` certificate files) of a running
        dask scheduler whose worker runs the worker side (default: a one-worker LocalCluster started and
        closed here).
    """
    _, plan = plan_campaign(config)
    records = checked_cases(plan, cases)
    case_ids = [int(record["case_id"]) for record in records]
    with connected_client(_worker_execution(config, scheduler), quiet=True) as client:
        shipping_errors: dict[str, str] = {}
        try:
            ship_plugin_code(client, config.estimators)
        except PluginSetupError as exc:         # the others still run; the broken one fails its build there too
            names = str(exc).split(" cannot be set up")[0].removeprefix("estimator ").split(", ")
            shipping_errors = {name: str(exc) for name in names}
        on_worker = client.submit(run_checks, config, records, pure=False)
        driver = run_checks(config, records, where="driver")            # meanwhile, in this process
        try:
            worker = on_worker.result()
        except Exception as exc:  # the worker could not run the cases at all: every estimator's violation
            text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
            worker = ProcessOutcome("worker", {spec.name: f"the worker could not run the cases: {text}"
                                               for spec in config.estimators}, {})
        worker.setup_errors.update({name: line for name, line in shipping_errors.items() if name not in worker.setup_errors})
    resources = campaign_inputs(config)
    sample = estimator_inputs(resources, simulate_case_inputs(resources, PlanRow.from_record(records[0])))
    out(f"{config.source}: {len(config.estimators)} estimators on {len(records)} planned cases "
        f"({', '.join(map(str, case_ids))}), on the driver and on the {worker.where}")
    total = 0
    for spec in config.estimators:
        target = spec.callable if spec.kind == "python" else " ".join(spec.argv) if spec.kind == "command" else "dimes_velocity"
        out(f"\nestimator {spec.name} ({spec.kind}: {target})")
        out("  inputs:")
        for line in describe_inputs(sample, spec):
            out(f"    {line}")
        for case_id, index in zip(case_ids, range(len(records))):
            for side in (driver, worker):
                runs = side.outcomes.get(spec.name, [])
                if index < len(runs):
                    run = runs[index].run
                    out(f"  case {case_id} {side.where.split(' ')[0]}: {_answer_text(run)}  [{run.elapsed_ms:.1f} ms]")
        problems = violations_of(spec, driver, worker, case_ids)
        total += len(problems)
        out(f"  {'PASS' if not problems else f'FAIL: {len(problems)} violations'}")
        for problem in problems:
            out(f"    violation: {problem}")
    out(f"\n{'all estimators keep the contract' if total == 0 else f'{total} contract violations'}")
    return total
