"""The regression gate a script can read: ``campaign gate CANDIDATE --baseline BASELINE`` (and ``campaign sweep
FILE --baseline DIR``, which gates its own output directory the same way).

Both sides are campaign stores (``manifest.json``) or both are sweep output directories (``sweep.json``); a
campaign store is one point without axis values. Points are matched by site and axis values (a sweep's
``site`` axis, or the site of its base, and every other axis value; 1 and 1.0 are the same value), so a
candidate may add or drop points or sites: the points without a partner are noted, not compared; at least
one point must match. Each matched point is judged by :mod:`campaign.report.baseline_gate` (false-valid count,
one-sided Fisher exact test on % valid, one-sided permutation test on the error) per estimator, class and
site, on the verified case rows of both stores, with the candidate's false-valid threshold and ellipse
fractions and the tolerances of ``--tolerances FILE`` (a ``[tolerances]`` table, e.g. the sweep file), else
the candidate sweep's (sweep.json), else the defaults (:class:`campaign.configuration.sweep_file.Tolerances`).

The verdict (:func:`write_verdict`) is written before anything is printed, as ``gate.json`` (JSON, for
scripts) and ``gate.md`` (the human table) in the candidate directory (or ``--verdict PATH`` and its
``.md`` beside it). ``gate.json``::

    verdict            "regression" | "incomplete" | "pass"
    exit_code          4 | 1 | 0 (the command's exit code, below)
    summary            the verdict line the command prints first
    candidate, baseline  each side's identity: directory (absolute), kind, sweep.json sha256 (a sweep),
                       and per point its id, axis values, site, store, configuration hash (which covers the
                       code: campaign.configuration.code_identity), manifest sha256, and planned / done /
                       failed / missing cases
    tolerances         the rules' thresholds and significance level
    compared_points, regressions, comparisons (their count)
    rows               every comparison: point_id, values, site, class, estimator, metric, baseline,
                       candidate (as printed), baseline_value, candidate_value (numbers), test, test_name
                       (count, fisher_exact_one_sided, permutation_one_sided, none), p_value (null for a
                       count or an untested growth), decision (regression, pass, not judged) and why
    notes              points and estimators not compared, and why

Exit codes: :data:`REGRESSION_EXIT` (4) when any comparison is a regression, else 1 when a candidate
point has failed or missing cases (its failed rows are left out of the counts: the gate cannot vouch
for them), else 0; bad input (not a store, incompatible sides, no matching point) is 2 with one line.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pandas as pd
import pyarrow as pa

from campaign.configuration.sweep_file import SITE_AXIS, Tolerances
from campaign.report.aggregate import COLUMNS_READ, render_grid
from campaign.report.baseline_gate import GATE_HEADERS, Finding, GateRules, compare_point, format_findings
from campaign.report.compare import with_estimator_column
from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import atomic_write_bytes
from campaign.store.errors import StoreError
from campaign.store.sweep_directory import point_label, read_description
from config_tables.models import parse
from config_tables.toml_file import load_toml

REGRESSION_EXIT = 4
"""Exit code of a gate that found a regression (distinct from 1: failed or missing cases, a held lock; 2: bad
input; 3: internal error)."""
INCOMPLETE_EXIT = 1
ALLOWED = "allowed: two campaign stores (manifest.json) or two sweep output directories (sweep.json)"


@dataclass(frozen=True)
class GatePoint:
    """One point of a side: a campaign store, alone or as a sweep's point."""

    point_id: str
    values: dict
    site: str
    store: Path
    config_hash: str
    manifest_sha256: str
    fractions: dict
    false_valid_mps: float
    planned: int
    done: int
    failed: int

    @property
    def missing(self) -> int:
        return self.planned - self.done - self.failed

    @property
    def label(self) -> str:
        return point_label(self.point_id, self.values) if self.values else self.point_id

    def key(self) -> tuple:
        """What matches a point of the other side: its site and axis values."""
        return (self.site.lower(), match_key({k: v for k, v in self.values.items() if k != SITE_AXIS}))

    def identity(self) -> dict:
        return {"point_id": self.point_id, "values": self.values, "site": self.site, "store": os.path.abspath(self.store),
                "config_hash": self.config_hash, "manifest_sha256": self.manifest_sha256, "planned": self.planned,
                "done": self.done, "failed": self.failed, "missing": self.missing}


@dataclass(frozen=True)
class GateSide:
    """A candidate or baseline: its directory, kind (campaign or sweep), axes, points and tolerances."""

    directory: Path
    kind: str
    axes: list
    points: list
    tolerances: dict | None = None
    description_sha256: str | None = None

    def identity(self) -> dict:
        return {"directory": os.path.abspath(self.directory), "kind": self.kind, "axes": self.axes,
                **({"sweep_json_sha256": self.description_sha256} if self.description_sha256 else {}),
                "points": [point.identity() for point in self.points]}


def match_key(values: dict) -> tuple:
    """Axis values as a comparable key (numbers as floats: 1 and 1.0, [6, 0] and [6.0, 0.0] are the same)."""
    def normal(value):
        if isinstance(value, list):
            return [normal(item) for item in value]
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    return tuple(sorted((name, json.dumps(normal(value))) for name, value in values.items()))


def _store_point(store: Path, point_id: str, values: dict, what: str) -> GatePoint:
    """A store as a gate point (StoreError, one line, when it has no verified manifest)."""
    manifest = CampaignStore(store).manifest()
    if manifest is None:
        raise StoreError(f"{store}: no manifest.json ({what}); {ALLOWED}")
    status = CampaignStore(store).status()
    threshold = manifest.get("config", {}).get("campaign", {}).get("false_valid_mps", 5.0)
    site = manifest.get("config", {}).get("site", {}).get("name") or str(manifest.get("site", ""))
    return GatePoint(point_id, values, site, store, manifest["config_hash"], manifest.get("manifest_sha256", ""),
                     dict(manifest.get("ellipse_fractions", {})), float(threshold), status.planned, status.done,
                     status.failed)


def read_side(directory: str | Path, role: str) -> GateSide:
    """A campaign store or sweep output directory as one side of the gate (``role``: "candidate" or
    "baseline", named in errors). Points of a sweep without a store yet are left out."""
    directory = Path(directory)
    if (directory / "manifest.json").exists():
        return GateSide(directory, "campaign", [], [_store_point(directory, "campaign", {}, role)])
    if not (directory / "sweep.json").is_file():
        what = "no manifest.json, no sweep.json" if directory.is_dir() else "no such directory"
        raise StoreError(f"{directory}: the {role} is not a campaign store and not a sweep output directory ({what}); "
                         f"{ALLOWED}")
    description = read_description(directory)
    points = []
    for point in description["points"]:
        store = directory / point["store"]
        if (store / "manifest.json").exists():
            points.append(_store_point(store, point["point_id"], point["values"], f"{role} point {point['point_id']}"))
        else:       # no store (moved away): its rows of the sweep's results.parquet, if any (point_rows)
            site = str(point.get("site") or description.get("site", ""))
            fractions = dict((description.get("classes") or {}).get(site, {}))
            points.append(GatePoint(point["point_id"], point["values"], site, store, str(point.get("config_hash", "")),
                                    "", fractions, float(description.get("false_valid_mps", 5.0)), 0, 0, 0))
    digest = hashlib.sha256((directory / "sweep.json").read_bytes()).hexdigest()
    return GateSide(directory, "sweep", list(description["axes"]), points, description.get("tolerances"), digest)


def point_rows(side: GateSide, point: GatePoint) -> pd.DataFrame:
    """A point's case rows: its store's verified rows (a sweep point without a store: its rows of the sweep's
    results.parquet), with an ``estimator`` column; StoreError (one line) when there are none."""
    try:
        rows = CampaignStore(point.store).results() if (point.store / "manifest.json").exists() else pd.DataFrame()
        if rows.empty and side.kind == "sweep" and (side.directory / "results.parquet").is_file():
            everything = pd.read_parquet(side.directory / "results.parquet")
            rows = everything[everything["point_id"] == point.point_id] if "point_id" in everything else everything[:0]
    except (OSError, ValueError, KeyError, pa.ArrowException) as exc:
        raise StoreError(f"{point.store}: the case rows of {point.label} cannot be read "
                         f"({' '.join(str(exc).split())[:200]}); {ALLOWED}") from None
    if rows.empty:
        raise StoreError(f"{point.store}: no case rows of {point.label}; allowed: a store with finished cases")
    missing = [name for name in COLUMNS_READ if name not in rows.columns]
    if missing:
        raise StoreError(f"{point.store}: the rows of {point.label} lack the column {missing[0]!r}; {ALLOWED}")
    return with_estimator_column(rows.reset_index(drop=True))


def matched_points(candidate: GateSide, baseline: GateSide, name: str = "the candidate"
                   ) -> tuple[list[tuple[GatePoint, GatePoint]], list[str]]:
    """(candidate point, baseline point) pairs matched by site and axis values, and notes on the candidate
    points without a partner; StoreError (one line, what differs; ``name`` names the candidate) when no
    point matches."""
    if candidate.kind != baseline.kind:
        raise StoreError(f"{baseline.directory}: the baseline is a {baseline.kind}, the candidate "
                         f"{candidate.directory} a {candidate.kind}; {ALLOWED}")
    mine = sorted(name for name in candidate.axes if name != SITE_AXIS)
    theirs = sorted(name for name in baseline.axes if name != SITE_AXIS)
    if mine != theirs:
        raise StoreError(f"{baseline.directory}: the baseline sweeps {', '.join(theirs) or 'no axes'}, {name} "
                         f"{', '.join(mine) or 'no axes'}; allowed: a baseline of the same axes (a site axis may differ)")
    partners = {point.key(): point for point in baseline.points}
    pairs, notes = [], []
    for point in candidate.points:
        partner = partners.get(point.key())
        if partner is None:
            notes.append(f"{point.label}: no baseline point with this site and these axis values: not compared")
        else:
            pairs.append((point, partner))
    if pairs:
        return pairs, notes
    sites = {point.site for point in candidate.points}
    if not sites & {point.site for point in baseline.points}:
        raise StoreError(f"{baseline.directory}: the baseline is of site "
                         f"{', '.join(repr(p) for p in sorted({q.site for q in baseline.points})) or 'none'}, {name} "
                         f"of {', '.join(repr(s) for s in sorted(sites)) or 'none'}; allowed: a baseline of "
                         "the same site")
    raise StoreError(f"{baseline.directory}: no point of {name} has the site and axis values of a baseline point; "
                     "allowed: a baseline sharing at least one point")


@dataclass
class GateReport:
    """What the gate found: every comparison, the points compared, notes, and both sides."""

    candidate: GateSide
    baseline: GateSide
    rules: GateRules
    comparisons: list[Finding] = field(default_factory=list)
    point_of: dict = field(default_factory=dict)        # comparison's point label -> candidate GatePoint
    compared: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def regressions(self) -> list[Finding]:
        return [finding for finding in self.comparisons if finding.regression]

    @property
    def unfinished(self) -> int:
        """Failed or missing cases of the candidate's compared points."""
        return sum(point.failed + point.missing for point in self.point_of.values())

    @property
    def verdict(self) -> str:
        return "regression" if self.regressions else "incomplete" if self.unfinished else "pass"

    @property
    def exit_code(self) -> int:
        return {"regression": REGRESSION_EXIT, "incomplete": INCOMPLETE_EXIT, "pass": 0}[self.verdict]

    def summary(self, verdict_path: Path | None = None) -> str:
        """The verdict line (printed first, so ``| head -1`` shows it)."""
        where = f"{self.candidate.directory} against {self.baseline.directory}"
        counts = f"{len(self.comparisons)} comparisons in {self.compared} points"
        if self.verdict == "regression":
            points = len({finding.point for finding in self.regressions})
            text = (f"gate: REGRESSION: {len(self.regressions)} of {len(self.comparisons)} comparisons regressed, in "
                    f"{points} of {self.compared} points, {where}")
        elif self.verdict == "incomplete":
            text = (f"gate: INCOMPLETE: no regression in {counts}, but {self.unfinished} candidate cases failed or "
                    f"are missing, {where}")
        else:
            text = f"gate: PASS: no regression in {counts}, {where}"
        return text + (f"; verdict in {verdict_path}" if verdict_path is not None else "")


def gate(candidate: GateSide, baseline: GateSide, rules: GateRules,
         baseline_rows: dict[str, pd.DataFrame] | None = None,
         candidate_rows: dict[str, pd.DataFrame] | None = None) -> GateReport:
    """Judge every matched point (``baseline_rows`` / ``candidate_rows``: point id -> rows read earlier, e.g.
    the baseline's before a sweep overwrote its directory; other points' rows are read from their stores)."""
    pairs, notes = matched_points(candidate, baseline)
    report = GateReport(candidate, baseline, rules, notes=notes)
    for mine, theirs in pairs:
        before = (baseline_rows or {}).get(theirs.point_id)
        before = point_rows(baseline, theirs) if before is None else before
        now = (candidate_rows or {}).get(mine.point_id)
        now = point_rows(candidate, mine) if now is None else with_estimator_column(now)
        for estimator in dict.fromkeys(now["estimator"]):
            if not (before["estimator"] == estimator).any():
                report.notes.append(f"{mine.label}: estimator {estimator} has no rows in baseline point "
                                    f"{theirs.point_id}: not compared")
        report.comparisons += compare_point(mine.label, repr((mine.site, mine.key()[1])) if mine.values else "campaign",
                                            before, now, mine.fractions, mine.site, mine.false_valid_mps, rules)
        report.point_of[mine.label] = mine
        report.compared += 1
    return report


def _number(value) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def verdict_record(report: GateReport, verdict_path: Path | None = None) -> dict:
    """The content of gate.json (module docstring)."""
    rows = []
    for finding in report.comparisons:
        point = report.point_of.get(finding.point)
        rows.append({"point_id": point.point_id if point else finding.point, "values": point.values if point else {},
                     "site": point.site if point else "", "class": finding.class_name, "estimator": finding.estimator,
                     "metric": finding.metric, "baseline": finding.baseline, "candidate": finding.candidate,
                     "baseline_value": _number(finding.baseline_value),
                     "candidate_value": _number(finding.candidate_value), "test": finding.test,
                     "test_name": finding.test_name, "p_value": _number(finding.p_value),
                     "decision": finding.decision, "why": finding.why})
    return {"verdict": report.verdict, "exit_code": report.exit_code, "summary": report.summary(verdict_path),
            "candidate": report.candidate.identity(), "baseline": report.baseline.identity(),
            "tolerances": asdict(report.rules), "compared_points": report.compared,
            "regressions": len(report.regressions), "comparisons": len(report.comparisons),
            "unfinished_cases": report.unfinished, "rows": rows, "notes": report.notes}


def human_table(report: GateReport) -> str:
    """The gate as people read it: the verdict, the regressions, how many comparisons passed, and the notes
    (gate.md lists every comparison when none regressed)."""
    lines = [report.summary()]
    if report.regressions:
        lines += [f"regressions against {report.baseline.directory}:", format_findings(report.regressions)]
    passed = sum(1 for finding in report.comparisons if not finding.regression)
    if passed:
        lines.append(f"{passed} comparisons passed or were not judged (every row, its test and p-value: gate.json, "
                     "gate.md)")
    lines += [f"note: {note}" for note in report.notes]
    return "\n".join(lines)


def write_verdict(report: GateReport, path: Path) -> tuple[Path, Path]:
    """Write gate.json at ``path`` and the human table (Markdown) beside it (``.md``); return both paths."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    markdown = path.with_suffix(".md")
    atomic_write_bytes(path, (json.dumps(verdict_record(report, path), indent=2) + "\n").encode())
    text = [f"# Gate: {report.verdict}", "", report.summary(path), ""]
    if report.comparisons:
        chosen = report.regressions or report.comparisons
        text += ["## " + ("Regressions" if report.regressions else "Every comparison"), "",
                 _markdown_findings(chosen), ""]
    text += [f"- note: {note}" for note in report.notes]
    atomic_write_bytes(markdown, ("\n".join(text) + "\n").encode())
    return path, markdown


def _markdown_findings(findings: list[Finding]) -> str:
    def cell(text: str) -> str:
        return str(text).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")

    return render_grid(GATE_HEADERS, [[cell(text) for text in finding.cells()] for finding in findings], markdown=True)


def rules_of(candidate: GateSide, tolerances_file: str | Path | None = None) -> GateRules:
    """The gate's rules: ``--tolerances FILE``'s ``[tolerances]``, else the candidate sweep's, else defaults."""
    if tolerances_file is not None:
        data = load_toml(Path(tolerances_file))
        table = parse(Tolerances, data.get("tolerances", {}) if isinstance(data, dict) else {}, str(tolerances_file),
                      prefix="tolerances")
    else:
        table = Tolerances.model_validate(candidate.tolerances or {})
    return GateRules(false_valid_increase=table.false_valid_increase, pct_valid_drop_points=table.pct_valid_drop_points,
                     error_increase_mps=table.error_increase_mps, significance=table.significance)
