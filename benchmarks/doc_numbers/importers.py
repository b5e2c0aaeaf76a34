"""Feeding the record: the ``bench/...`` facts from a ``make bench`` CSV (``import-bench``) and the site
tables from finished campaign stores (``campaign-table``).

``import-bench`` updates the ``bench/<row name>/<column>`` facts found in a ``make bench`` CSV (date from
the file's stamp), and the range facts ``bench/<name>|<name>|<pattern*>/<column>`` (``min-max`` over the
rows named); ``--add`` also records its other numeric columns. ``campaign-table`` replaces
``site_tables.csv`` with the table of each store (``table.csv``, written by ``campaign submit`` and
``campaign table``; manifest for the date, seed and settings).
"""
from __future__ import annotations

import fnmatch
import json
import math
import re
import subprocess
import sys
from pathlib import Path

from benchmarks.doc_numbers.record import (
    AXIS_STATISTICS,
    DATE,
    REPO,
    SITE_TABLE_COLUMNS,
    SITE_TABLES_FILE,
    Fact,
    RecordError,
    compact_number,
    read_csv,
    read_facts,
    write_csv,
    write_facts,
)


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

    named = [row for row in read_csv(bench_csv, ("benchmark",)) if row.get("name")]   # not per-case rows
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
    table = read_csv(table_path, ("estimator", "class", "cases", "valid", "failed", "pct_valid", "false_valid",
                                   "error_mean_3sigma_mps", "weighted_pct_valid", "weighted_error_mps"))
    estimator = manifest["estimators"][0]
    config = manifest["config"]
    site = manifest["site"]
    common = {"estimator": estimator, "date": str(manifest["created"])[:10], "store": store.name,
              "seed": manifest["seed"], "cases_scale": compact_number(float(config["campaign"]["cases_scale"])),
              "fidelity": config.get("scene", {}).get("fidelity", "default"),
              "flat_field": config["estimator"]["flat_field"],
              "false_valid_mps": compact_number(float(config["campaign"]["false_valid_mps"]))}
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
    write_csv(root / SITE_TABLES_FILE, SITE_TABLE_COLUMNS, rows)
    return len(rows)


def _rounded(text: str) -> str:
    return f"{float(text):.4f}" if text not in ("", "nan") else ""
