"""The ``campaign`` command line.

    campaign submit FILE   plan, run every missing case on dask, store, print the paper's table
    campaign plan FILE     print the plan and write footprint maps (PNG) without running anything
    campaign status DIR    done / failed / missing cases, from the store's verified case files
    campaign verify DIR    check every file of a store (sha256 records); list bad files, exit 1 if any
    campaign table DIR     the paper's table (also written as table.md and table.csv in DIR)
    campaign report DIR    a Markdown report with PNG plots
    campaign camera FILE   validate a camera TOML and print its derived numbers
    campaign cluster FILE  print the job script / pod spec a submit would use (submits nothing)
    campaign sweep FILE    run a sensitivity sweep (base campaign x parameter axes); --baseline DIR
    campaign compare-flight FLIGHT.toml   real descent images next to the simulator's view of the same poses
    campaign export DIR CASE_ID OUT   a case's exact estimator inputs and its truth as files (replay it)
    campaign schema [T]    print the JSON Schema of every configuration table, or of table T

Exit codes: 0 success (every case done, no estimator row failed), 1 cases failed or missing, an estimator's
row failed in the store (submit and sweep: one stderr line per such estimator with the count and the first
reason, e.g. ``campaign: estimator flight: 4 of 4 rows failed; first: case 0 (estimator_failed): ...``),
a run stopped (one line naming the
cause and the fix: campaign.run.faults), a sweep regressed, another writer holds the store's lock (one line
naming it; ``--wait`` waits instead) or ``verify`` found bad files, 2 usage or configuration
error (one clear line on stderr, nothing written; also a path the system refuses and running out of memory),
3 internal error (one line; CAMPAIGN_TRACEBACK=1 shows the traceback), 130 interrupted (one line saying what the
store kept), 141 stdout closed by its reader (silent). Never a traceback (see main). Command-line values (--cases-scale, --workers,
--scheduler) are validated against the same declarations as the TOML fields, before anything is written.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from pathlib import Path

from campaign.configuration.paths import check_input_file, check_output_dir, check_path_text
from campaign.configuration.schemas import SCHEMA_TABLES, all_schemas, table_schema
from campaign.run.faults import RunStopped
from campaign.store.errors import StoreError
from campaign.store.lock import StoreBusy
from flight_interface.camera import load_camera
from flight_interface.command_line import USAGE_ERROR
from flight_interface.command_line import OneLineParser as _Parser
from flight_interface.tomlfields import ConfigError, parse_field

# Each command imports its own stack (dask, pandas, matplotlib, the simulator, the estimator) inside its
# handler, when it runs: the command line then starts in about 0.8 s instead of 3 s for every command
# (`campaign camera`, `status`, `schema`, a refused file), and dask worker processes, which re-import this
# module as their __main__, do not load the report and flight-comparison stacks. These are the only
# function-local imports of project modules (tests/test_layers.py allows them here only).

COMMAND_LINE = "command line"
RUN_INCOMPLETE = 1      # exit code: cases failed, a run stopped, or a regression
INTERNAL_ERROR = 3      # exit code: an unexpected exception (a bug), one line
INTERRUPTED = 130       # exit code: Ctrl-C (128 + SIGINT)
BROKEN_PIPE = 141       # exit code: stdout's reader closed the pipe (128 + SIGPIPE), silent


def _check_cluster_flags(args) -> None:
    """--workers and --scheduler against the [execution] declarations (before anything is loaded or written)."""
    from campaign.configuration.execution import ExecutionConfig

    for flag, field in (("--workers", "workers"), ("--scheduler", "scheduler")):
        value = getattr(args, field, None)
        if value is not None:
            parse_field(ExecutionConfig, field, value, COMMAND_LINE, flag)


def _cmd_camera(args) -> int:
    from simulator.detector import psf

    camera = load_camera(args.file)
    horizontal, vertical = camera.fov_deg()
    print(f"{camera.name}: {camera.width_px}x{camera.height_px} px, binned {camera.binned_shape[0]}x"
          f"{camera.binned_shape[1]}, FOV {horizontal:.2f} x {vertical:.2f} deg, "
          f"focal {camera.model.hs:.1f} px, response {camera.responsivity_e_per_s:.4g} e-/s per W m^-2 sr^-1 um^-1, "
          f"dark {camera.electronics.dark_current_e_per_s():.4g} e-/s at {camera.electronics.ccd_temperature_k - 273.15:.1f} C")
    nyquist = 0.5 / camera.pixel_pitch_m
    optics_mtf, pixel_mtf = float(psf.optics_mtf(nyquist, camera)), float(psf.pixel_mtf(nyquist, camera.pixel_pitch_m))
    ee80_um = 1e6 * psf.encircled_energy_radius_m(camera, 0.8)
    print(f"optics: MTF at the pixel Nyquist frequency ({nyquist * 1e-3:.1f} cycles/mm) {optics_mtf:.3f} optics x "
          f"{pixel_mtf:.3f} pixel = {optics_mtf * pixel_mtf:.3f}; 80 % encircled energy within {ee80_um:.2f} um "
          f"({ee80_um * 1e-6 / camera.pixel_pitch_m:.2f} px) of the optics PSF")
    return 0


def _check_directory(path, what: str) -> None:
    """An output directory given on the command line or in a file must be a directory if it exists."""
    if path is not None and Path(path).exists() and not Path(path).is_dir():
        raise ConfigError(f"{what} = {str(path)!r} exists and is not a directory; allowed: a directory (new or existing)")


def _load(args):
    from campaign.configuration.campaign_file import load_campaign_config

    _check_cluster_flags(args)
    _check_directory(getattr(args, "output", None), "--output")
    _check_directory(getattr(args, "out", None), "--out")
    config = load_campaign_config(args.file, output_dir=getattr(args, "output", None),
                                  cases_scale=getattr(args, "cases_scale", None))
    args.store_dir = config.output_dir          # what an interrupt reports as kept (main)
    _check_directory(config.output_dir, f"{args.file}: campaign.output_dir")
    return config


def _cmd_submit(args) -> int:
    from campaign.run.orchestrate import submit
    from campaign.store.campaign_store import CampaignStore

    start = time.perf_counter()
    config = _load(args)
    summary, table_text = submit(config, scheduler=args.scheduler, workers=args.workers, fresh=args.fresh,
                                 progress=not args.no_progress, wait=args.wait)
    print(table_text)
    store = CampaignStore(config.output_dir)
    counts = _estimator_counts(store.results())
    print(f"results: {config.output_dir}  ({summary.done} done, {summary.failed} failed this run)"
          f"{_failed_rows_note(counts)}")
    print(f"wall time: {time.perf_counter() - start:.1f} s")
    status = store.status()
    failed_rows = _report_failed_rows(counts)
    return 0 if status.failed == 0 and status.missing == 0 and not failed_rows else RUN_INCOMPLETE


def _estimator_counts(results) -> list:
    """Per estimator its valid / invalid / failed rows (campaign.report.compare.estimator_counts)."""
    from campaign.report.compare import estimator_counts

    return estimator_counts(results) if not results.empty else []


def _failed_rows_note(counts: list) -> str:
    """"; estimator rows failed: NAME N, ... (stderr)" after the results line, "" when none failed."""
    failed = [f"{count.name} {count.failed}" for count in counts if count.failed]
    return f"; estimator rows failed: {', '.join(failed)} (reasons on stderr)" if failed else ""


def _report_failed_rows(counts: list) -> int:
    """One stderr line per estimator with failed rows (count and first reason); the number of failed rows
    (the store's, not only this run's: a failed row is kept and never retried)."""
    from campaign.report.compare import failure_lines

    for line in failure_lines(counts):
        print(f"campaign: {line}", file=sys.stderr, flush=True)
    return sum(count.failed for count in counts)


def _cmd_plan(args) -> int:
    from campaign.run.orchestrate import plan_campaign, write_plan_maps

    config = _load(args)
    resources, plan = plan_campaign(config)
    print(f"campaign {config.source} (site {config.site.name}, seed {config.seed}, hash {config.config_hash[:12]})")
    for class_name, members in plan.groupby("class_name", sort=False):
        print(f"  {class_name}: {len(members)} cases on {members['terrain_name'].iloc[0]}, "
              f"{members['profile_index'].nunique()} trajectories, "
              f"{int(members['footprint_inside'].sum())} with all footprints inside the strip")
    out_dir = Path(args.out) if args.out else config.output_dir / "plan"
    for path in write_plan_maps(config, resources, plan, out_dir):
        print(f"wrote {path}")
    return 0


def _cmd_status(args) -> int:
    from campaign.store.campaign_store import CampaignStore

    swept = (Path(args.dir) / "sweep.json").is_file() or (Path(args.dir) / "points").is_dir()
    if swept and not (Path(args.dir) / "manifest.json").exists():
        from campaign.run.sweep_baseline import sweep_status_lines  # a sweep output directory: its point stores

        print("\n".join(sweep_status_lines(args.dir)))
        return 0
    status = CampaignStore(args.dir).status()
    print(f"{args.dir}: {status.planned} planned, {status.done} done, {status.failed} failed, {status.missing} missing")
    if status.bad:
        foreign = f", {status.foreign} of them foreign (another campaign's or without identity)" if status.foreign else ""
        print(f"{args.dir}: {status.bad} bad case files not counted{foreign} (`campaign verify {args.dir}` lists them; "
              "the next submit moves them to rejected/ and computes their cases again)")
    if status.rejected:
        print(f"{args.dir}: {status.rejected} files rejected earlier, in rejected/ (rejected/rejected.log says why)")
    if status.outside_plan:
        print(f"{args.dir}: {status.outside_plan} case files of cases outside the plan (kept, not counted)")
    return 0


def _cmd_verify(args) -> int:
    from campaign.store.verify import verify_store

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


def _cmd_table(args) -> int:
    from campaign.run.orchestrate import write_table

    print(write_table(Path(args.dir)))
    return 0


def _cmd_report(args) -> int:
    from campaign.report.markdown import write_report

    path = write_report(Path(args.dir))
    print(f"wrote {path} and {path.parent / 'gallery.md'} (failure gallery), with their PNGs in {path.parent}")
    return 0


def _cmd_sweep(args) -> int:
    from campaign.configuration.sweep_file import load_sweep
    from campaign.report.baseline_gate import format_findings
    from campaign.run.sweep import run_sweep, sweep_results, write_description, write_outputs
    from campaign.run.sweep_baseline import compare_to_baseline, read_baseline

    start = time.perf_counter()
    _check_cluster_flags(args)
    _check_directory(args.output, "--output")
    spec = load_sweep(args.file, output_dir=args.output, cases_scale=args.cases_scale)   # validates, writes nothing
    _check_directory(spec.output_dir, f"{args.file}: sweep.output_dir")
    baseline = read_baseline(args.baseline, spec) if args.baseline else None   # before the run: as it was
    try:
        run = run_sweep(spec, scheduler=args.scheduler, workers=args.workers, progress=not args.no_progress,
                        wait=args.wait)
    except RunStopped:
        if any((point.config.output_dir / "manifest.json").exists() for point in spec.points):
            write_description(spec)       # a stopped sweep's points, for `campaign status`
        raise
    table, text = write_outputs(spec)
    print(text)
    results = sweep_results(spec)                               # every point store's rows, not only this run's
    counts = _estimator_counts(results)
    print(f"results: {spec.output_dir}  ({run.points} points, {run.reused_points} reused; {run.done} cases done, "
          f"{run.failed} failed this run){_failed_rows_note(counts)}")
    print(f"wall time: {time.perf_counter() - start:.1f} s")
    failed_rows = _report_failed_rows(counts)
    unfinished = run.unfinished or failed_rows
    if baseline is None:
        return RUN_INCOMPLETE if unfinished else 0
    gate = compare_to_baseline(spec, results, baseline, spec.tolerances)
    for note in gate.notes:
        print(f"note: {note}")
    if gate.findings:
        print(f"regressions against {args.baseline}:\n{format_findings(gate.findings)}")
        print(f"{len(gate.findings)} regressions against {args.baseline} ({gate.compared} points compared)")
        return RUN_INCOMPLETE
    print(f"no regression ({gate.compared} points compared against {args.baseline})")
    return RUN_INCOMPLETE if unfinished else 0


def _cmd_compare_flight(args) -> int:
    from campaign.realism.compare_flight import compare, load_flight, summary_lines

    _check_directory(args.out, "--out")
    spec = load_flight(args.file, output_dir=args.out, column=args.column)   # validates everything, writes nothing
    _check_directory(spec.output_dir, f"{args.file}: output_dir")
    summary = compare(spec)
    for line in summary_lines(summary):
        print(line)
    print(f"written to {spec.output_dir}: side-by-side, column and scatter PNGs, comparison.json, pixels.csv, features.csv")
    return 0


def _cmd_export(args) -> int:
    from campaign.run.export import export_case

    written = export_case(args.dir, args.case_id, args.out)
    record = json.loads((Path(args.out) / "truth.json").read_text())
    print(f"wrote {len(written)} files to {args.out}: {', '.join(path.name for path in written)}")
    print(f"replay: {record['replay']}")
    if not record["config_hash_matches_store"]:
        print(f"campaign: note: {args.dir} was computed by other code or input files (configuration hash differs): "
              "the export is of today's case, whose answer may differ from the stored one", file=sys.stderr)
    return 0


def _cmd_cluster(args) -> int:
    from campaign.run.cluster import cluster_description, require_backend

    config = _load(args)
    execution = config.execution.with_overrides(args.scheduler, args.workers)
    require_backend(execution, str(config.source))
    text, note = cluster_description(execution)
    print(text)
    print(f"campaign: note: {note}; nothing was submitted", file=sys.stderr)
    return 0


def _cmd_check_estimators(args) -> int:
    if args.cases < 1:           # before the stack is imported: a usage error is instant
        raise ConfigError(f"--cases = {args.cases} is not allowed; allowed: an integer >= 1")
    from campaign.run.check_estimators import check_estimators
    from estimators.entries import plugin_imports_deferred

    _check_cluster_flags(args)
    with plugin_imports_deferred():      # a module that does not import is the estimator's violation (exit 1)
        config = _load(args)
    return 1 if check_estimators(config, args.cases, args.scheduler) else 0


def _cmd_schema(args) -> int:

    print(json.dumps(table_schema(args.table) if args.table else all_schemas(), indent=2))
    return 0


@functools.cache
def build_parser() -> argparse.ArgumentParser:
    """The command line's parser (built once per process: parsing leaves it unchanged)."""
    parser = _Parser(prog="campaign", description="MOC2DIMES Monte Carlo campaigns")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    submit = commands.add_parser("submit", help="run a campaign (only its missing cases)")
    submit.add_argument("file")
    submit.add_argument("--output", help="output directory (default: [campaign] output_dir)")
    submit.add_argument("--scheduler", help="tcp://host:port of an existing dask scheduler")
    submit.add_argument("--workers", type=int, help="embedded cluster size (default: one per core)")
    submit.add_argument("--cases-scale", type=float, help="multiply every class's case count (quick looks)")
    submit.add_argument("--fresh", action="store_true",
                        help="move the existing store aside to OUTPUT.previous-<UTC time> (after every check) and start afresh")
    submit.add_argument("--wait", action="store_true", help="wait for another writer's lock on the store instead of exiting 1")
    submit.add_argument("--no-progress", action="store_true")
    submit.set_defaults(handler=_cmd_submit)

    plan = commands.add_parser("plan", help="print the plan and write footprint maps")
    plan.add_argument("file")
    plan.add_argument("--out", help="directory for the PNG maps (default: OUTPUT/plan)")
    plan.add_argument("--cases-scale", type=float)
    plan.set_defaults(handler=_cmd_plan)

    for name, handler, text in (("status", _cmd_status, "count done, failed and missing cases (per point of a sweep)"),
                                ("table", _cmd_table, "print and write the paper's table"),
                                ("report", _cmd_report, "write a Markdown report with plots"),
                                ("verify", _cmd_verify, "check every file of a store; exit 1 if any is bad")):
        command = commands.add_parser(name, help=text)
        command.add_argument("dir")
        command.set_defaults(handler=handler)

    sweep = commands.add_parser("sweep", help="run a sensitivity sweep (see campaign/configuration/sweep_file.py)")
    sweep.add_argument("file")
    sweep.add_argument("--output", help="output directory (default: [sweep] output_dir)")
    sweep.add_argument("--baseline", help="a previous sweep's output directory; exit 1 on a regression")
    sweep.add_argument("--scheduler", help="tcp://host:port of an existing dask scheduler")
    sweep.add_argument("--workers", type=int, help="embedded cluster size (default: one per core)")
    sweep.add_argument("--cases-scale", type=float, help="multiply every class's case count ([sweep] cases_scale)")
    sweep.add_argument("--wait", action="store_true", help="wait for other writers' locks on point stores")
    sweep.add_argument("--no-progress", action="store_true")
    sweep.set_defaults(handler=_cmd_sweep)

    flight = commands.add_parser("compare-flight", help="compare real descent images with the simulator's view "
                                 "(see campaign/realism/compare_flight.py)")
    flight.add_argument("file", help="FLIGHT.toml: site, class, images with their times and poses")
    flight.add_argument("--out", help="output directory (default: output_dir in the file, else runs/compare-flight)")
    flight.add_argument("--column", type=int, help="raw image column of the profile and scatter (default 512)")
    flight.set_defaults(handler=_cmd_compare_flight)

    export = commands.add_parser("export", help="write a case's exact estimator inputs (images, measurements, "
                                 "flat field) and its truth as files, to replay it (see campaign/run/export.py)")
    export.add_argument("dir", help="the campaign store")
    export.add_argument("case_id", type=int, help="a case id of the store's plan (`campaign plan`, results.parquet)")
    export.add_argument("out", help="output directory (created; files of an earlier export are replaced)")
    export.set_defaults(handler=_cmd_export)

    cluster = commands.add_parser("cluster", help="print the job script (slurm, pbs) or DaskCluster resource "
                                  "(kubernetes) that submit would use; submits nothing")
    cluster.add_argument("file")
    cluster.add_argument("--scheduler", help="tcp://host:port of an existing dask scheduler")
    cluster.add_argument("--workers", type=int, help="worker count (overrides [execution] workers)")
    cluster.set_defaults(handler=_cmd_cluster)

    check = commands.add_parser("check-estimators", help="run every declared estimator on a few planned cases on "
                                "the driver and on a worker and check the contract (writes no store)")
    check.add_argument("file")
    check.add_argument("--cases", type=int, default=2, help="planned cases to check on (default 2)")
    check.add_argument("--scheduler", help="tcp://host:port of a dask scheduler whose worker to check on "
                       "(default: a one-worker local cluster)")
    check.set_defaults(handler=_cmd_check_estimators)

    camera = commands.add_parser("camera", help="validate a camera TOML and print its derived numbers")
    camera.add_argument("file")
    camera.set_defaults(handler=_cmd_camera)


    schema = commands.add_parser("schema", help="print the JSON Schema of the configuration tables (for editors)")
    schema.add_argument("table", nargs="?", choices=tuple(SCHEMA_TABLES),
                        help="one table or file kind (default: all, as one JSON object keyed by name)")
    schema.set_defaults(handler=_cmd_schema)
    return parser


PATH_ARGUMENTS = {"file": "input", "dir": "text", "baseline": "text", "output": "directory", "out": "directory"}
"""Path arguments of the commands and how they are checked before the command runs (campaign.configuration.paths)."""


def _check_path_arguments(args) -> None:
    """Every path argument: not empty, not too long; an input file not a FIFO, device or dangling link (never
    opened to find out); an output directory creatable and writable. One-line ConfigError, nothing written."""
    for name, kind in PATH_ARGUMENTS.items():
        value = getattr(args, name, None)
        if value is None:
            continue
        label = name if name in ("file", "dir") else f"--{name}"
        if kind == "input":
            check_input_file(value, label)
        elif kind == "directory":
            check_output_dir(value, label)
        else:
            check_path_text(value, label)


def _kept(args) -> str:
    """After an interrupt: what the store holds (counted from its case files, nothing imported)."""
    store = getattr(args, "store_dir", None)
    if args.command not in ("submit", "sweep"):
        return "files already written are kept"
    if args.command == "sweep":
        return f"finished cases are kept in the point stores; `campaign sweep {args.file}` again runs the rest"
    cases = Path(store) / "cases" if store is not None else None
    if cases is None or not cases.is_dir():
        return "nothing was stored"
    done = sum(1 for _ in cases.glob("case-*.parquet"))
    return (f"{done} finished case files kept in {store} (a case being computed is not stored); "
            f"`campaign submit {args.file}` again computes the missing ones")


def _quiet_stdout() -> None:
    """stdout's reader went away (`campaign table DIR | head -1`): send what is left to /dev/null, so the
    interpreter's final flush does not complain either."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):     # captured stdout (tests): nothing to redirect
        pass


def _os_problem(exc: OSError) -> str:
    where = " -> ".join(str(name) for name in (exc.filename, exc.filename2) if name is not None)
    reason = exc.strerror or type(exc).__name__
    return f"{where}: {reason}" if where else reason


def main(argv: list[str] | None = None) -> int:
    """Run one command. Exit codes (also in the module docstring and README): 0 success, 1 cases failed or
    missing / run stopped / regression / lock held / bad store files, 2 bad input or a path the system refuses,
    3 internal error (a bug; ``CAMPAIGN_TRACEBACK=1`` shows the traceback), 130 interrupted (Ctrl-C),
    141 stdout closed by its reader. Every failure is one line on stderr, never a traceback."""
    args = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        _check_path_arguments(args)
        code = args.handler(args)
        sys.stdout.flush()                  # a closed pipe shows here, not at interpreter exit
        return code
    except (ConfigError, StoreError) as exc:
        print(f"campaign: error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    except RunStopped as exc:
        print(f"campaign: {exc}", file=sys.stderr, flush=True)
        return RUN_INCOMPLETE
    except StoreBusy as exc:
        print(f"campaign: busy: {exc}", file=sys.stderr, flush=True)
        return RUN_INCOMPLETE
    except KeyboardInterrupt:
        print(f"campaign: interrupted; {_kept(args) if args is not None else 'nothing was written'}",
              file=sys.stderr, flush=True)
        return INTERRUPTED
    except BrokenPipeError:
        _quiet_stdout()
        return BROKEN_PIPE
    except OSError as exc:                  # a path the system refuses only when used (e.g. /proc, a full disk)
        print(f"campaign: error: {_os_problem(exc)}", file=sys.stderr)
        return USAGE_ERROR
    except (MemoryError, RecursionError) as exc:
        what = "out of memory" if isinstance(exc, MemoryError) else "input nested too deeply"
        print(f"campaign: error: {what}: {' '.join(str(exc).split())[:300]}; allowed: sizes and nesting this "
              "machine can hold (see the documented maxima in docs/configuration.md)", file=sys.stderr)
        return USAGE_ERROR
    except Exception as exc:
        if os.environ.get("CAMPAIGN_TRACEBACK"):
            raise
        print(f"campaign: internal error: {type(exc).__name__}: {' '.join(str(exc).split())[:300]} (a bug; "
              "CAMPAIGN_TRACEBACK=1 shows where)", file=sys.stderr)
        return INTERNAL_ERROR


if __name__ == "__main__":
    sys.exit(main())
