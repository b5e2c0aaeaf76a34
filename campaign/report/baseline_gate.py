"""The statistics of ``campaign sweep --baseline``: is a candidate's result worse than its baseline's by
more than sampling noise?

For one sweep point and estimator, baseline and candidate are judged per appearance class and for the
site (the weighted row), on their case rows (``class_name``, ``status``, ``valid``,
``velocity_error_mps``; failed rows are left out, as in the tables). Three rules:

* **false-valid** (valid, error above the false-valid threshold): a regression when the candidate's count
  exceeds the baseline's by more than ``false_valid_increase`` (default 0: any increase). When the
  two ran different numbers of cases the baseline count is scaled to the candidate's:
  regression when ``fv_now > fv_before * n_now / n_before + false_valid_increase``.
* **% valid**: a drop is a regression when it is unlikely under sampling noise, the one-sided Fisher
  exact test on the 2 x 2 table (valid, not valid) x (baseline, candidate) giving ``p < significance``
  (:func:`valid_drop_p_value`), or when it is larger than ``pct_valid_drop_points`` whatever ``p``
  (a drop too large to wait for more cases). The site row tests the pooled counts of the classes inside
  the ellipse (non-zero fraction) and compares the ellipse-weighted % valid (``sum(fraction * value) /
  sum(fraction)`` over those classes, as in the tables) with the tolerance.
* **error mean + 3 sigma** (over valid cases): a regression when the growth is larger than
  ``error_increase_mps`` *and* unlikely under sampling noise: a one-sided permutation test
  (:func:`growth_p_value`: both sides' valid errors pooled, shuffled and split again :data:`RESAMPLES`
  times, seeded from the point, estimator and class, so the same inputs give the same verdict) gives
  ``p < significance``. The site row shuffles within every class inside the ellipse and grows the
  weighted sum. Without a valid case on either side the error is not judged (the % valid rule sees that).

  Why a permutation test and not a bootstrap interval, measured on pairs of error sets drawn from one
  distribution, 4 to 30 valid cases a side, nominal level 1 %: the percentile interval of the growth
  (each side resampled from itself) called 2 to 3.5 % of them a regression, the basic (centred)
  interval 2 to 13 %; resampling both sides with replacement from the pooled errors kept the level
  (0.5 to 1 %) but lost a 2 -> 32 m/s jump of six cases (p about 0.02: resampled mixtures of small
  and large errors have a huge sigma), which the permutation test, exact under exchangeability,
  finds (p = 0.002; 1/C(12,6) = 0.0011 up to Monte Carlo error) while keeping the level (0.25 to
  1.25 %). With n and m valid cases the smallest p is 1/C(n+m, n): 4 against 4 cases cannot go below
  1/70 = 0.014, so a class that small fails on the error only at a level above that.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
import pandas as pd

from campaign.report.aggregate import format_number, mean_plus_3_sigma, render_grid

RESAMPLES = 2000
REGRESSION, PASS, NOT_JUDGED = "regression", "pass", "not judged"      # a comparison's decision
GATE_HEADERS = ["point", "class", "estimator", "metric", "baseline", "candidate", "test", "why"]


@dataclass(frozen=True)
class GateRules:
    """The thresholds of the three rules (from the sweep file's ``[tolerances]``)."""

    false_valid_increase: int = 0
    pct_valid_drop_points: float = 20.0
    error_increase_mps: float = 0.5
    significance: float = 0.01


@dataclass(frozen=True)
class ClassSample:
    """One class's rows of one estimator: cases that ran (failed rows left out), valid cases,
    false-valid cases and the valid cases' errors (m/s, shape (valid,))."""

    cases: int
    valid: int
    false_valid: int
    valid_errors_mps: np.ndarray

    @property
    def pct_valid(self) -> float:
        return 100.0 * self.valid / self.cases if self.cases else math.nan


@dataclass(frozen=True)
class Finding:
    """One comparison of a metric: where, which metric, both values (as read, and as numbers), the test, its
    p-value (None for a count or an untested growth), the decision (``regression``, ``pass`` or ``not
    judged``) and why."""

    point: str
    class_name: str
    estimator: str
    metric: str
    baseline: str
    candidate: str
    test: str
    why: str
    decision: str = REGRESSION
    p_value: float | None = None
    test_name: str = ""
    baseline_value: float | None = None
    candidate_value: float | None = None

    @property
    def regression(self) -> bool:
        return self.decision == REGRESSION

    def cells(self) -> list[str]:
        return [self.point, self.class_name, self.estimator, self.metric, self.baseline, self.candidate,
                self.test, self.why]


def class_sample(rows: pd.DataFrame, false_valid_mps: float) -> ClassSample:
    """Counts and valid errors of result rows (one class, one estimator)."""
    ok = rows[rows["status"] == "ok"] if len(rows) else rows
    valid_mask = ok["valid"].astype(bool).to_numpy() if len(ok) else np.zeros(0, dtype=bool)
    errors = ok["velocity_error_mps"].to_numpy(dtype=float)[valid_mask] if len(ok) else np.zeros(0)
    with np.errstate(invalid="ignore"):
        false_valid = int(np.count_nonzero(errors > false_valid_mps))
    return ClassSample(int(len(ok)), int(valid_mask.sum()), false_valid, errors)


def valid_drop_p_value(valid_before: int, cases_before: int, valid_now: int, cases_now: int) -> float:
    """One-sided Fisher exact test that the candidate's valid fraction is lower than the baseline's.

    With all margins fixed, the baseline's valid count is hypergeometric; ``p`` is the probability of
    it being ``valid_before`` or more (the ``alternative="greater"`` p-value of
    ``scipy.stats.fisher_exact([[valid_before, invalid_before], [valid_now, invalid_now]])``),
    computed exactly with integer binomial coefficients. 10/10 vs 0/10 gives 1 / C(20, 10).
    """
    total, valid_total = cases_before + cases_now, valid_before + valid_now
    highest = min(cases_before, valid_total)
    tail = sum(math.comb(valid_total, k) * math.comb(total - valid_total, cases_before - k)
               for k in range(valid_before, highest + 1))
    return float(Fraction(tail, math.comb(total, cases_before)))


def _statistic(samples_mps: np.ndarray) -> np.ndarray:
    """mean + 3 sigma (ddof=1; 0 spread for one value) of each row of ``samples_mps`` (shape (resamples, n))."""
    with np.errstate(over="ignore", invalid="ignore"):
        spread = samples_mps.std(axis=1, ddof=1) if samples_mps.shape[1] > 1 else np.zeros(len(samples_mps))
        return samples_mps.mean(axis=1) + 3.0 * spread


def growth_p_value(pairs: list[tuple[float, np.ndarray, np.ndarray]], seed_text: str,
                   resamples: int = RESAMPLES) -> float:
    """One-sided Monte Carlo permutation p-value of the growth of ``sum(weight * (mean + 3 sigma))`` from
    baseline to candidate.

    Under "nothing changed" the labels baseline/candidate of a class's valid errors are exchangeable: each
    resample shuffles every class's pooled errors and splits them into sets of the observed sizes, and
    ``p = (1 + #(resampled growth >= observed growth)) / (1 + resamples)``.

    Parameters
    ----------
    pairs : list of (weight, baseline valid errors (m/s), candidate valid errors (m/s))
        One entry per class (weight 1 for a class row, the normalised ellipse fraction for the site row);
        every array finite and non-empty.
    seed_text : str
        Names what is judged; its sha256 seeds the generator (same inputs, same p-value).
    """
    rng = np.random.default_rng(int.from_bytes(hashlib.sha256(seed_text.encode()).digest()[:8], "little"))
    observed = sum(weight * (mean_plus_3_sigma(now) - mean_plus_3_sigma(before)) for weight, before, now in pairs)
    growth = np.zeros(resamples)
    for weight, before, now in pairs:
        pool = np.concatenate([now, before])
        shuffled = pool[np.argsort(rng.random((resamples, pool.size)), axis=1)]
        growth += weight * (_statistic(shuffled[:, :now.size]) - _statistic(shuffled[:, now.size:]))
    ties = 1e-9 * max(1.0, abs(observed))
    return float((1 + np.count_nonzero(growth >= observed - ties)) / (1 + resamples))


def judge(where: str, class_label: str, estimator: str, before: list[tuple[float, ClassSample]],
          now: list[tuple[float, ClassSample]], rules: GateRules, seed_text: str, weighted: bool) -> list[Finding]:
    """Every comparison of one class (one entry, weight 1) or of the site (every class with its ellipse
    fraction; ``weighted``) of one point and estimator: false-valid, % valid and error, each with its
    decision (the regressions are those with ``decision == "regression"``)."""
    comparisons = []

    def compared(metric, base_text, now_text, test, why, decision, p_value=None, test_name="", values=(None, None)):
        comparisons.append(Finding(where, class_label, estimator, metric, base_text, now_text, test, why, decision,
                                   p_value, test_name, *values))

    cases_before, cases_now = sum(s.cases for _, s in before), sum(s.cases for _, s in now)
    if cases_before == 0 or cases_now == 0:
        return comparisons
    fv_before, fv_now = sum(s.false_valid for _, s in before), sum(s.false_valid for _, s in now)
    allowed = fv_before * cases_now / cases_before + rules.false_valid_increase
    valid_before, valid_now = sum(s.valid for _, s in before), sum(s.valid for _, s in now)
    scaled = "count" if cases_now == cases_before else f"baseline count x {cases_now}/{cases_before} cases"
    regressed = fv_now > allowed + 1e-9
    compared("false-valid", f"{fv_before} of {valid_before} valid", f"{fv_now} of {valid_now} valid", scaled,
             f"{fv_now} {'>' if regressed else '<='} {allowed:g} allowed (baseline + {rules.false_valid_increase})",
             REGRESSION if regressed else PASS, test_name="count", values=(fv_before, fv_now))

    judged = [(w if weighted else 1.0, b, n) for (w, b), (_, n) in zip(before, now) if w > 0 or not weighted]
    if weighted:
        pct_before, pct_now = _weighted_pct(before), _weighted_pct(now)
    else:
        pct_before, pct_now = before[0][1].pct_valid, now[0][1].pct_valid
    drop = pct_before - pct_now
    metric = "weighted % valid" if weighted else "% valid"
    if judged and math.isfinite(drop):
        vb, nb = sum(b.valid for _, b, _ in judged), sum(b.cases for _, b, _ in judged)
        vn, nn = sum(n.valid for _, _, n in judged), sum(n.cases for _, _, n in judged)
        p_value = valid_drop_p_value(vb, nb, vn, nn) if nb and nn else 1.0
        reasons = []
        if drop > 0 and p_value < rules.significance:
            reasons.append(f"p < {rules.significance:g}")
        if drop > rules.pct_valid_drop_points:
            reasons.append(f"drop {drop:.1f} > {rules.pct_valid_drop_points:g} points")
        if reasons:
            why, decision = "; ".join(reasons), REGRESSION
        elif drop > 0:
            why = f"drop {drop:.1f} <= {rules.pct_valid_drop_points:g} points and p >= {rules.significance:g}"
            decision = PASS
        else:
            why, decision = "no drop", PASS
        compared(metric, f"{pct_before:.1f} ({vb}/{nb})", f"{pct_now:.1f} ({vn}/{nn})", f"p = {p_value:.3g}", why,
                 decision, p_value, "fisher_exact_one_sided", (pct_before, pct_now))

    metric = "weighted error m/s" if weighted else "error mean+3 sigma m/s"
    pairs = [(w, b.valid_errors_mps[np.isfinite(b.valid_errors_mps)], n.valid_errors_mps[np.isfinite(n.valid_errors_mps)])
             for w, b, n in judged]
    if pairs and all(before_errors.size and now_errors.size for _, before_errors, now_errors in pairs):
        error_before = sum(w * mean_plus_3_sigma(b) for w, b, _ in pairs)
        error_now = sum(w * mean_plus_3_sigma(n) for w, _, n in pairs)
        growth = error_now - error_before
        texts = format_number(error_before, "{:.2f}"), format_number(error_now, "{:.2f}")
        if math.isfinite(growth) and growth > rules.error_increase_mps:
            p_value = growth_p_value(pairs, seed_text)
            regressed = p_value < rules.significance
            compared(metric, *texts, f"p = {p_value:.3g} (permutation)",
                     f"+{growth:.2f} > {rules.error_increase_mps:g} m/s; p {'<' if regressed else '>='} "
                     f"{rules.significance:g}", REGRESSION if regressed else PASS, p_value, "permutation_one_sided",
                     (error_before, error_now))
        else:
            compared(metric, *texts, "not tested", f"growth {growth:+.2f} <= {rules.error_increase_mps:g} m/s"
                     if math.isfinite(growth) else "not finite", PASS, None, "none", (error_before, error_now))
    elif pairs:
        compared(metric, "n/a", "n/a", "not tested", "no valid case on one side (the % valid rule judges that)",
                 NOT_JUDGED, None, "none")
    return comparisons


def _weighted_pct(entries: list[tuple[float, ClassSample]]) -> float:
    return sum(0.0 if w == 0 else w * s.pct_valid for w, s in entries)


def judge_point(where: str, seed_key: str, before_rows: pd.DataFrame, now_rows: pd.DataFrame,
                fractions: dict[str, float], site_name: str, false_valid_mps: float,
                rules: GateRules) -> list[Finding]:
    """Every regression of one sweep point (:func:`compare_point`'s regressions)."""
    return [finding for finding in compare_point(where, seed_key, before_rows, now_rows, fractions, site_name,
                                                 false_valid_mps, rules) if finding.regression]


def compare_point(where: str, seed_key: str, before_rows: pd.DataFrame, now_rows: pd.DataFrame,
                  fractions: dict[str, float], site_name: str, false_valid_mps: float,
                  rules: GateRules) -> list[Finding]:
    """Every comparison of one sweep point: per estimator of the candidate (rows ``estimator``; compared
    with the baseline's rows of the same name), per class in ``fractions`` order, then the site."""
    findings = []
    for estimator in dict.fromkeys(now_rows["estimator"]) if len(now_rows) else []:
        base = before_rows[before_rows["estimator"] == estimator] if len(before_rows) else before_rows
        if base.empty:
            continue        # an estimator the baseline did not run: the caller notes it
        mine = now_rows[now_rows["estimator"] == estimator]
        before = [(fractions[c], class_sample(base[base["class_name"] == c], false_valid_mps)) for c in fractions]
        now = [(fractions[c], class_sample(mine[mine["class_name"] == c], false_valid_mps)) for c in fractions]
        for index, name in enumerate(fractions):
            findings += judge(where, name, estimator, [(1.0, before[index][1])], [(1.0, now[index][1])], rules,
                              f"{seed_key}|{estimator}|{name}", weighted=False)
        inside = sum(weight for weight in fractions.values() if weight > 0)   # site: sum(w x) / sum(w), w > 0
        if inside > 0:
            findings += judge(where, f"{site_name} weighted", estimator, [(w / inside, s) for w, s in before],
                              [(w / inside, s) for w, s in now], rules, f"{seed_key}|{estimator}|{site_name}",
                              weighted=True)
    return findings


def format_findings(findings: list[Finding]) -> str:
    """The regression table (plain text, right-aligned columns)."""
    return render_grid(GATE_HEADERS, [finding.cells() for finding in findings])
