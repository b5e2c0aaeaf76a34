"""The generated blocks of the pages: rendered from the record, checked and rewritten.

A page quotes a figure through a generated block, inline or around a table::

    <!-- measured:begin bench/campaign/gusev+meridiani/wall_s -->115 s<!-- measured:end -->
    <!-- measured:begin bench/campaign/gusev+meridiani/wall_s date -->2026-11-26<!-- measured:end -->
    <!-- measured:begin table sites -->
    ... (the table, written by this package) ...
    <!-- measured:end -->

A block's name is a fact key followed by an optional form (``value``: value and unit, the default;
``number``: the value alone; ``date``: its date; ``was FIGURE``: one of the fact's superseded figures, quoted as
history, e.g. "the suite then had 1090 triples": the figure must be in the record's ``superseded`` column, so a
page never quotes an old figure as current without saying so), ``table NAME`` (a generated table of
:data:`~benchmarks.doc_numbers.tables.TABLES` or a recorded one of ``tables.csv``: a caption with the date,
then the table) or ``table NAME date`` (that date alone). A page adopts the record by putting a block around a
figure or table and running ``write``. ``check`` fails when a block differs from what the record generates
(e.g. edited by hand), names an unknown fact or table, when the record holds a fact twice, or when any page
(or ``pyproject.toml``) still quotes a superseded figure: a fact has one figure on every page.
"""
from __future__ import annotations

import re
from pathlib import Path

from benchmarks.doc_numbers.record import Fact, RecordError, Sources, read_sources
from benchmarks.doc_numbers.tables import TABLES, recorded_table

#: files scanned for superseded figures even without blocks (comments there may quote a figure)
ALWAYS_SCANNED = ("pyproject.toml",)
BLOCK = re.compile(r"<!-- measured:begin (?P<name>[^>]*?) -->(?P<body>.*?)<!-- measured:end -->", re.DOTALL)
FACT_FORMS = ("value", "number", "date")


def read_block_sources(root: Path) -> Sources:
    """What the blocks under ``root`` are generated from (no recorded table may take a generated table's name)."""
    return read_sources(root, TABLES)


def render_block(name: str, sources: Sources) -> str:
    """What the block ``name`` holds: a fact in one of :data:`FACT_FORMS` or a table of :data:`TABLES`.

    Parameters
    ----------
    name : str
        ``KEY``, ``KEY value``, ``KEY number``, ``KEY date``, ``KEY was FIGURE`` (a superseded figure),
        ``table NAME`` or ``table NAME date`` (the date its caption states).
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
        text = TABLES[words[1]](sources) if words[1] in TABLES else recorded_table(sources.recorded[words[1]])
        if len(words) == 3:
            return _caption_date(text)
        return "\n" + text + "\n"
    if len(words) >= 3 and words[1] == "was":         # a superseded figure quoted as history
        fact, old = sources.fact(words[0]), " ".join(words[2:])
        if old not in fact.superseded:
            raise RecordError(f"{old!r} is not a superseded figure of {fact.key} (superseded: "
                              f"{'; '.join(fact.superseded) or 'none'})")
        return old
    if len(words) not in (1, 2) or (len(words) == 2 and words[1] not in FACT_FORMS):
        raise RecordError(f"block name {name!r} is not 'KEY', 'KEY {{{'|'.join(FACT_FORMS)}}}', 'KEY was FIGURE', "
                          "'table NAME' or 'table NAME date'")
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
    outside the blocks of any page (with or without blocks) or in :data:`ALWAYS_SCANNED`.
    """
    try:
        sources = read_block_sources(root)
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
        problems += _superseded_quotes(outside, sources.facts, where)     # every page: one figure per fact
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
    sources = read_block_sources(root)
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
