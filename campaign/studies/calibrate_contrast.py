"""Template contrast of simulated descents against MER-A flight (paper Table 3), and the terrain contrast
scale that matches it (issue 30: "Gusev anchored to flight").

::

    python -m campaign.studies.calibrate_contrast SITE.toml [--cases N] [--contrast-scale S ...]
                                                  [--fit-classes gcp,gdcp]

Renders the first ``N`` planned cases of every class of the campaign (the same cases, seeds and
default fidelity as ``campaign submit``; default 8 per class), runs the campaign's first estimator (the
reference DIMES by default) on them in this process and prints per class, for each terrain contrast scale
(``site.terrain_contrast_scale``, applied on top of the presets' own), the Table-3 medians over EVERY
template the estimator selected and tracked (whether or not its match passed the checks, and in valid and
invalid cases alike: the flight software reported the metrics of the templates it selected), with the
MER-A flight values beside them. With two or more scales, ``--fit-classes`` gives for each named class
the scale at which its median contrast/brightness equals the flight median (1.07 %), interpolated in
log(scale) between the bracketing scales.

Metric definitions (the reference estimator's; the flight software's are unpublished, see
docs/realism.md): brightness = mean of the 15 x 15 template in the binned (256 x 256), rectified,
flattened image (DN of a 4 x 4 block); contrast = standard deviation of the same template;
contrast/brightness their ratio per template (median of the ratios); correlation = normalised correlation
at the sub-pixel peak of matches that passed every check.

Nothing is written (terrains go to the terrain cache as in a campaign).

::

    python -m campaign.studies.calibrate_contrast --sweep runs/sweeps/terrain_contrast_gusev

reads a finished sweep (``results.parquet``, ``sweep.json``; e.g. ``sitedata/sweeps/terrain_contrast_*.toml``)
and gives, per point and class, % valid and false-valid against the median template contrast/brightness of
that point's cases (every selected template, as above): printed, written as ``DIR/template_contrast.md``,
and plotted in ``DIR/plots/template_contrast.png`` (% valid and false-valid against contrast/brightness, one
line per class, the flight band shaded).
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from campaign.case.compute import compute_case
from campaign.case.inputs import CampaignInputs, PlanRow
from campaign.configuration.campaign_file import campaign_config_from_data
from campaign.realism.flight_metrics import percentile_summary, template_values
from campaign.run.planning import plan_campaign
from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from config_tables.toml_file import load_toml

#: MER-A flight (paper Table 3, features 00, 01, 10): brightness and contrast (DN), correlation.
FLIGHT_BRIGHTNESS_DN = (4710.0, 3898.0, 4693.0)
FLIGHT_CONTRAST_DN = (47.5, 41.7, 55.6)
FLIGHT_CORRELATION = (0.88, 0.91, 1.00)
#: Contrast over brightness of the three flight features (%), and their median: the calibration target.
FLIGHT_RATIO_PCT = tuple(100.0 * c / b for c, b in zip(FLIGHT_CONTRAST_DN, FLIGHT_BRIGHTNESS_DN))
FLIGHT_RATIO_TARGET_PCT = float(np.median(FLIGHT_RATIO_PCT))
#: The band the anchored Gusev plains classes must lie in (issue 30), %.
FLIGHT_RATIO_BAND_PCT = (0.8, 1.4)


@dataclass(frozen=True)
class ClassTemplates:
    """Every tracked template of one class's cases: brightness and contrast (DN), correlation of the
    matches that passed every check, and the cases' outcome."""

    class_name: str
    brightness_dn: np.ndarray
    contrast_dn: np.ndarray
    correlation_ok: np.ndarray
    cases: int
    valid: int
    reasons: dict

    @property
    def ratio_pct(self) -> np.ndarray:
        return 100.0 * self.contrast_dn / np.maximum(self.brightness_dn, 1e-9)

    def median_ratio_pct(self) -> float:
        return float(np.median(self.ratio_pct)) if self.ratio_pct.size else math.nan


def campaign_with_cases(path: Path, cases: int, contrast_scale: float = 1.0, classes: list[str] | None = None):
    """The campaign of ``path`` with ``cases`` cases per class (of ``classes`` only, when given: the others
    none) and the site's terrain contrast scale set."""

    data = load_toml(path)
    site = data.get("site")
    if not isinstance(site, dict) or not isinstance(site.get("classes"), list):
        raise ConfigError(f"{path}: site is missing (a [site] table with classes)")
    names = [entry.get("name") for entry in site["classes"] if isinstance(entry, dict)]
    campaign = dict(data.get("campaign", {}))
    campaign["cases"] = {str(name): int(cases) if classes is None or name in classes else 0 for name in names}
    campaign.pop("cases_scale", None)
    data = {**data, "campaign": campaign, "site": {**site, "terrain_contrast_scale": float(contrast_scale)}}
    return campaign_config_from_data(data, path)


def class_templates(config) -> dict[str, ClassTemplates]:
    """Run the planned cases of ``config`` in this process; the first estimator's templates per class."""

    _, plan = plan_campaign(config)
    resources = CampaignInputs(config)
    collected: dict[str, dict] = {}
    for record in plan.to_dict("records"):
        row = PlanRow.from_record(record)
        estimate = compute_case(resources, row).estimates[0]
        entry = collected.setdefault(row.class_name, {"b": [], "c": [], "r": [], "cases": 0, "valid": 0, "reasons": {}})
        entry["cases"] += 1
        entry["valid"] += bool(estimate.valid)
        if not estimate.valid:
            entry["reasons"][estimate.reason] = entry["reasons"].get(estimate.reason, 0) + 1
        entry["b"].extend(estimate.feature_brightness or ())
        entry["c"].extend(estimate.feature_contrast or ())
        entry["r"].extend(r for r, s in zip(estimate.feature_correlation or (), estimate.feature_status or ()) if s == "ok")
    return {name: ClassTemplates(name, np.asarray(e["b"], float), np.asarray(e["c"], float), np.asarray(e["r"], float),
                                 e["cases"], e["valid"], e["reasons"])
            for name, e in collected.items()}


def weighted_median_ratio_pct(templates: dict[str, ClassTemplates], fractions: dict[str, float]) -> float:
    """Median contrast/brightness (%) of the templates of the classes pooled with their ellipse fractions as
    weights (each class's templates share its fraction): the site's median over a random landing."""
    values, weights = [], []
    for name, fraction in fractions.items():
        ratio = templates[name].ratio_pct if name in templates else np.zeros(0)
        if fraction > 0 and ratio.size:
            values.append(ratio)
            weights.append(np.full(ratio.size, fraction / ratio.size))
    if not values:
        return math.nan
    v, w = np.concatenate(values), np.concatenate(weights)
    order = np.argsort(v)
    cumulative = np.cumsum(w[order]) / w.sum()
    return float(v[order][np.searchsorted(cumulative, 0.5)])


def format_rows(scale: float, templates: dict[str, ClassTemplates]) -> list[str]:
    """One table row per class at one contrast scale."""
    rows = []
    for name, t in templates.items():
        reasons = ", ".join(f"{r} {n}" for r, n in sorted(t.reasons.items()))
        rows.append(f"| {scale:g} | {name} | {t.cases} | {t.valid}{f' ({reasons})' if reasons else ''} | "
                    f"{t.brightness_dn.size} | {percentile_summary(t.brightness_dn, '{:.0f}')} | {percentile_summary(t.contrast_dn, '{:.1f}')} | "
                    f"{percentile_summary(t.ratio_pct, '{:.2f}')} | {percentile_summary(t.correlation_ok, '{:.3f}')} |")
    return rows


def flight_row() -> str:
    return ("| - | MER-A flight (paper Table 3) | - | - | 3 | " + " / ".join(f"{v:.0f}" for v in FLIGHT_BRIGHTNESS_DN)
            + " | " + " / ".join(f"{v:.1f}" for v in FLIGHT_CONTRAST_DN) + " | "
            + " / ".join(f"{v:.2f}" for v in FLIGHT_RATIO_PCT) + f" (median {FLIGHT_RATIO_TARGET_PCT:.2f}) | "
            + " / ".join(f"{v:.2f}" for v in FLIGHT_CORRELATION) + " |")


def fit_scale(scales: list[float], ratios: list[float], target_pct: float = FLIGHT_RATIO_TARGET_PCT) -> float:
    """The scale at which the median contrast/brightness equals ``target_pct``: linear interpolation of
    the ratio in log(scale) between the two measured scales that bracket it (NaN when none do)."""
    order = np.argsort(scales)
    s = np.log(np.asarray(scales, float)[order])
    r = np.asarray(ratios, float)[order]
    for k in range(len(s) - 1):
        low, high = r[k], r[k + 1]
        if min(low, high) <= target_pct <= max(low, high) and high != low:
            return float(np.exp(s[k] + (target_pct - low) / (high - low) * (s[k + 1] - s[k])))
    return math.nan


def sweep_template_table(sweep_dir: Path) -> tuple[list[dict], str]:
    """Per point and class of a finished sweep: axis values, cases, % valid, false-valid and the template
    medians (every selected template of the first estimator's rows). Returns (rows, markdown)."""
    import json

    import pandas as pd

    description = json.loads((sweep_dir / "sweep.json").read_text())
    results = pd.read_parquet(sweep_dir / "results.parquet")
    if "estimator" in results:
        results = results[results["estimator"] == results["estimator"].iloc[0]]
    axes = list(description["axes"])
    false_valid_mps = float(description["false_valid_mps"])
    rows = []
    for point in description["points"]:
        members = results[results["point_id"] == point["point_id"]]
        for class_name in dict.fromkeys(members["class_name"]):
            cases = members[members["class_name"] == class_name]
            ran = cases[cases["status"] == "ok"]
            brightness = template_values(ran, "feature_brightness")
            contrast = template_values(ran, "feature_contrast")
            valid = ran["valid"].astype(bool)
            errors = ran["velocity_error_mps"].astype(float)
            ratio = 100.0 * contrast / np.maximum(brightness, 1e-9)
            rows.append({"point_id": point["point_id"], **point["values"], "class_name": class_name,
                         "cases": len(ran), "pct_valid": 100.0 * float(valid.mean()) if len(ran) else math.nan,
                         "false_valid": int((valid & (errors > false_valid_mps)).sum()),
                         "templates": int(ratio.size),
                         "ratio_pct": float(np.median(ratio)) if ratio.size else math.nan,
                         "ratio_p10_pct": float(np.percentile(ratio, 10)) if ratio.size else math.nan,
                         "ratio_p90_pct": float(np.percentile(ratio, 90)) if ratio.size else math.nan,
                         "brightness_dn": float(np.median(brightness)) if brightness.size else math.nan,
                         "contrast_dn": float(np.median(contrast)) if contrast.size else math.nan})
    lines = ["| point | " + " | ".join(axes) + " | class | cases | % valid | false-valid (> "
             f"{false_valid_mps:g} m/s) | templates | brightness DN | contrast DN | contrast / brightness % [p10-p90] |",
             "|---" * (len(axes) + 9) + "|"]
    for row in sorted(rows, key=lambda r: (r["class_name"], *(r[a] for a in axes))):
        lines.append(f"| {row['point_id']} | " + " | ".join(f"{row[a]:g}" if isinstance(row[a], float) else str(row[a])
                                                           for a in axes)
                     + f" | {row['class_name']} | {row['cases']} | {row['pct_valid']:.0f} | {row['false_valid']} | "
                     f"{row['templates']} | {row['brightness_dn']:.0f} | {row['contrast_dn']:.1f} | "
                     f"{row['ratio_pct']:.2f} [{row['ratio_p10_pct']:.2f}-{row['ratio_p90_pct']:.2f}] |")
    lines.append(f"| flight | | MER-A (paper Table 3) | | | | 3 | {' / '.join(f'{v:.0f}' for v in FLIGHT_BRIGHTNESS_DN)} | "
                 f"{' / '.join(f'{v:.1f}' for v in FLIGHT_CONTRAST_DN)} | {' / '.join(f'{v:.2f}' for v in FLIGHT_RATIO_PCT)} |"
                 .replace("| flight | |", "| flight | " + " | ".join("" for _ in axes) + " |"))
    return rows, "\n".join(lines)


def plot_sweep_templates(rows: list[dict], path: Path, title: str) -> None:
    """% valid and false-valid against the median template contrast/brightness, one line per class."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    figure, (top, bottom) = plt.subplots(2, 1, figsize=(6.5, 6.0), sharex=True)
    for colour, name in enumerate(dict.fromkeys(r["class_name"] for r in rows)):
        members = sorted((r for r in rows if r["class_name"] == name), key=lambda r: r["ratio_pct"])
        xs = [r["ratio_pct"] for r in members]
        top.plot(xs, [r["pct_valid"] for r in members], marker="o", color=f"C{colour}", label=name)
        bottom.plot(xs, [r["false_valid"] for r in members], marker="o", color=f"C{colour}", label=name)
    for axes in (top, bottom):
        axes.axvspan(*FLIGHT_RATIO_BAND_PCT, color="grey", alpha=0.2, label="MER-A flight band")
        axes.set_xscale("log")
        axes.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        axes.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        axes.set_xticks([0.5, 0.7, 1.0, 1.4, 2.0, 3.0, 5.0, 7.0, 10.0])
        axes.grid(alpha=0.3)
    top.set_ylim(-2, 102)
    top.set_ylabel("% valid")
    bottom.set_ylabel("false-valid cases")
    bottom.set_xlabel("median template contrast / brightness (%)")
    top.set_title(title, fontsize=8)
    top.legend(fontsize=7)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=90)
    plt.close(figure)


HEADER = ["| scale | class | cases | valid | templates | brightness DN | contrast DN | contrast / brightness % | correlation |",
          "|---|---|---|---|---|---|---|---|---|"]


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m campaign.studies.calibrate_contrast",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("campaign", type=Path, nargs="?", help="campaign or site TOML (e.g. sitedata/gusev.toml)")
    parser.add_argument("--sweep", type=Path, help="a finished sweep's output directory: its table against template contrast")
    parser.add_argument("--cases", type=int, default=8, help="cases per class (the first planned; default 8)")
    parser.add_argument("--contrast-scale", type=float, nargs="+", default=[1.0],
                        help="site terrain contrast scale(s) on top of the presets' (default 1)")
    parser.add_argument("--fit-classes", default="",
                        help="comma-separated classes to fit to the flight median, or 'site' for the ellipse-weighted "
                             "pool of the classes with a non-zero ellipse fraction")
    args = parser.parse_args(argv)
    if args.sweep is not None:
        if not (args.sweep / "sweep.json").is_file() or not (args.sweep / "results.parquet").is_file():
            print(f"--sweep {args.sweep}: no sweep.json and results.parquet (run the sweep first)", file=sys.stderr)
            return USAGE_ERROR
        rows, text = sweep_template_table(args.sweep)
        (args.sweep / "template_contrast.md").write_text(text + "\n")
        plot_sweep_templates(rows, args.sweep / "plots" / "template_contrast.png", str(args.sweep))
        print(text)
        print(f"wrote {args.sweep / 'template_contrast.md'} and {args.sweep / 'plots' / 'template_contrast.png'}")
        return 0
    if args.campaign is None:
        print("a campaign file or --sweep DIR is required", file=sys.stderr)
        return USAGE_ERROR
    if args.cases < 1:
        print("--cases must be >= 1", file=sys.stderr)
        return USAGE_ERROR
    try:
        results = {}
        print("\n".join(HEADER))
        for scale in args.contrast_scale:
            config = campaign_with_cases(args.campaign, args.cases, scale)
            fractions = {entry.name: entry.ellipse_fraction for entry in config.site.classes}
            results[scale] = class_templates(config)
            print("\n".join(format_rows(scale, results[scale])), flush=True)
            print(f"| {scale:g} | {config.site.name} (ellipse-weighted) | | | | | | "
                  f"{weighted_median_ratio_pct(results[scale], fractions):.2f} | |", flush=True)
        print(flight_row())
    except ConfigError as exc:
        print(str(exc), file=sys.stderr)
        return USAGE_ERROR
    low, high = FLIGHT_RATIO_BAND_PCT
    print(f"\nflight band of contrast/brightness: {low}-{high} %; target (median of the flight features) "
          f"{FLIGHT_RATIO_TARGET_PCT:.2f} %")
    for name in [n for n in args.fit_classes.split(",") if n]:
        scales = list(results)
        ratios = [weighted_median_ratio_pct(results[s], fractions) if name == "site"
                  else results[s][name].median_ratio_pct() for s in scales]
        print(f"{name}: contrast scale for {FLIGHT_RATIO_TARGET_PCT:.2f} % = {fit_scale(scales, ratios):.3f} "
              f"(measured {', '.join(f'{s:g}: {r:.2f} %' for s, r in zip(scales, ratios))})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
