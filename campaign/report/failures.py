"""Failed estimator rows in plain sight: every kind of failure per estimator, counted, with one example each.

A failed row (``status`` 'failed') carries a ``reason`` (``case_failed``: the case's simulation failed;
``estimator_failed``: the estimator crashed or broke the contract; ``implausible``: its answer was refused, e.g.
a NaN velocity declared valid) and the full ``error`` text, which ends with the file and line where a Python
plug-in raised (``... | File "/path/myest.py", line 12, in estimate``). :func:`failure_kind` names the kind of a
row (the reason, and the exception type of a crash), :func:`failure_summary` groups an estimator's failed rows
by kind (most frequent first) and :func:`failure_report_lines` prints them, one line per kind, for the end of
``campaign submit`` and ``campaign sweep``. :func:`abbreviate_error` shortens a text for a terminal line but
never cuts its ``File "...", line N`` part; :func:`markdown_cell` escapes a text for a Markdown table cell.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import pandas as pd

TERMINAL_ERROR_CHARS = 300
"""A failure example on a terminal line is at most this long, plus its whole ``File "...", line N`` part."""
LOCATION = re.compile(r'\s*\|\s*(File ".*", line \d+.*)$')
CRASHED = re.compile(r"^estimator [^:]+: crashed: ([A-Za-z_][\w.]*)")
CASE_FAILED = re.compile(r"^([A-Za-z_][\w.]*): ")
COMMAND_FAILURES = re.compile(r"^estimator [^:]+: (exit status -?\d+|killed by signal \w+|timeout)")


def failure_kind(reason: object, error: object) -> str:
    """The kind of a failed row, from its ``reason`` and ``error`` text.

    Parameters
    ----------
    reason : str or None
        The row's ``reason`` column ('case_failed', 'estimator_failed', 'implausible', ...).
    error : str or None
        The row's ``error`` column.

    Returns
    -------
    str
        ``"crashed (RuntimeError)"``, ``"implausible answer"``, ``"case failed (MemoryError)"``,
        ``"exit status 2"``, ``"timeout"``, ``"contract violation"`` or the reason itself.
    """
    text = " ".join(error.split()) if isinstance(error, str) else ""
    reason = reason if isinstance(reason, str) and reason else "failed"
    if reason == "case_failed":
        match = CASE_FAILED.match(text)
        return f"case failed ({match[1]})" if match else "case failed"
    if reason == "implausible":
        return "implausible answer"
    crashed = CRASHED.match(text)
    if crashed:
        return f"crashed ({crashed[1]})"
    command = COMMAND_FAILURES.match(text)
    if command:
        return command[1]
    return "contract violation" if reason == "estimator_failed" else reason


def abbreviate_error(text: object, limit: int = TERMINAL_ERROR_CHARS) -> str:
    """``text`` on one line, its message shortened to ``limit`` characters with "..." in the middle when longer;
    the trailing ``| File "...", line N, in f`` part (where a plug-in raised) is always kept whole."""
    if not isinstance(text, str) or not text.strip():
        return "no error text"
    line = " ".join(text.split())
    location = LOCATION.search(line)
    message, where = (line[:location.start()], location[1]) if location else (line, "")
    if len(message) > limit:
        head = max(limit - 3, 0) * 2 // 3
        tail = max(limit - 3 - head, 0)
        message = message[:head] + "..." + (message[-tail:] if tail else "")
    return f"{message} | {where}" if where else message


@dataclass(frozen=True)
class FailureKind:
    """One kind of failure of one estimator: how many rows, and the first of them (where and its error text)."""

    kind: str
    rows: int
    example_where: str        # "case 3" or "point 2 case 3"
    example_error: str        # the row's full error text


@dataclass(frozen=True)
class EstimatorFailures:
    """An estimator's failed rows out of its rows, by kind (most frequent first)."""

    estimator: str
    rows: int
    failed: int
    kinds: tuple[FailureKind, ...]


def failure_summary(results: pd.DataFrame) -> list[EstimatorFailures]:
    """Per estimator with failed rows (in [[estimators]] order) its failure kinds.

    Parameters
    ----------
    results : DataFrame
        Result rows with ``estimator``, ``status``, ``reason``, ``error`` and ``case_id`` (a sweep's also
        ``point_id``, named in the example).

    Returns
    -------
    list of EstimatorFailures
        Only estimators with at least one failed row; kinds by count (descending), then first appearance.
    """
    if results.empty or "status" not in results.columns:
        return []
    estimators = results["estimator"] if "estimator" in results.columns else pd.Series("dimes", index=results.index)
    summaries = []
    for name in dict.fromkeys(estimators):
        rows = results[estimators == name]
        failed = rows[rows["status"] != "ok"]
        if failed.empty:
            continue
        reasons = failed["reason"] if "reason" in failed.columns else pd.Series(None, index=failed.index)
        errors = failed["error"] if "error" in failed.columns else pd.Series(None, index=failed.index)
        kinds = [failure_kind(reason, error) for reason, error in zip(reasons, errors)]
        grouped: dict[str, list[int]] = {}
        for position, kind in enumerate(kinds):
            grouped.setdefault(kind, []).append(position)
        found = []
        for kind, positions in sorted(grouped.items(), key=lambda item: -len(item[1])):   # stable: first seen first
            first = failed.iloc[positions[0]]
            where = " ".join(f"{key.split('_')[0]} {first[key]}" for key in ("point_id", "case_id") if key in failed.columns)
            error = first.get("error")
            found.append(FailureKind(kind, len(positions), where, error if isinstance(error, str) else ""))
        summaries.append(EstimatorFailures(str(name), len(rows), len(failed), tuple(found)))
    return summaries


def failure_report_lines(summaries: list[EstimatorFailures], limit: int = TERMINAL_ERROR_CHARS) -> list[str]:
    """The terminal lines of :func:`failure_summary`: per estimator a line with its count of failed rows and of
    kinds, then one line per kind with its count and its first row's error (:func:`abbreviate_error`)."""
    lines = []
    for summary in summaries:
        plural = "s" if len(summary.kinds) > 1 else ""
        lines.append(f"estimator {summary.estimator}: {summary.failed} of {summary.rows} rows failed, "
                     f"{len(summary.kinds)} kind{plural} (full error texts: `campaign report`, Failed cases; "
                     "or the store's results, column error):")
        for kind in summary.kinds:
            lines.append(f"  {kind.rows} x {kind.kind}, e.g. {kind.example_where}: "
                         f"{abbreviate_error(kind.example_error, limit)}")
    return lines


def markdown_cell(text: object, emphasis: bool = True) -> str:
    """``text`` as the content of a GitHub Markdown table cell, shown as written: on one line (a newline is
    ``<br>``), ``|``, backticks and backslashes escaped, ``<``, ``>`` and ``&`` as entities; with ``emphasis``
    (free text such as an error) also ``*`` and ``_`` (``__init__.py`` is not bold)."""
    if text is None or (isinstance(text, float) and text != text):
        return ""
    value = str(text).replace("\\", "\\\\").replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    value = value.replace("|", "\\|").replace("`", "\\`")
    if emphasis:
        value = value.replace("*", "\\*").replace("_", "\\_")
    return "<br>".join(part.strip() for part in value.replace("\r\n", "\n").split("\n")).strip()
