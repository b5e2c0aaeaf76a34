"""The ``campaign`` command line.

    campaign submit FILE   plan, run every missing case on dask, store, print the paper's table
    campaign plan FILE     print the plan and write footprint maps (PNG) without running anything
    campaign status DIR    done / failed / missing cases, from the store's verified case files
    campaign verify DIR    check every file of a store (sha256 records); list bad files, exit 1 if any
    campaign table DIR     the paper's table (also written as table.md and table.csv in DIR)
    campaign report DIR    a Markdown report with PNG plots
    campaign camera FILE   validate a camera TOML and print its derived numbers
    campaign cluster FILE  print the job script / pod spec a submit would use (submits nothing)
    campaign sweep FILE    run a sensitivity sweep (base campaign x parameter axes); --baseline DIR, --reuse DIR
    campaign gate DIR --baseline DIR   judge a campaign or sweep against a baseline: gate.json, exit 4 on a regression
    campaign sensitivity DIR   rank the recorded inputs by their effect on validity, false-valid and error
    campaign compare-flight FLIGHT.toml   real descent images next to the simulator's view of the same poses
    campaign export DIR CASE_ID OUT   a case's exact estimator inputs and its truth as files (replay it)
    campaign schema [T]    print the JSON Schema of every configuration table, or of table T

Exit codes: 0 success (every case done, no estimator row failed), 1 cases failed or missing, an estimator's
row failed in the store (submit and sweep: one stderr line per such estimator with the count and the first
reason, e.g. ``campaign: estimator flight: 4 of 4 rows failed; first: case 0 (estimator_failed): ...``),
a run stopped (one line naming the
cause and the fix: campaign.run.faults), another writer holds the store's lock (one line
naming it; ``--wait`` waits instead) or ``verify`` found bad files, 2 usage or configuration
error (one clear line on stderr, nothing written; also a path the system refuses and running out of memory),
4 a regression against a baseline (``gate``, ``sweep --baseline``: campaign.report.gate; the verdict line is
printed first and kept through a closed pipe), 3 internal error (one line; CAMPAIGN_TRACEBACK=1 shows the
traceback), 128 + signal interrupted by SIGINT (130),
SIGHUP (129) or SIGTERM (143) (one line saying what the store kept and the command line that resumes), 141
stdout closed by its reader (silent). Never a traceback (see main). Command-line values (--cases-scale, --workers,
--scheduler) are validated against the same declarations as the TOML fields, before anything is written.
"""
from __future__ import annotations

import argparse
import functools
import os
import sys
from pathlib import Path

from campaign import commands
from campaign.commands import RUN_INCOMPLETE
from campaign.configuration.paths import check_input_file, check_output_dir, check_path_text
from campaign.configuration.schemas import SCHEMA_TABLES
from campaign.run.faults import FULL_DISK_ERRNOS, RunStopped, storage_fix
from campaign.run.interrupts import exit_code, resume_command, signal_label, stop_signals
from campaign.store.errors import StoreError
from campaign.store.lock import StoreBusy
from config_tables.command_line import USAGE_ERROR
from config_tables.command_line import OneLineParser as _Parser
from config_tables.errors import ConfigError

# The commands themselves are campaign.commands (each imports its own stack when it runs); this module holds
# the parser and the mapping of what a command raises to one stderr line and an exit code.

INTERNAL_ERROR = 3      # exit code: an unexpected exception (a bug), one line
INTERRUPTED = 130       # exit code: Ctrl-C (128 + SIGINT); SIGTERM 143, SIGHUP 129 (campaign.run.interrupts)
BROKEN_PIPE = 141       # exit code: stdout's reader closed the pipe (128 + SIGPIPE), silent


SCHEDULER_HELP = "tls://host:port (certificate files: [execution] tls_*_file) or tcp://host:port of an existing dask scheduler"


@functools.cache
def build_parser() -> argparse.ArgumentParser:
    """The command line's parser (built once per process: parsing leaves it unchanged)."""
    parser = _Parser(prog="campaign", description="MOC2DIMES Monte Carlo campaigns")
    subcommands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    submit = subcommands.add_parser("submit", help="run a campaign (only its missing cases)")
    submit.add_argument("file")
    submit.add_argument("--output", help="output directory (default: [campaign] output_dir)")
    submit.add_argument("--scheduler", help=SCHEDULER_HELP)
    submit.add_argument("--workers", type=int, help="embedded cluster size (default: one per core)")
    submit.add_argument("--cases-scale", type=float, help="multiply every class's case count (quick looks)")
    submit.add_argument("--fresh", action="store_true",
                        help="move the existing store aside to OUTPUT.previous-<UTC time> (after every check) and start afresh")
    submit.add_argument("--wait", action="store_true", help="wait for another writer's lock on the store instead of exiting 1")
    submit.add_argument("--no-progress", action="store_true")
    submit.set_defaults(handler=commands.submit)

    plan = subcommands.add_parser("plan", help="print the plan and write footprint maps")
    plan.add_argument("file")
    plan.add_argument("--out", help="directory for the PNG maps (default: OUTPUT/plan)")
    plan.add_argument("--cases-scale", type=float)
    plan.set_defaults(handler=commands.plan)

    for name, handler, text in (("status", commands.status, "count done, failed and missing cases (per point of a sweep)"),
                                ("table", commands.table, "print and write the paper's table"),
                                ("report", commands.report, "write a Markdown report with plots"),
                                ("verify", commands.verify, "check every file of a store; exit 1 if any is bad")):
        command = subcommands.add_parser(name, help=text)
        command.add_argument("dir", help="a campaign store, or a sweep output directory (every point, or --point)")
        command.add_argument("--point", help="of a sweep directory: one point, by its id (p003) or store (points/<hash>)")
        command.set_defaults(handler=handler)

    gate = subcommands.add_parser("gate", help="judge a campaign or sweep against a baseline; write gate.json; exit 4 "
                               "on a regression (see campaign/report/gate.py)")
    gate.add_argument("dir", help="the candidate: a campaign store or a sweep output directory")
    gate.add_argument("--baseline", required=True, help="the baseline: a store or sweep directory of the same kind")
    gate.add_argument("--verdict", help="where to write the verdict JSON (default CANDIDATE/gate.json; .md beside it)")
    gate.add_argument("--tolerances", help="a TOML file whose [tolerances] table sets the rules (e.g. the sweep file; "
                      "default: the candidate sweep's, else the defaults)")
    gate.set_defaults(handler=commands.gate)

    sweep = subcommands.add_parser("sweep", help="run a sensitivity sweep (see campaign/configuration/sweep_file.py)")
    sweep.add_argument("file")
    sweep.add_argument("--output", help="output directory (default: [sweep] output_dir)")
    sweep.add_argument("--baseline", help="a previous sweep's output directory; writes OUT/gate.json, exit 4 on a regression")
    sweep.add_argument("--reuse", help="a previous sweep's output directory: copy (and verify) every point whose "
                       "configuration and code are unchanged instead of computing it")
    sweep.add_argument("--scheduler", help=SCHEDULER_HELP)
    sweep.add_argument("--workers", type=int, help="embedded cluster size (default: one per core)")
    sweep.add_argument("--cases-scale", type=float, help="multiply every class's case count ([sweep] cases_scale)")
    sweep.add_argument("--wait", action="store_true", help="wait for other writers' locks on point stores")
    sweep.add_argument("--no-progress", action="store_true")
    sweep.set_defaults(handler=commands.sweep)

    sensitivity = subcommands.add_parser("sensitivity", help="rank the recorded inputs by their effect on each "
                                      "estimator's validity, false-valid and error (see campaign/analysis/sensitivity.py)")
    sensitivity.add_argument("dir", help="a finished campaign store, or a sweep directory (each point)")
    sensitivity.add_argument("--estimator", action="append", help="only this estimator (repeatable; default all)")
    sensitivity.add_argument("--resamples", type=int, default=300, help="bootstrap replicates per interval (default 300)")
    sensitivity.add_argument("--seed", type=int, default=0, help="seed of the resampling (default 0)")
    sensitivity.set_defaults(handler=commands.sensitivity)

    flight = subcommands.add_parser("compare-flight", help="compare real descent images with the simulator's view "
                                 "(see campaign/realism/compare_flight.py)")
    flight.add_argument("file", help="FLIGHT.toml: site, class, images with their times and poses")
    flight.add_argument("--out", help="output directory (default: output_dir in the file, else runs/compare-flight)")
    flight.add_argument("--column", type=int, help="raw image column of the profile and scatter (default 512)")
    flight.set_defaults(handler=commands.compare_flight)

    export = subcommands.add_parser("export", help="write a case's exact estimator inputs (images, measurements, "
                                 "flat field) and its truth as files, to replay it (see campaign/case/export.py)")
    export.add_argument("dir", help="the campaign store")
    export.add_argument("case_id", type=int, help="a case id of the store's plan (`campaign plan`, results.parquet)")
    export.add_argument("out", help="output directory (created; files of an earlier export are replaced)")
    export.set_defaults(handler=commands.export)

    cluster = subcommands.add_parser("cluster", help="print the job script (slurm, pbs) or DaskCluster resource "
                                  "(kubernetes) that submit would use; submits nothing")
    cluster.add_argument("file")
    cluster.add_argument("--scheduler", help=SCHEDULER_HELP)
    cluster.add_argument("--workers", type=int, help="worker count (overrides [execution] workers)")
    cluster.set_defaults(handler=commands.cluster)

    check = subcommands.add_parser("check-estimators", help="run every declared estimator on a few planned cases on "
                                "the driver and on a worker and check the contract (writes no store)")
    check.add_argument("file")
    check.add_argument("--cases", type=int, default=2, help="planned cases to check on (default 2)")
    check.add_argument("--scheduler", help="tcp://host:port of a dask scheduler whose worker to check on "
                       "(default: a one-worker local cluster)")
    check.set_defaults(handler=commands.check_estimators)

    camera = subcommands.add_parser("camera", help="validate a camera TOML and print its derived numbers")
    camera.add_argument("file")
    camera.set_defaults(handler=commands.camera)

    schema = subcommands.add_parser("schema", help="print the JSON Schema of the configuration tables (for editors)")
    schema.add_argument("table", nargs="?", choices=tuple(SCHEMA_TABLES),
                        help="one table or file kind (default: all, as one JSON object keyed by name)")
    schema.set_defaults(handler=commands.schema)
    return parser


PATH_ARGUMENTS = {"file": "input", "dir": "text", "baseline": "text", "output": "directory", "out": "directory",
                  "reuse": "text", "verdict": "text", "tolerances": "input"}
"""Path arguments of the commands and how they are checked before the command runs (campaign.configuration.paths)."""


def _check_path_arguments(args: argparse.Namespace) -> None:
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


def _kept(args: argparse.Namespace, argv: list[str] | None) -> str:
    """After an interrupt: what the store holds (counted from its case files, nothing imported) and the
    user's own command line to run again (campaign.run.interrupts.resume_command)."""
    store = getattr(args, "store_dir", None)
    if args.command not in ("submit", "sweep"):
        return "files already written are kept"
    again = resume_command(argv)
    if args.command == "sweep":
        return f"finished cases are kept in the point stores; `{again}` again runs the rest"
    cases = Path(store) / "cases" if store is not None else None
    if cases is None or not cases.is_dir():
        return f"nothing was stored; `{again}` starts it again"
    done = sum(1 for _ in cases.glob("??/batch-*.parquet")) + sum(1 for _ in cases.glob("case-*.parquet"))
    return (f"{done} finished case files kept in {store} (a case being computed is not stored); "
            f"`{again}` again computes the missing ones")


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
    missing / run stopped / lock held / bad store files, 2 bad input or a path the system refuses, 4 regression,
    3 internal error (a bug; ``CAMPAIGN_TRACEBACK=1`` shows the traceback), 128 + signal interrupted (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP),
    141 stdout closed by its reader. Every failure is one line on stderr, never a traceback."""
    args = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        _check_path_arguments(args)
        with stop_signals():                # SIGINT, SIGTERM, SIGHUP: Interrupted (campaign.run.interrupts)
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
    except KeyboardInterrupt as exc:        # also SIGTERM and SIGHUP (campaign.run.interrupts.Interrupted)
        print(f"campaign: interrupted{signal_label(exc)}; "
              f"{_kept(args, argv) if args is not None else 'nothing was written'}", file=sys.stderr, flush=True)
        return exit_code(exc)
    except BrokenPipeError:
        _quiet_stdout()
        return BROKEN_PIPE
    except OSError as exc:                  # a path the system refuses only when used (e.g. /proc)
        if exc.errno in FULL_DISK_ERRNOS:   # the machine's fault, not bad input (campaign.run.faults)
            print(f"campaign: {_os_problem(exc)}; {storage_fix(exc)}", file=sys.stderr)
            return RUN_INCOMPLETE
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
