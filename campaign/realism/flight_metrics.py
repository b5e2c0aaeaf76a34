"""The DIMES correlation metrics of the selected templates per class, next to the paper's Table 3
(DIMES flight software on MOC2DIMES images and on the MER-A flight images of Gusev).

Metric definitions (the reference estimator's ``FeatureMetrics``; the paper reports the flight
software's values without formulas; its brightness has the scale of this one, i.e. the same binned DN):

* brightness: mean of the 15 x 15 template in the binned (256 x 256), flattened image, DN of a whole
  4 x 4 block (exposure only: dark, smear and falloff removed);
* contrast: standard deviation of the same template, same DN;
* contrast / brightness: their ratio per template (%), the measure the terrain is anchored to (the MER-A
  flight templates: 1.01, 1.07, 1.18 %; :mod:`campaign.studies.calibrate_contrast`);
* correlation: normalised correlation coefficient of the template with its match at the sub-pixel
  peak, over templates whose match passed every check (status "ok").

Brightness and contrast are taken over every template the estimator selected and searched for, whatever
its match's status and in valid and invalid cases alike (the flight software reported the metrics of the
templates it selected, before knowing whether their matches would pass).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

# Table 3 of the paper: features 00, 01 and 10 (feature 11: N/A)
PAPER_TABLE3 = {
    "MOC2DIMES (paper)": {"brightness": (5212.0, 4139.0, 5526.0), "contrast": (14.9, 14.1, 23.1),
                          "correlation": (0.87, 0.84, 0.94)},
    "MER-A flight (paper)": {"brightness": (4710.0, 3898.0, 4693.0), "contrast": (47.5, 41.7, 55.6),
                             "correlation": (0.88, 0.91, 1.00)},
}
COLUMNS = ("feature_brightness", "feature_contrast", "feature_correlation", "feature_status")


def template_values(members: pd.DataFrame, column: str, matched_only: bool = False) -> np.ndarray:
    """Every template's value of a per-template result column (``feature_*``) over the rows of ``members``,
    one flat array; ``matched_only``: only templates whose match passed every check (status "ok")."""
    values: list[float] = []
    has_status = "feature_status" in members
    for _, row in members.iterrows():
        data = row[column]
        if data is None or (isinstance(data, float) and np.isnan(data)):
            continue
        data = list(data)
        if matched_only and has_status and row["feature_status"] is not None:
            data = [v for v, s in zip(data, row["feature_status"]) if s == "ok"]
        values.extend(float(v) for v in data)
    return np.asarray(values, dtype=float)


def percentile_summary(values: np.ndarray, pattern: str, empty: str = "n/a") -> str:
    """``median [10th-90th percentile]`` of the finite ``values``, each formatted with ``pattern`` (``empty``
    when none is finite: a plug-in that reports templates without this metric stores NaN)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return empty
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return f"{pattern.format(p50)} [{pattern.format(p10)}-{pattern.format(p90)}]"


def metrics_table(results: pd.DataFrame, class_order: list[str]) -> str:
    """Markdown: per class the median [10th-90th percentile] of brightness, contrast and correlation
    of the selected templates, then the paper's three features for MOC2DIMES and MER-A flight."""
    ok = results[results["status"] == "ok"] if "status" in results else results
    lines = ["| source | templates | brightness DN | contrast DN | contrast / brightness % | correlation |",
             "|---|---|---|---|---|---|"]
    for class_name in class_order:
        members = ok[ok["class_name"] == class_name]
        if members.empty or "feature_brightness" not in members:
            continue
        brightness = template_values(members, "feature_brightness")
        contrast = template_values(members, "feature_contrast")
        correlation = template_values(members, "feature_correlation", matched_only=True)
        ratio = 100.0 * contrast / np.maximum(brightness, 1e-9) if contrast.size == brightness.size else np.zeros(0)
        none = "no valid templates"
        lines.append(f"| {class_name} (this campaign) | {brightness.size} | {percentile_summary(brightness, '{:.0f}', none)} | "
                     f"{percentile_summary(contrast, '{:.1f}', none)} | {percentile_summary(ratio, '{:.2f}', none)} | "
                     f"{percentile_summary(correlation, '{:.3f}', none)} |")
    for source, values in PAPER_TABLE3.items():
        ratios = [100.0 * c / b for c, b in zip(values["contrast"], values["brightness"])]
        lines.append(f"| {source} | 3 | {', '.join(f'{v:.0f}' for v in values['brightness'])} | "
                     f"{', '.join(f'{v:.1f}' for v in values['contrast'])} | "
                     f"{', '.join(f'{v:.2f}' for v in ratios)} | "
                     f"{', '.join(f'{v:.2f}' for v in values['correlation'])} |")
    return "\n".join(lines)
