"""The record of measured numbers: ``docs/measured/`` read, validated and written.

Every measured figure the pages quote lives once, with its date and source, in ``docs/measured/``:

- ``facts.csv``: one row per fact: ``fact`` (key), ``value`` (as printed), ``unit``, ``date`` (YYYY-MM-DD),
  ``source`` (the command, run or commit that measured it), ``conditions`` (machine, load) and
  ``superseded`` (older figures of the same fact, ``;``-separated, that no page may quote any more);
- ``site_tables.csv``: the per-class table of finished campaign stores (``campaign-table``);
- ``paper_tables.csv``: the paper's Tables 1 and 2 (quoted, not measured), printed beside them;
- ``tables.csv`` and ``tables/NAME.csv``: measured tables kept as printed (a sweep's or an experiment's
  results, not produced by a command of this package), each with its date, source and conditions.

Standard library only.
"""
from __future__ import annotations

import csv
import re
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MEASURED_DIR = Path("docs") / "measured"
FACTS_FILE = MEASURED_DIR / "facts.csv"
SITE_TABLES_FILE = MEASURED_DIR / "site_tables.csv"
PAPER_TABLES_FILE = MEASURED_DIR / "paper_tables.csv"
RECORDED_TABLES_FILE = MEASURED_DIR / "tables.csv"
RECORDED_TABLES_DIR = MEASURED_DIR / "tables"
RECORDED_TABLE_COLUMNS = ("name", "date", "source", "conditions")
FACT_COLUMNS = ("fact", "value", "unit", "date", "source", "conditions", "superseded")
#: the per-axis error statistic and the attitude-knowledge floor's two statistics (``campaign table``'s table.csv)
AXIS_STATISTICS = ("error_axis_mean_3sigma_mps", "floor_mean_3sigma_mps", "floor_axis_mean_3sigma_mps")
SITE_TABLE_COLUMNS = ("site", "row", "estimator", "cases", "valid", "failed", "pct_valid", "false_valid",
                      "error_mean_3sigma_mps", *AXIS_STATISTICS, "date", "store", "seed", "cases_scale", "fidelity",
                      "flat_field", "false_valid_mps")
#: units printed without a space before them
ATTACHED_UNITS = ("x",)
DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")


class RecordError(ValueError):
    """The record or a page cannot be read as the package expects (one line naming file and problem)."""


@dataclass(frozen=True)
class Fact:
    """One measured figure.

    Parameters
    ----------
    key : str
        The fact's name, e.g. ``bench/campaign/gusev+meridiani/wall_s``.
    value : str
        The figure as printed, e.g. ``115``.
    unit : str
        Its unit as printed (``s``, ``ms``, ``MiB``, ``x``; empty for a count).
    date : str
        The day it was measured, YYYY-MM-DD.
    source : str
        The command, run or commit that measured it.
    conditions : str
        Machine and load, when they matter.
    superseded : tuple of str
        Older figures of the same fact that no page may quote any more.
    """

    key: str
    value: str
    unit: str
    date: str
    source: str
    conditions: str = ""
    superseded: tuple[str, ...] = ()

    def printed(self) -> str:
        """The value with its unit, as a page prints it (``115 s``, ``1.3x``, ``1090``)."""
        if not self.unit:
            return self.value
        return f"{self.value}{self.unit}" if self.unit in ATTACHED_UNITS else f"{self.value} {self.unit}"


def read_facts(root: Path) -> dict[str, Fact]:
    """The record ``docs/measured/facts.csv`` under ``root``, by key.

    Parameters
    ----------
    root : Path
        Repository root.

    Returns
    -------
    dict of str to Fact
        Every fact, in file order.

    Raises
    ------
    RecordError
        A missing column, a fact recorded twice, an empty value or source, or a date not YYYY-MM-DD.
    """
    path = root / FACTS_FILE
    rows = read_csv(path, FACT_COLUMNS)
    facts: dict[str, Fact] = {}
    for line, row in enumerate(rows, start=2):
        key = row["fact"].strip()
        where = f"{FACTS_FILE}:{line}: fact {key!r}"
        if key in facts:
            previous = facts[key]
            raise RecordError(f"{where} is recorded twice ({previous.value} {previous.unit} on {previous.date} "
                              f"and {row['value']} {row['unit']} on {row['date']}); keep one row per fact")
        if not key or not row["value"].strip() or not row["source"].strip():
            raise RecordError(f"{where}: fact, value and source must not be empty")
        if not DATE.match(row["date"].strip()):
            raise RecordError(f"{where}: date {row['date']!r} is not YYYY-MM-DD")
        superseded = tuple(part.strip() for part in row["superseded"].split(";") if part.strip())
        facts[key] = Fact(key, row["value"].strip(), row["unit"].strip(), row["date"].strip(), row["source"].strip(),
                          row["conditions"].strip(), superseded)
    return facts


def write_facts(root: Path, facts: dict[str, Fact]) -> None:
    """Write the record ``docs/measured/facts.csv`` under ``root`` (sorted by key)."""
    rows = [{"fact": fact.key, "value": fact.value, "unit": fact.unit, "date": fact.date, "source": fact.source,
             "conditions": fact.conditions, "superseded": "; ".join(fact.superseded)}
            for fact in sorted(facts.values(), key=lambda fact: fact.key)]
    write_csv(root / FACTS_FILE, FACT_COLUMNS, rows)


def read_csv(path: Path, columns: Iterable[str]) -> list[dict[str, str]]:
    """The rows of the CSV file ``path`` (empty cells as ``""``); :class:`RecordError` when it cannot be read
    or lacks one of ``columns``."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [column for column in columns if column not in (reader.fieldnames or [])]
            if missing:
                raise RecordError(f"{path}: missing column(s) {', '.join(missing)}")
            return [{key: value or "" for key, value in row.items()} for row in reader]
    except OSError as error:
        raise RecordError(f"{path}: {error.strerror or error}") from error


def write_csv(path: Path, columns: Iterable[str], rows: list[dict]) -> None:
    """Write ``rows`` to the CSV file ``path`` with the header ``columns`` (its directory made when missing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def compact_number(value: float) -> str:
    """A setting as ``site_tables.csv`` records it and the site table's caption prints it (``0.1``, ``1``, ``3``)."""
    return f"{value:g}"


@dataclass(frozen=True)
class RecordedTable:
    """A measured table kept as printed: ``tables/NAME.csv`` (header row, then the rows) and its
    ``tables.csv`` row (date, source, conditions)."""

    name: str
    date: str
    source: str
    conditions: str
    header: list[str]
    rows: list[list[str]]


def read_recorded_tables(root: Path, generated: Collection[str]) -> dict[str, RecordedTable]:
    """The recorded tables under ``root``, by name (none when ``tables.csv`` is absent).

    Parameters
    ----------
    root : Path
        Repository root.
    generated : collection of str
        The names of the generated tables, which no recorded table may take.

    Raises
    ------
    RecordError
        A table recorded twice or named like a generated one, a bad date, an empty source, a missing or
        ragged ``tables/NAME.csv``.
    """
    index = root / RECORDED_TABLES_FILE
    if not index.exists():
        return {}
    tables: dict[str, RecordedTable] = {}
    for line, row in enumerate(read_csv(index, RECORDED_TABLE_COLUMNS), start=2):
        name = row["name"].strip()
        where = f"{RECORDED_TABLES_FILE}:{line}: table {name!r}"
        if name in tables or name in generated:
            raise RecordError(f"{where} is recorded twice (or is a generated table); keep one")
        if not DATE.match(row["date"].strip()) or not row["source"].strip():
            raise RecordError(f"{where}: date must be YYYY-MM-DD and source not empty")
        path = root / RECORDED_TABLES_DIR / f"{name}.csv"
        try:
            with path.open(newline="", encoding="utf-8") as handle:
                cells = list(csv.reader(handle))
        except OSError as error:
            raise RecordError(f"{where}: {path}: {error.strerror or error}") from error
        if len(cells) < 2 or any(len(cell_row) != len(cells[0]) for cell_row in cells):
            raise RecordError(f"{path}: needs a header row and rows of as many cells as the header")
        tables[name] = RecordedTable(name, row["date"].strip(), row["source"].strip(), row["conditions"].strip(),
                                     cells[0], cells[1:])
    return tables


@dataclass(frozen=True)
class Sources:
    """What the blocks are generated from: the facts, the site and paper tables and the recorded tables."""

    facts: dict[str, Fact]
    site_rows: list[dict[str, str]]
    paper_rows: list[dict[str, str]]
    recorded: dict[str, RecordedTable]

    def fact(self, key: str) -> Fact:
        """The fact ``key``; :class:`RecordError` when the record has none."""
        if key not in self.facts:
            raise RecordError(f"no fact {key!r} in {FACTS_FILE}")
        return self.facts[key]


def read_sources(root: Path, generated: Collection[str]) -> Sources:
    """The record, the site tables, the paper's tables and the recorded tables under ``root`` (``generated``:
    the generated tables' names, see :func:`read_recorded_tables`)."""
    return Sources(read_facts(root), read_csv(root / SITE_TABLES_FILE, SITE_TABLE_COLUMNS),
                   read_csv(root / PAPER_TABLES_FILE, ("site", "row", "pct_valid", "error_mean_3sigma_mps")),
                   read_recorded_tables(root, generated))
