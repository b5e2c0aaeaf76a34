"""Measured numbers of the README and docs/ from one record.

Every measured figure the pages quote lives once, with its date and source, in ``docs/measured/``:

- ``facts.csv``: one row per fact: ``fact`` (key), ``value`` (as printed), ``unit``, ``date`` (YYYY-MM-DD),
  ``source`` (the command, run or commit that measured it), ``conditions`` (machine, load) and
  ``superseded`` (older figures of the same fact, ``;``-separated, that no page may quote any more);
- ``site_tables.csv``: the per-class table of finished campaign stores (``campaign-table``);
- ``paper_tables.csv``: the paper's Tables 1 and 2 (quoted, not measured), printed beside them;
- ``tables.csv`` and ``tables/NAME.csv``: measured tables kept as printed (a sweep's or an experiment's
  results, not produced by a command of this module), each with its date, source and conditions.

A page quotes a figure through a generated block, inline or around a table::

    <!-- measured:begin bench/campaign/gusev+meridiani/wall_s -->115 s<!-- measured:end -->
    <!-- measured:begin bench/campaign/gusev+meridiani/wall_s date -->2026-11-26<!-- measured:end -->
    <!-- measured:begin table sites -->
    ... (the table, written by this module) ...
    <!-- measured:end -->

A block's name is a fact key followed by an optional form (``value``: value and unit, the default;
``number``: the value alone; ``date``: its date), ``table NAME`` (a generated table of :data:`TABLES` or a
recorded one of ``tables.csv``: a caption with the date, then the table) or ``table NAME date`` (that
date alone). A page adopts the record by putting a block around a figure or table and running ``write``. ``check`` fails when
a block differs from what the record generates (e.g. edited by hand), names an unknown fact or table,
when the record holds a fact twice, or when a page with blocks (or ``pyproject.toml``) still quotes a
superseded figure. ``tests/test_documented_numbers.py`` runs it.

Commands (from the repository root)::

    python -m benchmarks.doc_numbers check                  # exit 1 and one line per problem
    python -m benchmarks.doc_numbers write                  # rewrite every block from the record
    python -m benchmarks.doc_numbers import-bench bench-results/bench-20261127T031500.csv [--conditions TEXT]
    python -m benchmarks.doc_numbers campaign-table runs/gusev runs/meridiani
    python -m benchmarks.doc_numbers list                   # the record: fact, value, unit, date

``import-bench`` updates the ``bench/<row name>/<column>`` facts found in a ``make bench`` CSV (date from
the file's stamp), and the range facts ``bench/<name>|<name>|<pattern*>/<column>`` (``min-max`` over the
rows named); ``--add`` also records its other numeric columns; ``campaign-table`` replaces
``site_tables.csv`` with the table of each store (``table.csv``, written by ``campaign submit`` and
``campaign table``; manifest for the date, seed and settings). Both then rewrite the blocks.

This module uses the standard library only, so checking the pages imports nothing of the project.
"""
from __future__ import annotations

import csv
import fnmatch
import json
import math
import re
import subprocess
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from config_tables.command_line import USAGE_ERROR, OneLineParser

REPO = Path(__file__).resolve().parents[1]
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
#: files scanned for superseded figures even without blocks (comments there may quote a figure)
ALWAYS_SCANNED = ("pyproject.toml",)
#: units printed without a space before them
ATTACHED_UNITS = ("x",)

BLOCK = re.compile(r"<!-- measured:begin (?P<name>[^>]*?) -->(?P<body>.*?)<!-- measured:end -->", re.DOTALL)
DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")
FACT_FORMS = ("value", "number", "date")


class RecordError(ValueError):
    """The record or a page cannot be read as the module expects (one line naming file and problem)."""


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


# ---------------------------------------------------------------------------------------------- the record

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
    rows = _read_csv(path, FACT_COLUMNS)
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
    _write_csv(root / FACTS_FILE, FACT_COLUMNS, rows)


def _read_csv(path: Path, columns: Iterable[str]) -> list[dict[str, str]]:
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [column for column in columns if column not in (reader.fieldnames or [])]
            if missing:
                raise RecordError(f"{path}: missing column(s) {', '.join(missing)}")
            return [{key: value or "" for key, value in row.items()} for row in reader]
    except OSError as error:
        raise RecordError(f"{path}: {error.strerror or error}") from error


def _write_csv(path: Path, columns: Iterable[str], rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


# ---------------------------------------------------------------------------------------------- tables

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

    def render(self) -> str:
        """Caption with the date, source and conditions, a blank line, then the Markdown table."""
        notes = "; ".join(note for note in (self.source, self.conditions) if note)
        return f"Measured {self.date} ({notes}):\n\n" + _markdown_table(self.header, self.rows)


def read_recorded_tables(root: Path) -> dict[str, RecordedTable]:
    """The recorded tables under ``root``, by name (none when ``tables.csv`` is absent)."""
    index = root / RECORDED_TABLES_FILE
    if not index.exists():
        return {}
    tables: dict[str, RecordedTable] = {}
    for line, row in enumerate(_read_csv(index, RECORDED_TABLE_COLUMNS), start=2):
        name = row["name"].strip()
        where = f"{RECORDED_TABLES_FILE}:{line}: table {name!r}"
        if name in tables or name in TABLES:
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


def read_sources(root: Path) -> Sources:
    """The record, the site tables and the paper's tables under ``root``."""
    return Sources(read_facts(root), _read_csv(root / SITE_TABLES_FILE, SITE_TABLE_COLUMNS),
                   _read_csv(root / PAPER_TABLES_FILE, ("site", "row", "pct_valid", "error_mean_3sigma_mps")),
                   read_recorded_tables(root))


def _markdown_table(header: list[str], body: list[list[str]]) -> str:
    def line(cells: list[str]) -> str:
        return "|" + "|".join(f" {cell} " if cell else " " for cell in cells) + "|"

    return "\n".join([line(header), "|" + "---|" * len(header)] + [line(cells) for cells in body])


def _one_date(facts: list[Fact], table: str) -> str:
    dates = sorted({fact.date for fact in facts})
    if len(dates) != 1:
        raise RecordError(f"table {table}: its facts were measured on different days ({', '.join(dates)}); "
                          "import them from one run")
    return dates[0]


def sites_table(sources: Sources) -> str:
    """The campaigns as shipped, per class and site, beside the paper's Tables 1 and 2 (``table sites``).

    From ``site_tables.csv`` (the first estimator of each store, as ``campaign-table`` wrote it) and
    ``paper_tables.csv``; a caption line with the stores' settings and date, then the table.
    """
    rows = sources.site_rows
    if not rows:
        raise RecordError(f"{SITE_TABLES_FILE} has no rows; run campaign-table on finished stores")
    paper = {(row["site"], row["row"]): row for row in sources.paper_rows}
    dates = sorted({row["date"] for row in rows})
    settings = sorted({(row["seed"], row["cases_scale"], row["fidelity"], row["flat_field"], row["estimator"],
                        row["false_valid_mps"]) for row in rows})
    if len(settings) != 1:
        raise RecordError(f"{SITE_TABLES_FILE}: the stores differ in seed, cases scale, fidelity, flat field, "
                          f"estimator or false-valid threshold: {settings}")
    seed, cases_scale, fidelity, flat_field, estimator, false_valid_mps = settings[0]
    scale = "all cases" if float(cases_scale) == 1.0 else f"cases_scale {cases_scale}"
    sites = " and ".join(dict.fromkeys(row["site"] for row in rows))
    caption = (f"The {sites} campaigns as shipped (seed {seed}, {scale}, {fidelity} fidelity, {flat_field} flat "
               f"field, estimator `{estimator}`), next to the paper's Tables 1 and 2; false-valid = valid with a "
               f"velocity error above {_trim(float(false_valid_mps))} m/s; measured {' and '.join(dates)}:")
    header = ["class", "cases", "paper % valid", "paper error (m/s, mean+3σ)", "% valid (valid/ran)",
              "false-valid", "error, magnitude (m/s, mean+3σ)", "error, per axis", "attitude floor, magnitude / per axis"]
    body = []
    for row in rows:
        quoted = paper.get((row["site"], row["row"]), {})
        name = f"{row['site']} (weighted)" if row["row"] == "site" else row["row"]
        ran = int(row["cases"]) - int(row["failed"])
        body.append([name, row["cases"],
                     f"{quoted['pct_valid']} %" if quoted else "",
                     quoted.get("error_mean_3sigma_mps", ""),
                     f"{float(row['pct_valid']):.1f}% ({row['valid']}/{ran})",
                     row["false_valid"], f"{float(row['error_mean_3sigma_mps']):.2f}",
                     _two_decimals(row["error_axis_mean_3sigma_mps"]),
                     f"{_two_decimals(row['floor_mean_3sigma_mps'])} / {_two_decimals(row['floor_axis_mean_3sigma_mps'])}"])
    return caption + "\n\n" + _markdown_table(header, body)


FIDELITY_PRESETS = ("reference", "high", "default", "fast")


def _fidelity_facts(sources: Sources, preset: str, columns: Iterable[str]) -> dict[str, Fact]:
    return {column: sources.fact(f"bench/fidelity/{preset}/{column}") for column in columns}


def _image_ms(facts: dict[str, Fact], preset: str) -> str:
    if preset == "reference":
        return facts["ms_per_image"].value
    return f"{facts['ms_per_image'].value} ({facts['scene_ms'].value} + {facts['camera_ms'].value})"


def fidelity_table(sources: Sources, detail: bool) -> str:
    """The fidelity presets' time against error, from the ``bench/fidelity/<preset>/...`` facts.

    ``detail``: also the worst image, the largest pixel error and the velocity change against ``reference``
    (``table fidelity_presets_detail``); else the mean RMS error only (``table fidelity_presets``).
    """
    columns = ["ms_per_image", "scene_ms", "camera_ms", "ms_per_case", "rms_dn_vs_reference_mean"]
    if detail:
        columns += ["rms_dn_vs_reference_max", "max_dn_vs_reference", "dv_vs_reference_mean_mps",
                    "dv_vs_reference_max_mps"]
    per_preset = {preset: _fidelity_facts(sources, preset,
                                          ["ms_per_image", "ms_per_case"] if preset == "reference" else columns)
                  for preset in FIDELITY_PRESETS}
    name = "fidelity_presets_detail" if detail else "fidelity_presets"
    everything = [fact for facts in per_preset.values() for fact in facts.values()]
    date = _one_date(everything, name)
    conditions = "; ".join(dict.fromkeys(fact.conditions for fact in everything if fact.conditions))
    caption = f"Measured {date} (`python -m benchmarks fidelity`{'; ' + conditions if conditions else ''}):"
    if detail:
        header = ["preset", "ms/image (scene + camera)", "ms/case (3 images + estimator)",
                  "expected-image error vs reference, RMS mean / worst image / max pixel (DN)",
                  "velocity change vs reference, mean / max (m/s)"]
    else:
        header = ["preset", "ms/image (scene + camera)", "ms/case (3 images + estimator)",
                  "expected-image RMS error vs reference (DN, mean)"]
    body = []
    for preset, facts in per_preset.items():
        cells = [preset, _image_ms(facts, preset), facts["ms_per_case"].value]
        if preset == "reference":
            cells += ["0", "0"] if detail else ["0"]
        elif detail:
            cells += [f"{facts['rms_dn_vs_reference_mean'].value} / {facts['rms_dn_vs_reference_max'].value} / "
                      f"{facts['max_dn_vs_reference'].value}",
                      f"{facts['dv_vs_reference_mean_mps'].value} / {facts['dv_vs_reference_max_mps'].value}"]
        else:
            cells.append(facts["rms_dn_vs_reference_mean"].value)
        body.append(cells)
    return caption + "\n\n" + _markdown_table(header, body)


#: the speed-up table: row label -> fact key prefix (``<prefix>/before``, ``/after``, ``/ratio``)
SPEEDUP_ROWS = (
    ("case (3 images, sensors, reference estimator)", "speedup/case_cpu_ms"),
    ("camera chain per image", "speedup/camera_chain_cpu_ms"),
    ("optics PSF per image: still / block smear / moving", "speedup/optics_psf_cpu_ms"),
    ("reference estimator (same bits on 136 estimates and the 1090 adversarial triples)", "speedup/estimator_cpu_ms"),
    ("reference preset, one image", "speedup/reference_image_cpu_ms"),
    ("campaign worker: wall-time parallel efficiency (loaded machine)", "speedup/parallel_efficiency"),
)


def speedup_table(sources: Sources) -> str:
    """Before/after the speed-up work, both versions back to back in one run (``table speedup``)."""
    everything: list[Fact] = []
    body = []
    row_dates: dict[str, str] = {}
    for label, prefix in SPEEDUP_ROWS:
        before, after = sources.fact(f"{prefix}/before"), sources.fact(f"{prefix}/after")
        ratio = sources.facts.get(f"{prefix}/ratio")
        facts = [before, after] + ([ratio] if ratio else [])
        row_dates[label.split(":")[0].split(" (")[0]] = _one_date(facts, f"speedup, row {label!r}")
        everything += facts
        body.append([label, before.value, after.value, ratio.printed() if ratio else ""])
    dates = list(row_dates.values())
    date = max(set(dates), key=dates.count)
    exceptions = "; ".join(f"{label}: {day}" for label, day in row_dates.items() if day != date)
    conditions = "; ".join(dict.fromkeys(fact.conditions for fact in everything if fact.conditions))
    notes = "; ".join(note for note in (exceptions, conditions) if note)
    caption = f"Measured {date}{' (' + notes + ')' if notes else ''}:"
    return caption + "\n\n" + _markdown_table(["", "before", "after", "ratio"], body)


#: generated tables by block name
TABLES: dict[str, Callable[[Sources], str]] = {
    "sites": sites_table,
    "fidelity_presets": lambda sources: fidelity_table(sources, detail=False),
    "fidelity_presets_detail": lambda sources: fidelity_table(sources, detail=True),
    "speedup": speedup_table,
}


# ---------------------------------------------------------------------------------------------- blocks

def render_block(name: str, sources: Sources) -> str:
    """What the block ``name`` holds: a fact in one of :data:`FACT_FORMS` or a table of :data:`TABLES`.

    Parameters
    ----------
    name : str
        ``KEY``, ``KEY value``, ``KEY number``, ``KEY date``, ``table NAME`` or ``table NAME date`` (the date
        its caption states).
    sources : Sources
        The record and tables.

    Returns
    -------
    str
        The block's text: inline for a fact, a newline-framed table for a table.
    """
    words = name.split()
    if words[:1] == ["table"] and (len(words) == 2 or words[2:] == ["date"]):
        if len(words) < 2 or (words[1] not in TABLES and words[1] not in sources.recorded):
            known = ", ".join([*TABLES, *sources.recorded])
            raise RecordError(f"no table {' '.join(words[1:2])!r} (known: {known})")
        text = TABLES[words[1]](sources) if words[1] in TABLES else sources.recorded[words[1]].render()
        if len(words) == 3:
            return _caption_date(text)
        return "\n" + text + "\n"
    if len(words) not in (1, 2) or (len(words) == 2 and words[1] not in FACT_FORMS):
        raise RecordError(f"block name {name!r} is not 'KEY', 'KEY {{{'|'.join(FACT_FORMS)}}}', 'table NAME' "
                          "or 'table NAME date'")
    fact = sources.fact(words[0])
    form = words[1] if len(words) == 2 else "value"
    return {"value": fact.printed(), "number": fact.value, "date": fact.date}[form]


def _caption_date(table: str) -> str:
    """The date(s) a generated table's caption states (``measured 2026-11-27``, ``Measured 2026-11-21``)."""
    caption = table.split("\n", 1)[0]
    match = re.search(r"[Mm]easured (\d{4}-\d{2}-\d{2}(?: and \d{4}-\d{2}-\d{2})*)", caption)
    if match is None:
        raise RecordError(f"the caption {caption!r} states no date")
    return match[1]


def pages(root: Path) -> list[Path]:
    """The Markdown pages a user reads: ``README.md`` and ``docs/**/*.md`` under ``root``."""
    found = [root / "README.md"] if (root / "README.md").exists() else []
    return found + sorted((root / "docs").rglob("*.md"))


def regenerate(text: str, sources: Sources, where: str) -> tuple[str, list[str]]:
    """``text`` with every block rewritten from ``sources``, and one problem line per block that failed."""
    problems: list[str] = []

    def replace(match: re.Match) -> str:
        try:
            body = render_block(match["name"].strip(), sources)
        except RecordError as error:
            line = text.count("\n", 0, match.start()) + 1
            problems.append(f"{where}:{line}: block {match['name'].strip()!r}: {error}")
            return match.group(0)
        return f"<!-- measured:begin {match['name']} -->{body}<!-- measured:end -->"

    return BLOCK.sub(replace, text), problems


def check(root: Path) -> list[str]:
    """Every problem of the pages under ``root`` against the record (empty: all blocks are current).

    A block whose text differs from what the record generates, an unknown fact or table, an unreadable or
    inconsistent record, a stray ``measured:begin``/``measured:end`` marker, and a superseded figure quoted
    outside the blocks of a page that has blocks or of :data:`ALWAYS_SCANNED`.
    """
    try:
        sources = read_sources(root)
    except RecordError as error:
        return [str(error)]
    problems: list[str] = []
    for page in pages(root):
        text = page.read_text(encoding="utf-8")
        where = str(page.relative_to(root))
        generated, failed = regenerate(text, sources, where)
        problems += failed
        if not failed and generated != text:
            for match, expected in zip(BLOCK.finditer(text), BLOCK.finditer(generated)):
                if match.group(0) != expected.group(0):
                    line = text.count("\n", 0, match.start()) + 1
                    problems.append(f"{where}:{line}: block {match['name'].strip()!r} differs from the record "
                                    f"(edited by hand? run python -m benchmarks.doc_numbers write)")
        outside = BLOCK.sub("", text)
        for marker in ("measured:begin", "measured:end"):
            if marker in outside:
                problems.append(f"{where}: a {marker} marker without its pair")
        if BLOCK.search(text):
            problems += _superseded_quotes(outside, sources.facts, where)
    for name in ALWAYS_SCANNED:
        path = root / name
        if path.exists():
            problems += _superseded_quotes(path.read_text(encoding="utf-8"), sources.facts, name)
    return problems


def _superseded_quotes(text: str, facts: dict[str, Fact], where: str) -> list[str]:
    problems = []
    for fact in facts.values():
        for old in fact.superseded:
            if re.search(rf"(?<![\w.]){re.escape(old)}(?![\w])", text):
                problems.append(f"{where}: quotes {old!r}, a superseded figure of {fact.key} "
                                f"(now {fact.printed()}, {fact.date}); use its block")
    return problems


def write(root: Path) -> list[str]:
    """Rewrite every block of the pages under ``root`` from the record; the pages that changed."""
    sources = read_sources(root)
    changed = []
    for page in pages(root):
        text = page.read_text(encoding="utf-8")
        generated, problems = regenerate(text, sources, str(page.relative_to(root)))
        if problems:
            raise RecordError(problems[0])
        if generated != text:
            page.write_text(generated, encoding="utf-8")
            changed.append(str(page.relative_to(root)))
    return changed


# ---------------------------------------------------------------------------------------------- feeding

def printed_number(value: float) -> str:
    """A measured float as the record prints it: three significant figures, whole numbers from 100 up.

    Parameters
    ----------
    value : float
        The figure.

    Returns
    -------
    str
        E.g. ``115`` for 115.23, ``2697`` for 2697.4, ``18.6`` for 18.63, ``4.71`` for 4.714, ``0.963``.
    """
    if value == 0 or not math.isfinite(value):
        return str(value) if not math.isfinite(value) else "0"
    decimals = max(0, 2 - math.floor(math.log10(abs(value))))
    return f"{value:.{decimals}f}"


_COLUMN_UNITS = (("_mps", "m/s"), ("_mib", "MiB"), ("_ms", "ms"), ("_s", "s"), ("_dn", "DN"))


def _unit_of(column: str, row: dict[str, str]) -> str:
    if column in ("measured", "target") and row.get("unit"):
        return row["unit"]
    if column.startswith("ms_") or column == "ms":
        return "ms"
    for suffix, unit in _COLUMN_UNITS:
        if column.endswith(suffix):
            return unit
    return ""


def bench_date(path: Path) -> str:
    """The day of a ``bench-YYYYMMDDTHHMMSS.csv`` file (its stamp), YYYY-MM-DD."""
    match = re.search(r"bench-(\d{4})(\d{2})(\d{2})T\d{6}", path.name)
    if match is None:
        raise RecordError(f"{path}: not a bench-YYYYMMDDTHHMMSS.csv file of make bench; give --date")
    return "-".join(match.groups())


def import_bench(root: Path, bench_csv: Path, date: str | None = None, conditions: str = "",
                 add: bool = False) -> list[str]:
    """Update the ``bench/...`` facts from a ``make bench`` CSV; the keys updated or added.

    Parameters
    ----------
    root : Path
        Repository root (the record is ``root/docs/measured/facts.csv``).
    bench_csv : Path
        A ``bench-results/bench-*.csv`` file.
    date : str, optional
        The day it was measured (default: the file's stamp).
    conditions : str
        Machine and load during the run, recorded with each fact.
    add : bool
        Also record the file's numeric columns the record does not have yet (else only update).

    Returns
    -------
    list of str
        The keys whose value or date changed.
    """
    date = date or bench_date(bench_csv)
    if not DATE.match(date):
        raise RecordError(f"--date {date!r} is not YYYY-MM-DD")
    facts = read_facts(root)
    source = f"make bench ({bench_csv.name})"
    changed = []

    def record(key: str, value: str, unit: str) -> None:
        old = facts.get(key)
        fact = Fact(key, value, old.unit if old else unit, date, source,
                    conditions or (old.conditions if old else ""), old.superseded if old else ())
        if fact != old:
            facts[key] = fact
            changed.append(key)

    named = [row for row in _read_csv(bench_csv, ("benchmark",)) if row.get("name")]   # not per-case rows
    for row in named:
        for column, text in row.items():
            if column in ("benchmark", "name", "unit", "bound", "meets", "ratio", "target") or not text:
                continue
            number = _number_or_none(text)
            key = f"bench/{row['name']}/{column}"
            if number is not None and (key in facts or add):
                record(key, printed_number(number), _unit_of(column, row))
    for key in [key for key in facts if key.startswith("bench/") and RANGE_KEY.search(key)]:
        patterns, column = key.removeprefix("bench/").rsplit("/", 1)
        numbers = [number for row in named for number in [_number_or_none(row.get(column, ""))]
                   if number is not None and any(fnmatch.fnmatchcase(row["name"], pattern)
                                                 for pattern in patterns.split("|"))]
        if numbers:
            low, high = printed_number(min(numbers)), printed_number(max(numbers))
            record(key, low if low == high else f"{low}-{high}", "")
    write_facts(root, facts)
    return changed


#: a ``bench/`` fact over several rows (``|``-separated names or fnmatch patterns): recorded as ``min-max``
RANGE_KEY = re.compile(r"[|*?\[]")


def _number_or_none(text: str) -> float | None:
    try:
        number = float(text)
    except ValueError:
        return None
    return number if math.isfinite(number) else None


def campaign_table_rows(store: Path) -> list[dict]:
    """The ``site_tables.csv`` rows of a finished campaign store (its ``table.csv`` and manifest).

    Parameters
    ----------
    store : Path
        A campaign store directory; its ``table.csv`` is written by ``campaign table DIR`` (run when missing).

    Returns
    -------
    list of dict
        One row per class and one for the site (``row = "site"``, ellipse-weighted % valid and error) of the
        store's first estimator, with the store's date (manifest ``created``), seed and settings.
    """
    manifest_path = store / "manifest.json"
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise RecordError(f"{manifest_path}: not a campaign store ({error})") from error
    table_path = store / "table.csv"
    results = store / "results.parquet"
    if not table_path.exists() or (results.exists() and results.stat().st_mtime > table_path.stat().st_mtime):
        done = subprocess.run([sys.executable, "-m", "campaign.cli", "table", str(store)], capture_output=True,
                              text=True, cwd=REPO)
        if done.returncode != 0 or not table_path.exists():
            raise RecordError(f"{store}: campaign table failed: {done.stderr.strip() or done.returncode}")
    table = _read_csv(table_path, ("estimator", "class", "cases", "valid", "failed", "pct_valid", "false_valid",
                                   "error_mean_3sigma_mps", "weighted_pct_valid", "weighted_error_mps"))
    estimator = manifest["estimators"][0]
    config = manifest["config"]
    site = manifest["site"]
    common = {"estimator": estimator, "date": str(manifest["created"])[:10], "store": store.name,
              "seed": manifest["seed"], "cases_scale": _trim(float(config["campaign"]["cases_scale"])),
              "fidelity": config.get("scene", {}).get("fidelity", "default"),
              "flat_field": config["estimator"]["flat_field"],
              "false_valid_mps": _trim(float(config["campaign"]["false_valid_mps"]))}
    rows = []
    for entry in table:
        if entry["estimator"] != estimator:
            continue
        is_site = entry["class"] == site
        rows.append({"site": site, "row": "site" if is_site else entry["class"], **common,
                     "cases": entry["cases"], "valid": entry["valid"], "failed": entry["failed"],
                     "pct_valid": _rounded(entry["weighted_pct_valid" if is_site else "pct_valid"]),
                     "false_valid": entry["false_valid"],
                     "error_mean_3sigma_mps": _rounded(entry["weighted_error_mps" if is_site
                                                             else "error_mean_3sigma_mps"]),
                     # a store tabulated before these statistics existed has none: blank, printed n/a
                     **{column: _rounded(entry.get(column) or "") for column in AXIS_STATISTICS}})
    if not any(row["row"] == "site" for row in rows):
        raise RecordError(f"{table_path}: no site row for {site} and estimator {estimator}")
    return rows


def campaign_table(root: Path, stores: list[Path]) -> int:
    """Replace ``site_tables.csv`` under ``root`` with the tables of ``stores``; the number of rows."""
    rows = [row for store in stores for row in campaign_table_rows(store)]
    _write_csv(root / SITE_TABLES_FILE, SITE_TABLE_COLUMNS, rows)
    return len(rows)


def _two_decimals(text: str) -> str:
    """A recorded statistic as printed in the site table (blank when the store had none)."""
    return f"{float(text):.2f}" if text else "n/a"


def _rounded(text: str) -> str:
    return f"{float(text):.4f}" if text not in ("", "nan") else ""


def _trim(value: float) -> str:
    return f"{value:g}"


# ---------------------------------------------------------------------------------------------- command line

def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.doc_numbers``: check, write, import-bench, campaign-table, list.

    Returns 0 on success, 1 when ``check`` finds a problem, 2 for unreadable input (one line on stderr).
    """
    parser = OneLineParser(prog="python -m benchmarks.doc_numbers", description=__doc__.split("\n")[0])
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
