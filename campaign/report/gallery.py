"""The failure gallery of `campaign report DIR`: ``report/gallery.md`` and one PNG per case shown.

Which cases (:func:`gallery_cases`): for every estimator, each false-valid case (valid, horizontal error
above the false-valid threshold; at most :data:`MAX_FALSE_VALID` per estimator, the worst first) and up
to :data:`INVALID_PER_REASON` invalid cases (ran, answered not valid) of each reason, lowest case id first.
Failed rows (no answer) are not drawn: a "Failed rows" section counts them per estimator and kind
(:func:`failed_rows_section`), so an estimator whose every row failed is still on the page.

How (:func:`draw_gallery`): each case is simulated again from the store with the functions `campaign export`
uses (:func:`campaign.store.stored_config.stored_config`, :func:`campaign.case.inputs.campaign_inputs`,
:func:`campaign.case.compute.simulate_case_inputs`, :func:`~campaign.case.compute.estimator_inputs`,
:func:`~campaign.case.compute.case_truth`): a case is deterministic per (campaign seed, case id), so these are
the images its estimators got. Its PNG (``gallery/case-<id>-<estimator>.png``, :data:`FIGURE_INCHES` at
:data:`FIGURE_DPI`) shows the three read-out images (binned rows stretched 4x to the sensor's aspect) and,
under them, the stored reason, velocity error, stated uncertainty, attitude bias and attitude-knowledge floor
(``campaign/case/error_budget.py``).

Templates and matches: only the reference estimator (:mod:`dimes_velocity`) exposes where its templates
are (``FeatureMetrics``: the template's ground position in its frame and the match's offset from the IMU
prediction). The gallery runs it again on the re-created inputs and projects both into the raw images
with the poses the estimator itself believes (measured attitude and altitude, IMU-predicted position):
a square at each template (in the first image of its pair), an x where the IMU predicts it in the
second image and a + at the match found, joined by a line (the correction); colour: green = used in
the pair's agreeing group, yellow = matched but not used, red = rejected (its status). A plug-in
estimator (python or command) reports no positions, so its cases show the images and numbers only,
and the page says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from campaign.case.compute import case_truth, estimator_inputs, simulate_case_inputs  # noqa: E402
from campaign.case.inputs import (
    PlanRow,  # noqa: E402
    campaign_inputs,  # noqa: E402
)
from campaign.report.failures import failure_summary, markdown_cell  # noqa: E402
from campaign.report.plots import LABEL_POINTS, NOTE_POINTS, TICK_POINTS, TITLE_POINTS  # noqa: E402
from campaign.store.campaign_store import CampaignStore  # noqa: E402
from campaign.store.stored_config import stored_config  # noqa: E402
from dimes_velocity import geometry  # noqa: E402
from dimes_velocity.estimator import estimate_velocity  # noqa: E402
from flight_interface import cahvor  # noqa: E402

INVALID_PER_REASON = 3
MAX_FALSE_VALID = 20
FIGURE_INCHES = (15.0, 6.5)
FIGURE_DPI = 80
STATUS_COLOURS = {"used": "lime", "ok": "yellow", "rejected": "red"}


@dataclass(frozen=True)
class GalleryCase:
    """One case to show: the estimator, the case id, ``kind`` ("false-valid" or "invalid") and the
    stored result row (a dict of result columns)."""

    estimator: str
    case_id: int
    kind: str
    row: dict


def gallery_cases(results: pd.DataFrame, false_valid_mps: float, per_reason: int = INVALID_PER_REASON,
                  max_false_valid: int = MAX_FALSE_VALID) -> list[GalleryCase]:
    """The cases of the gallery (module docstring), per estimator in row order: false-valid ones worst
    first, then the invalid ones reason by reason (reasons in alphabetical order)."""
    chosen = []
    for name in dict.fromkeys(results["estimator"]):
        rows = results[(results["estimator"] == name) & (results["status"] == "ok")]
        valid = rows[rows["valid"].astype(bool)]
        errors = pd.to_numeric(valid["velocity_error_mps"], errors="coerce")
        wrong = valid[(errors > false_valid_mps) | errors.isna()]    # an unknown error is not vouched for either
        wrong = wrong.assign(_order=pd.to_numeric(wrong["velocity_error_mps"], errors="coerce").fillna(math.inf))
        for row in wrong.sort_values(["_order", "case_id"], ascending=[False, True]).head(max_false_valid).to_dict("records"):
            chosen.append(GalleryCase(str(name), int(row["case_id"]), "false-valid", row))
        invalid = rows[~rows["valid"].astype(bool)]
        for _, members in sorted(invalid.groupby(invalid["reason"].astype(str)), key=lambda item: item[0]):
            for row in members.sort_values("case_id").head(per_reason).to_dict("records"):
                chosen.append(GalleryCase(str(name), int(row["case_id"]), "invalid", row))
    return chosen


def failed_rows_section(results: pd.DataFrame) -> list[str]:
    """The gallery's "Failed rows" section: per estimator with failed rows (no answer, so no images of its own to
    judge) the count and every kind of failure with its count and first case (:mod:`campaign.report.failures`);
    [] when no row failed."""
    summaries = failure_summary(results)
    if not summaries:
        return []
    lines = ["## Failed rows", "", "Rows with no answer (the case's simulation or the estimator failed): not drawn, "
             "counted here; their full error texts are in the report's Failed cases tables.", "",
             "| estimator | failed rows | kind | rows | first |", "|---|---|---|---|---|"]
    for summary in summaries:
        for number, kind in enumerate(summary.kinds):
            total = f"{summary.failed} of {summary.rows}" if number == 0 else ""
            lines.append(f"| {markdown_cell(summary.estimator) if number == 0 else ''} | {total} | "
                         f"{markdown_cell(kind.kind)} | {kind.rows} | {markdown_cell(kind.example_where)} |")
    return lines + [""]


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _text(value: float, pattern: str = "{:.2f}") -> str:
    return pattern.format(value) if math.isfinite(value) else ("n/a" if math.isnan(value) else f"{value:.3g}")


def feature_marks(camera, measurements, features) -> list[dict]:
    """Read-out image positions (column, binned row) of the reference estimator's templates and matches:
    per feature its pair, colour class, template in the pair's first image, IMU-predicted position and
    match in the second (NaN when behind the camera or not matched), and the template-to-match motion
    in the estimator's square binned frame beside the estimator's own ``image_motion_px``."""
    positions = geometry.predicted_positions_m(measurements)
    poses = [geometry.camera_pose(camera, m.attitude_quat, m.radar_altitude_m, positions[k])
             for k, m in enumerate(measurements.images)]
    binning = camera.binning_rows

    def pixel(pose, east_m: float, north_m: float) -> tuple[float, float]:
        """(read-out column, binned row): CAHVOR gives full-resolution pixels; rows are binned on chip."""
        pixels, in_front = cahvor.project(pose.model, np.array([[east_m, north_m, 0.0]]))
        if not bool(np.asarray(in_front).ravel()[0]):
            return math.nan, math.nan
        column, row = np.asarray(pixels, dtype=float).reshape(-1, 2)[0]
        return float(column), float((row - 0.5 * (binning - 1)) / binning)

    marks = []
    for feature in features:
        first, second = poses[feature.pair], poses[feature.pair + 1]
        state = "used" if feature.used else ("ok" if feature.status == "ok" else "rejected")
        matched = feature.status == "ok"
        template = pixel(first, feature.east_m, feature.north_m)
        match = (pixel(second, feature.east_m + feature.displacement_east_m,
                       feature.north_m + feature.displacement_north_m) if matched else (math.nan, math.nan))
        marks.append({
            "pair": int(feature.pair), "state": state, "status": str(feature.status), "template": template,
            "predicted": pixel(second, feature.east_m, feature.north_m), "match": match,
            # template to match in the estimator's square frame (columns binned too): its image_motion_px
            "motion_px": float(np.hypot((match[0] - template[0]) / binning, match[1] - template[1])),
            "estimator_motion_px": float(feature.image_motion_px),
        })
    return marks


def draw_case(images_dn, marks: list[dict] | None, case: GalleryCase, floor_mps: float, bias_deg: float,
              false_valid_mps: float, binning: int, path: Path, note: str) -> Path:
    """One gallery PNG (module docstring); ``marks`` None: the estimator exposes no template positions."""
    figure = plt.figure(figsize=FIGURE_INCHES)
    grid = figure.add_gridspec(2, 3, height_ratios=[5.0, 1.1])
    row = case.row
    error = _number(row.get("velocity_error_mps"))
    for index, dn in enumerate(images_dn):
        axes = figure.add_subplot(grid[0, index])
        image = np.asarray(dn, dtype=float)
        height, width = image.shape
        low, high = np.percentile(image, [1, 99]) if image.size else (0.0, 1.0)
        shown = image[:, : width - width % binning].reshape(height, -1, binning).mean(axis=2)   # columns as rows:
        axes.imshow(shown, cmap="gray", vmin=low, vmax=max(high, low + 1e-9), aspect=binning,   # a square grid,
                    interpolation="nearest", extent=(-0.5, width - 0.5, height - 0.5, -0.5))    # drawn 4x faster
        for mark in marks or []:
            colour = STATUS_COLOURS[mark["state"]]
            if mark["pair"] == index:
                axes.plot(*mark["template"], marker="s", markersize=9, markerfacecolor="none",
                          markeredgecolor=colour, linestyle="none")
            if mark["pair"] + 1 == index:
                (pc, pr), (mc, mr) = mark["predicted"], mark["match"]
                axes.plot(pc, pr, marker="x", markersize=6, color=colour, linestyle="none")
                if math.isfinite(mc):
                    axes.plot([pc, mc], [pr, mr], color=colour, linewidth=0.8)
                    axes.plot(mc, mr, marker="+", markersize=10, color=colour, linestyle="none")
        axes.set_xlim(-0.5, width - 0.5)
        axes.set_ylim(height - 0.5, -0.5)
        axes.set_title(f"image {index + 1} (binned DN, 1st-99th percentile)", fontsize=TITLE_POINTS)
        axes.set_xlabel("column (px)", fontsize=LABEL_POINTS)
        axes.set_ylabel("binned row (px)", fontsize=LABEL_POINTS)
        axes.tick_params(labelsize=TICK_POINTS)
    text_axes = figure.add_subplot(grid[1, :])
    text_axes.axis("off")
    uncertainty = _number(row.get("velocity_uncertainty_mps"))
    lines = [
        f"reason: {row.get('reason')}   valid: {bool(row.get('valid'))}   velocity error: {_text(error)} m/s "
        f"(false-valid above {false_valid_mps:g} m/s)   stated uncertainty: {_text(uncertainty)} m/s",
        f"attitude bias (tilt): {_text(bias_deg)} deg   attitude-knowledge floor: {_text(floor_mps)} m/s   "
        f"error - floor: {_text(error - floor_mps)} m/s   altitude at image 1: "
        f"{_text(_number(row.get('altitude_image1_m')), '{:.0f}')} m",
        note,
    ]
    text_axes.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", fontsize=9, family="monospace",
                   transform=text_axes.transAxes)
    figure.suptitle(f"case {case.case_id} ({row.get('class_name')}), estimator {case.estimator}: {case.kind}",
                    fontsize=TITLE_POINTS + 1)
    if marks:
        for state, colour in STATUS_COLOURS.items():
            text_axes.plot([], [], marker="s", markerfacecolor="none", markeredgecolor=colour, linestyle="none",
                           label={"used": "template used", "ok": "matched, not used", "rejected": "rejected"}[state])
        text_axes.legend(loc="lower right", fontsize=NOTE_POINTS, facecolor="0.6",
                         title="square: template; x: IMU-predicted; +: match", title_fontsize=NOTE_POINTS)
    figure.subplots_adjust(left=0.04, right=0.99, top=0.9, bottom=0.02, wspace=0.18, hspace=0.15)
    figure.savefig(path, dpi=FIGURE_DPI)
    plt.close(figure)
    return path


def draw_gallery(store: CampaignStore, results: pd.DataFrame, out: Path, false_valid_mps: float) -> list[str]:
    """Write ``out/gallery/*.png`` and return the lines of ``gallery.md`` (module docstring)."""
    cases = gallery_cases(results, false_valid_mps)
    lines = ["# Failure gallery", "",
             f"Every false-valid case (valid, error above {false_valid_mps:g} m/s; at most {MAX_FALSE_VALID} per "
             f"estimator, worst first) and up to {INVALID_PER_REASON} invalid cases per reason, each re-simulated "
             "from the store as `campaign export` does. Squares: the reference estimator's templates (first image "
             "of each pair); x: where the IMU predicts them in the second image; +: the match found (green used, "
             "yellow matched but not used, red rejected). Plug-in estimators expose no template positions: their "
             "cases show the images and numbers only.", ""]
    lines += failed_rows_section(results)
    if not cases:
        return lines + ["No false-valid or invalid case to draw.", ""]
    manifest = store.manifest() or {}
    config = stored_config(store, manifest)
    resources = campaign_inputs(config)
    plan = store.plan()
    reference, reference_estimator = next(((spec, built) for spec, built in resources.estimators()
                                           if spec.kind == "reference"), (None, None))
    reference_config = reference_estimator.config if reference_estimator is not None else None
    (out / "gallery").mkdir(exist_ok=True)
    simulated: dict[int, tuple] = {}
    for case in cases:
        if case.case_id not in simulated:
            plan_row = PlanRow.from_record(plan[plan["case_id"].astype(int) == case.case_id].iloc[0].to_dict())
            inputs = simulate_case_inputs(resources, plan_row)
            truth = case_truth(resources, inputs)
            shared = estimator_inputs(resources, inputs)
            marks = None
            if reference_config is not None:
                answer = estimate_velocity(list(shared.images), shared.measurements, shared.camera, reference_config,
                                           shared.calibration.flat_field)
                marks = feature_marks(shared.camera, shared.measurements, answer.features)
            bias = truth.sensor_errors
            tilt_deg = math.degrees(math.hypot(bias.get("attitude_bias_east_rad", math.nan),
                                               bias.get("attitude_bias_north_rad", math.nan)))
            simulated[case.case_id] = (shared, truth, marks, tilt_deg)
        shared, truth, marks, tilt_deg = simulated[case.case_id]
        is_reference = reference is not None and case.estimator == reference.name
        note = (f"templates and matches: reference estimator {case.estimator} run again on these inputs"
                if is_reference else
                f"estimator {case.estimator} exposes no template positions: images and numbers only")
        name = f"case-{case.case_id}-{case.estimator}.png"
        draw_case(shared.images, marks if is_reference else None, case, truth.attitude_floor_mps, tilt_deg,
                  false_valid_mps, shared.camera.binning_rows, out / "gallery" / name, note)
        error = _number(case.row.get("velocity_error_mps"))
        lines += [f"## Case {case.case_id} ({case.row.get('class_name')}), `{case.estimator}`: {case.kind}, "
                  f"reason `{case.row.get('reason')}`, error {_text(error)} m/s, floor "
                  f"{_text(truth.attitude_floor_mps)} m/s", "", f"![case {case.case_id}](gallery/{name})", ""]
    return lines
