"""``python -m benchmarks.doc_numbers``: check, write, import-bench, campaign-table, list.

Commands (from the repository root)::

    python -m benchmarks.doc_numbers check                  # exit 1 and one line per problem
    python -m benchmarks.doc_numbers write                  # rewrite every block from the record
    python -m benchmarks.doc_numbers import-bench bench-results/bench-20261127T031500.csv [--conditions TEXT]
    python -m benchmarks.doc_numbers campaign-table runs/gusev runs/meridiani
    python -m benchmarks.doc_numbers list                   # the record: fact, value, unit, date

``import-bench`` and ``campaign-table`` feed the record (:mod:`benchmarks.doc_numbers.importers`), then
rewrite the blocks.
"""
from __future__ import annotations

import sys
from pathlib import Path

from benchmarks.doc_numbers.blocks import check, write
from benchmarks.doc_numbers.importers import campaign_table, import_bench
from benchmarks.doc_numbers.record import REPO, SITE_TABLES_FILE, RecordError, read_facts
from config_tables.command_line import USAGE_ERROR, OneLineParser

DESCRIPTION = "Measured numbers of the README and docs/ from one record."


def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.doc_numbers``: check, write, import-bench, campaign-table, list.

    Returns 0 on success, 1 when ``check`` finds a problem, 2 for unreadable input (one line on stderr).
    """
    parser = OneLineParser(prog="python -m benchmarks.doc_numbers", description=DESCRIPTION)
    parser.add_argument("--root", type=Path, default=REPO, help="repository root (default: this checkout)")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("check", help="exit 1 when a block differs from the record")
    commands.add_parser("write", help="rewrite every block from the record")
    commands.add_parser("list", help="print the record")
    bench = commands.add_parser("import-bench", help="update the bench/ facts from a make bench CSV, then write")
    bench.add_argument("csv", type=Path)
    bench.add_argument("--date", help="YYYY-MM-DD (default: the file's stamp)")
    bench.add_argument("--conditions", default="", help="machine and load, e.g. 'idle 2-core machine'")
    bench.add_argument("--add", action="store_true", help="also record columns the record does not have yet")
    table = commands.add_parser("campaign-table", help="site_tables.csv from finished stores, then write")
    table.add_argument("stores", type=Path, nargs="+")
    options = parser.parse_args(argv)
    root = options.root.resolve()
    try:
        if options.command == "check":
            problems = check(root)
            for problem in problems:
                print(problem, file=sys.stderr)
            print(f"measured numbers: {len(problems)} problem(s)" if problems
                  else "measured numbers: every block matches the record")
            return 1 if problems else 0
        if options.command == "list":
            for fact in read_facts(root).values():
                print(f"{fact.key}\t{fact.printed()}\t{fact.date}")
            return 0
        if options.command == "import-bench":
            changed = import_bench(root, options.csv, options.date, options.conditions, options.add)
            print(f"{len(changed)} fact(s) updated from {options.csv}")
        elif options.command == "campaign-table":
            count = campaign_table(root, options.stores)
            print(f"{SITE_TABLES_FILE}: {count} rows from {len(options.stores)} store(s)")
        for page in write(root):
            print(f"rewritten {page}")
        return 0
    except RecordError as error:
        print(f"doc_numbers: {error}", file=sys.stderr)
        return USAGE_ERROR


if __name__ == "__main__":
    sys.exit(main())
