"""The ``campaign`` commands, one function each (:mod:`campaign.cli` parses the command line and maps what they
raise to exit codes).

Each command imports its own stack (dask, pandas, matplotlib, the simulator, the estimator) inside its
function, when it runs: a read-only command (``status``, ``verify``, ``table``, ``schema``) loads only the
store or configuration modules it reads, the command line starts in a fraction of a second, and dask worker
processes, which re-import the command line as their __main__, do not load the report and flight-comparison
stacks. These are, with :mod:`campaign.cli`, the only function-local imports of project modules
(tests/test_layers.py allows them here only).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from campaign.run.faults import RunStopped
from config_tables.errors import ConfigError

if TYPE_CHECKING:
    import pandas as pd

    from campaign.configuration.campaign_file import CampaignConfig
    from campaign.report.compare import EstimatorCounts

COMMAND_LINE = "command line"
RUN_INCOMPLETE = 1      # exit code: cases failed, a run stopped, or a regression


def _check_cluster_flags(args: argparse.Namespace) -> None:
    """--workers and --scheduler against the [execution] declarations (before anything is loaded or written)."""
    from campaign.configuration.execution import ExecutionConfig
    from config_tables.models import parse_field

    for flag, field in (("--workers", "workers"), ("--scheduler", "scheduler")):
        value = getattr(args, field, None)
        if value is not None:
            parse_field(ExecutionConfig, field, value, COMMAND_LINE, flag)


def camera(args: argparse.Namespace) -> int:
    """``campaign camera FILE``: validate a camera TOML and print its derived numbers."""
    import numpy as np

    from flight_interface.camera import load_camera
    from simulator.detector import psf

    camera = load_camera(args.file)
    horizontal, vertical = camera.fov_deg()
    print(f"{camera.name}: {camera.width_px}x{camera.height_px} px, binned {camera.binned_shape[0]}x"
          f"{camera.binned_shape[1]}, FOV {horizontal:.2f} x {vertical:.2f} deg, "
          f"focal {camera.model.hs:.1f} px, response {camera.responsivity_e_per_s:.4g} e-/s per W m^-2 sr^-1 um^-1, "
          f"dark {camera.electronics.dark_current_e_per_s():.4g} e-/s at {camera.electronics.ccd_temperature_k - 273.15:.1f} C")
    nyquist = 0.5 / camera.pixel_pitch_m
    frequency = np.asarray(nyquist)            # cycles/m (the MTFs take any shape)
    optics_mtf, pixel_mtf = float(psf.optics_mtf(frequency, camera)), float(psf.pixel_mtf(frequency, camera.pixel_pitch_m))
    ee80_um = 1e6 * psf.encircled_energy_radius_m(camera, 0.8)
    print(f"optics: MTF at the pixel Nyquist frequency ({nyquist * 1e-3:.1f} cycles/mm) {optics_mtf:.3f} optics x "
          f"{pixel_mtf:.3f} pixel = {optics_mtf * pixel_mtf:.3f}; 80 % encircled energy within {ee80_um:.2f} um "
          f"({ee80_um * 1e-6 / camera.pixel_pitch_m:.2f} px) of the optics PSF")
    return 0


def _check_directory(path: str | Path | None, what: str) -> None:
    """An output directory given on the command line or in a file must be a directory if it exists."""
    if path is not None and Path(path).exists() and not Path(path).is_dir():
        raise ConfigError(f"{what} = {str(path)!r} exists and is not a directory; allowed: a directory (new or existing)")


def _load(args: argparse.Namespace) -> CampaignConfig:
    """The command's campaign file, validated with its command-line overrides (nothing written)."""
    from campaign.configuration.campaign_file import load_campaign_config

    _check_cluster_flags(args)
    _check_directory(getattr(args, "output", None), "--output")
    _check_directory(getattr(args, "out", None), "--out")
    config = load_campaign_config(args.file, output_dir=getattr(args, "output", None),
                                  cases_scale=getattr(args, "cases_scale", None))
    args.store_dir = config.output_dir          # what an interrupt reports as kept (main)
    _check_directory(config.output_dir, f"{args.file}: campaign.output_dir")
    return config


def submit(args: argparse.Namespace) -> int:
    """``campaign submit FILE``: plan, run every missing case, then print (and write) the paper's table."""
    from campaign.report.table import write_table
    from campaign.run.orchestrate import submit as run_campaign
    from campaign.store.campaign_store import CampaignStore

    start = time.perf_counter()
    config = _load(args)
    summary = run_campaign(config, scheduler=args.scheduler, workers=args.workers, fresh=args.fresh,
                           progress=not args.no_progress, wait=args.wait)
    print(write_table(config.output_dir, config.false_valid_mps))
    store = CampaignStore(config.output_dir)
    results = store.results()
    counts = _estimator_counts(results)
    print(f"results: {config.output_dir}  ({summary.done} done, {summary.failed} failed this run)"
          f"{_failed_rows_note(counts)}")
    print(f"wall time: {time.perf_counter() - start:.1f} s")
    status = store.status()
    failed_rows = _report_failed_rows(results)
    return 0 if status.failed == 0 and status.missing == 0 and not failed_rows else RUN_INCOMPLETE


def _estimator_counts(results: pd.DataFrame) -> list[EstimatorCounts]:
    """Per estimator its valid / invalid / failed rows (campaign.report.compare.estimator_counts)."""
    from campaign.report.compare import estimator_counts

    return estimator_counts(results) if not results.empty else []


def _failed_rows_note(counts: list[EstimatorCounts]) -> str:
    """"; estimator rows failed: NAME N, ... (stderr)" after the results line, "" when none failed."""
    failed = [f"{count.name} {count.failed}" for count in counts if count.failed]
    return f"; estimator rows failed: {', '.join(failed)} (every kind on stderr)" if failed else ""


def _report_failed_rows(results: pd.DataFrame) -> int:
    """The last lines on stderr: per estimator with failed rows every kind of failure with its count and one
    example (campaign.report.failures); the number of failed rows (the store's, not only this run's: a failed
    row is kept and never retried)."""
    from campaign.report.failures import failure_report_lines, failure_summary

    summaries = failure_summary(results)
    for line in failure_report_lines(summaries):
        print(f"campaign: {line}", file=sys.stderr, flush=True)
    return sum(summary.failed for summary in summaries)


def plan(args: argparse.Namespace) -> int:
    """``campaign plan FILE``: print the plan and write the footprint maps."""
    from campaign.report.plan_maps import write_plan_maps
    from campaign.run.planning import plan_campaign

    config = _load(args)
    site, plan = plan_campaign(config)
    print(f"campaign {config.source} (site {config.site.name}, seed {config.seed}, hash {config.config_hash[:12]})")
    for class_name, members in plan.groupby("class_name", sort=False):
        print(f"  {class_name}: {len(members)} cases on {members['terrain_name'].iloc[0]}, "
              f"{members['profile_index'].nunique()} trajectories, "
              f"{int(members['footprint_inside'].sum())} with all footprints inside the strip")
    out_dir = Path(args.out) if args.out else config.output_dir / "plan"
    for path in write_plan_maps(config, site, plan, out_dir):
        print(f"wrote {path}")
    return 0


def status(args: argparse.Namespace) -> int:
    """``campaign status DIR``: done / failed / missing cases of a store (per point of a sweep directory) and
    the failed rows of each estimator; 1 when there are failed rows, else 0."""
    from campaign.store.campaign_store import CampaignStore

    if _sweep_point(args) is None and _is_sweep(args.dir):
        from campaign.store.sweep_directory import sweep_status_lines  # a sweep output directory: its point stores

        print("\n".join(sweep_status_lines(args.dir)))
        return 0
    counts = CampaignStore(args.dir).status()
    print(f"{args.dir}: {counts.planned} planned, {counts.done} done, {counts.failed} failed, {counts.missing} missing")
    if counts.bad:
        foreign = f", {counts.foreign} of them foreign (another campaign's or without identity)" if counts.foreign else ""
        print(f"{args.dir}: {counts.bad} bad case files not counted{foreign} (`campaign verify {args.dir}` lists them; "
              "the next submit moves them to rejected/ and computes their cases again)")
    if counts.rejected:
        print(f"{args.dir}: {counts.rejected} files rejected earlier, in rejected/ (rejected/rejected.log says why)")
    if counts.outside_plan:
        print(f"{args.dir}: {counts.outside_plan} case files of cases outside the plan (kept, not counted)")
    for name, rows in counts.failed_rows.items():
        print(f"{args.dir}: estimator {name}: {rows} failed rows (of {counts.done + counts.failed} finished cases)")
    return 1 if counts.failed_rows else 0


def _is_sweep(directory: str) -> bool:
    from campaign.store.sweep_directory import is_sweep_directory

    return is_sweep_directory(directory)


def _sweep_point(args: argparse.Namespace) -> str | None:
    """``--point ID`` of a sweep directory: ``args.dir`` becomes the point's store (its path); None without
    ``--point``. ``--point`` on a campaign store is a usage error (one line)."""
    point = getattr(args, "point", None)
    if point is None:
        return None
    if not _is_sweep(args.dir):
        raise ConfigError(f"--point {point}: {args.dir} is not a sweep output directory; allowed: --point with a "
                          "sweep directory (a campaign store needs none)")
    from campaign.store.sweep_directory import point_store

    args.dir = str(point_store(args.dir, point))
    return point


def _require_store_or_sweep(directory: str) -> None:
    """``table`` and ``report`` read a store or a sweep directory: anything else is one line saying which."""
    if not (Path(directory) / "manifest.json").exists() and not _is_sweep(directory):
        from campaign.store.errors import StoreError

        raise StoreError(f"{directory}: not a campaign store (no manifest.json) and not a sweep output directory (no "
                         "sweep.json, no points/); allowed: the output directory of `campaign submit` or `campaign sweep`")


def _each_point(args: argparse.Namespace) -> list[tuple[str, str]]:
    """The (label, store) of every point of the sweep directory ``args.dir`` that has a store (status,
    verify and report run per point without ``--point``)."""
    from campaign.store.sweep_directory import point_choices, point_label

    return [(point_label(point_id, values), str(store)) for point_id, values, store in point_choices(args.dir)
            if (store / "manifest.json").exists()]


def verify(args: argparse.Namespace) -> int:
    """``campaign verify DIR``: check every file of a store against its sha256 record; 1 when one is bad. A sweep
    directory: every point's store (or ``--point``'s), one summary line each."""
    from campaign.store.verify import verify_store

    if _sweep_point(args) is None and _is_sweep(args.dir):
        bad = 0
        points = _each_point(args)
        for label, store in points:
            result = verify_store(store)
            for path, problem in result.problems:
                print(f"{path}: {problem}")
            bad += len(result.problems)
            print(f"{label}: {f'{len(result.problems)} bad files' if result.problems else 'clean'} "
                  f"({result.verified_cases} case files, {store})")
        print(f"{args.dir}: sweep of {len(points)} point stores: {'clean' if not bad else f'{bad} bad files'}")
        return 1 if bad else 0
    result = verify_store(args.dir)
    for path, problem in result.problems:
        print(f"{path}: {problem}")
    for note in result.notes:
        print(f"note: {note}")
    if result.problems:
        print(f"{args.dir}: {len(result.problems)} bad files (`campaign submit` moves bad case files to rejected/ "
              "and computes them again)")
        return 1
    print(f"{args.dir}: clean: manifest.json, plan.parquet, {result.verified_cases} case files and the compacted "
          "results match their sha256 records")
    return 0


def table(args: argparse.Namespace) -> int:
    """``campaign table DIR``: print the paper's table (also written as table.md and table.csv in DIR)."""
    from campaign.report.table import write_table

    _require_store_or_sweep(args.dir)
    if _sweep_point(args) is None and _is_sweep(args.dir):
        from campaign.report.sweep_outputs import directory_table

        print(directory_table(args.dir))
        print(f"one point's campaign table: `campaign table {args.dir} --point ID`")
        return 0
    print(write_table(Path(args.dir)))
    return 0


def report(args: argparse.Namespace) -> int:
    """``campaign report DIR``: a Markdown report with PNG plots and the failure gallery (a sweep directory:
    every point's, in its store, or ``--point``'s)."""
    from campaign.report.markdown import write_report

    _require_store_or_sweep(args.dir)
    if _sweep_point(args) is None and _is_sweep(args.dir):
        points = _each_point(args)
        for label, store in points:
            print(f"{label}: wrote {write_report(Path(store))}")
        print(f"{args.dir}: reports of {len(points)} points (each with gallery.md and PNGs in its store); the sweep's "
              f"own table and plots: {Path(args.dir) / 'sensitivity.md'}, {Path(args.dir) / 'plots'}")
        return 0
    path = write_report(Path(args.dir))
    print(f"wrote {path} and {path.parent / 'gallery.md'} (failure gallery), with their PNGs in {path.parent}")
    return 0


def sweep(args: argparse.Namespace) -> int:
    """``campaign sweep FILE``: run a sensitivity sweep, write its outputs, judge it against ``--baseline``."""
    from campaign.configuration.sweep_file import load_sweep
    from campaign.report.gate import gate, human_table, read_side, rules_of, write_verdict
    from campaign.report.sweep_baseline import read_baseline
    from campaign.report.sweep_outputs import sweep_results, write_outputs
    from campaign.run.sweep import Reuse, reuse_points, run_sweep
    from campaign.store.sweep_directory import write_description

    start = time.perf_counter()
    _check_cluster_flags(args)
    _check_directory(args.output, "--output")
    spec = load_sweep(args.file, output_dir=args.output, cases_scale=args.cases_scale)   # validates, writes nothing
    _check_directory(spec.output_dir, f"{args.file}: sweep.output_dir")
    baseline = read_baseline(args.baseline, spec) if args.baseline else None   # before the run: as it was
    reuse = reuse_points(spec, args.reuse, progress=not args.no_progress) if args.reuse else Reuse()
    for note in reuse.notes:
        print(f"campaign: note: --reuse: {note}", file=sys.stderr, flush=True)
    try:
        run = run_sweep(spec, scheduler=args.scheduler, workers=args.workers, progress=not args.no_progress,
                        wait=args.wait)
    except RunStopped:
        if any((point.config.output_dir / "manifest.json").exists() for point in spec.points):
            write_description(spec, reuse.reused)       # a stopped sweep's points, for `campaign status`
        raise
    _, text = write_outputs(spec, reuse.reused)
    verdict = None
    if baseline is not None:     # judged and written before anything is printed: `| head -1` shows the verdict
        candidate = read_side(spec.output_dir, "candidate")
        report = gate(candidate, baseline.side, rules_of(candidate), baseline.rows)
        verdict_path, _ = write_verdict(report, Path(spec.output_dir) / "gate.json")
        verdict = report
        if not _print_lines([report.summary(verdict_path)]):
            return report.exit_code
    if not _print_lines([text]):
        return verdict.exit_code if verdict is not None else RUN_INCOMPLETE
    results = sweep_results(spec)                               # every point store's rows, not only this run's
    counts = _estimator_counts(results)
    copied = f", {len(reuse.reused)} copied from {args.reuse}" if args.reuse else ""
    _print_lines([f"results: {spec.output_dir}  ({run.points} points, {run.reused_points} reused{copied}; {run.done} "
                  f"cases done, {run.failed} failed this run){_failed_rows_note(counts)}",
                  f"wall time: {time.perf_counter() - start:.1f} s"])
    failed_rows = _report_failed_rows(results)
    unfinished = run.unfinished or failed_rows
    if verdict is None:
        return RUN_INCOMPLETE if unfinished else 0
    _print_lines([human_table(verdict)])
    return verdict.exit_code if verdict.regressions else RUN_INCOMPLETE if unfinished else 0


def _print_lines(lines: list[str]) -> bool:
    """Print ``lines`` and flush; False when stdout's reader has gone (``| head -1``): stdout is sent to
    /dev/null and the command ends with its own exit code (not 141: a gate's verdict is not hidden)."""
    try:
        for line in lines:
            print(line)
        sys.stdout.flush()
        return True
    except BrokenPipeError:
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (AttributeError, OSError, ValueError):
            pass
        return False


def gate(args: argparse.Namespace) -> int:
    """``campaign gate CANDIDATE --baseline BASELINE``: judge two campaign stores or two sweep directories
    (campaign.report.gate); write gate.json and gate.md, print the verdict line first, then the table. Exit 4
    on a regression, 1 when the candidate has failed or missing cases, else 0."""
    from campaign.report.gate import gate as run_gate
    from campaign.report.gate import human_table, read_side, rules_of, write_verdict

    candidate = read_side(args.dir, "candidate")
    baseline = read_side(args.baseline, "baseline")
    report = run_gate(candidate, baseline, rules_of(candidate, args.tolerances))
    verdict_path, _ = write_verdict(report, Path(args.verdict) if args.verdict else Path(args.dir) / "gate.json")
    _print_lines([report.summary(verdict_path), *human_table(report).splitlines()[1:]])
    return report.exit_code




def sensitivity(args: argparse.Namespace) -> int:
    """``campaign sensitivity DIR``: the PAWN sensitivity of each estimator's outputs to every recorded input
    (campaign.analysis.sensitivity), for a store or for every point of a sweep directory."""
    from campaign.analysis.sensitivity import AnalysisSettings, analyse_store
    from campaign.store.sweep_directory import read_description

    if not 10 <= args.resamples <= 100_000:
        raise ConfigError(f"--resamples = {args.resamples}; allowed: 10 to 100000")
    settings = AnalysisSettings(resamples=args.resamples, seed=args.seed)
    directory = Path(args.dir)
    if (directory / "sweep.json").is_file() and not (directory / "manifest.json").is_file():
        for point in read_description(directory)["points"]:
            print(f"== point {point['point_id']} {point['values']}")
            print(analyse_store(directory / point["store"], settings, args.estimator))
        return 0
    print(analyse_store(directory, settings, args.estimator), end="")
    return 0


def compare_flight(args: argparse.Namespace) -> int:
    """``campaign compare-flight FLIGHT.toml``: real descent images beside the simulator's view of their poses."""
    from campaign.realism.compare_flight import compare, load_flight, summary_lines

    _check_directory(args.out, "--out")
    spec = load_flight(args.file, output_dir=args.out, column=args.column)   # validates everything, writes nothing
    _check_directory(spec.output_dir, f"{args.file}: output_dir")
    summary = compare(spec)
    for line in summary_lines(summary):
        print(line)
    print(f"written to {spec.output_dir}: side-by-side, column and scatter PNGs, comparison.json, pixels.csv, features.csv")
    return 0


def export(args: argparse.Namespace) -> int:
    """``campaign export DIR CASE_ID OUT``: a case's exact estimator inputs and its truth as files, and per
    estimator (reference, python, command) its parameters and the command that replays its stored row."""
    from campaign.case.export import export_case

    written = export_case(args.dir, args.case_id, args.out)
    record = json.loads((Path(args.out) / "truth.json").read_text())
    print(f"wrote {len(written)} files to {args.out}: {', '.join(path.name for path in written)}")
    for entry in record["estimators"]:        # every estimator, every kind: its stored row, bit for bit
        answer = "answer on stdout" if entry["answer"] == "stdout" else f"answer in {entry['answer']}"
        print(f"replay {entry['name']} ({entry['kind']}, {answer}): {entry['replay']}")
    if not record["config_hash_matches_store"]:
        print(f"campaign: note: {args.dir} was computed by other code or input files (configuration hash differs): "
              "the export is of today's case, whose answer may differ from the stored one", file=sys.stderr)
    return 0


def cluster(args: argparse.Namespace) -> int:
    """``campaign cluster FILE``: print the job script or pod spec a submit would use (submits nothing)."""
    from campaign.run.cluster import cluster_description, require_backend

    config = _load(args)
    execution = config.execution.with_overrides(args.scheduler, args.workers)
    require_backend(execution, str(config.source))
    text, note = cluster_description(execution)
    print(text)
    print(f"campaign: note: {note}; nothing was submitted", file=sys.stderr)
    return 0


def check_estimators(args: argparse.Namespace) -> int:
    """``campaign check-estimators FILE``: every estimator on a few planned cases, on the driver and a worker."""
    if args.cases < 1:           # before the stack is imported: a usage error is instant
        raise ConfigError(f"--cases = {args.cases} is not allowed; allowed: an integer >= 1")
    from campaign.run.check_estimators import check_estimators as run_checks
    from estimators.entries import plugin_imports_deferred

    _check_cluster_flags(args)
    with plugin_imports_deferred():      # a module that does not import is the estimator's violation (exit 1)
        config = _load(args)
    return 1 if run_checks(config, args.cases, args.scheduler) else 0


def schema(args: argparse.Namespace) -> int:
    """``campaign schema [TABLE]``: the JSON Schema of every configuration table, or of one."""
    from campaign.configuration.schemas import all_schemas, table_schema

    print(json.dumps(table_schema(args.table) if args.table else all_schemas(), indent=2))
    return 0
