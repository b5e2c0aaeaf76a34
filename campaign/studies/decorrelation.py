"""What decorrelates a template from its match: an ablation study on rendered descent cases (issue 30).

The paper's Table 3 gives the normalised correlation of three templates tracked by the DIMES flight
software between the first two MER-A flight images: 0.88, 0.91, 1.00 (its own MOC2DIMES simulation
0.84-0.94, on templates of contrast/brightness ~0.3 %). This module measures, on cases rendered by the
simulator and run through the reference estimator (its feature selection and matching, default
parameters), the distribution of that correlation and how much each mechanism of the image chain
moves it, one mechanism at a time.

Protocol
--------
1. Cases: the first ``cases_per_class`` cases of every class of a site's plan (the same plan, cases
   and seeds for every variant), rendered with the campaign's scene, sensors and calibration.
2. Terrain: the site file's classes (``sitedata/gusev.toml``: anchored to MER-A flight's template
   contrast/brightness, ~1.1 %; ``sitedata/examples/gusev_rough_moc.toml``: the rough MOC ground, ~3 %),
   optionally every synthetic class's contrast multiplied by ``--contrast-scale`` (``[site]
   terrain_contrast_scale``).
3. Variants (:data:`MECHANISMS`): the reference variant ("all on") is the campaign's nominal image
   chain; each ablation switches one mechanism off (or, for relief and atmosphere, which are off in
   the nominal Gusev campaign, on) through the campaign file's own tables (``[scene]``,
   ``[scene.effects]``, ``[scene.camera_effects]``, ``[sensors]``, ``[scene.atmosphere]``, the class's
   ``relief``), or holds the lander's attitude at its first-image value (no rotation between frames).
4. Metric: the correlation the estimator reports for each tracked template (normalised correlation
   at the refined sub-pixel peak, :mod:`dimes_velocity.matching`; for a match refused at the coarse
   level, the coarse level's best value), summarised as median [10-90 %] (a) over every tracked template
   ("all": whatever its checks said, as the flight software reported every template it tracked) and
   (b) over those whose match passed every check ("ok"), for both pairs and for the first pair alone
   (the images of Table 3).
5. Closed form: with template signal variance ``S`` and noise variances ``n_A^2``, ``n_B^2``, two noisy
   copies of one template correlate at ``rho = S / sqrt((S + n_A^2) (S + n_B^2))``
   (:func:`~campaign.studies.template_correlation.noise_correlation`). For every "ok" match ``S`` and
   ``n^2`` are measured after rectification (noisy minus noise-free expected DN through the same
   flattening, blur and map: :func:`~campaign.studies.template_correlation.case_features`); the
   estimator's own raw-pixel prediction ``rho ~ 1 / (1 + e)``, ``e = (n_A^2 / S_A + n_B^2 / S_B) / 2``,
   is reported beside it.
6. The same "ok" matches' correlation read on the whole-pixel grid
   (:func:`~campaign.studies.template_correlation.grid_peak_correlation`).
7. ``--unresolved-texture``: what ground texture finer than the terrain strip's pixels would add
   (:func:`~campaign.studies.template_correlation.unresolved_texture_experiment`).

This module holds the variants, runs them over the cases and tabulates the result; the measurement of one
case's templates (5-7) is :mod:`campaign.studies.template_correlation`. Run
``python -m campaign.studies.decorrelation --help``.
"""
from __future__ import annotations

import copy
import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from campaign.case.inputs import CampaignInputs, PlanRow, SharedInputs
from campaign.configuration.campaign_file import campaign_config_from_data
from campaign.run.planning import plan_campaign
from campaign.studies.template_correlation import case_features, recording_estimator, unresolved_texture_experiment
from config_tables.command_line import OneLineParser
from config_tables.toml_file import load_toml
from simulator.scene.descent_profile import DescentProfile

#: Table 3 of the paper, correlation of the three templates (features 00, 01, 10) of the first pair.
FLIGHT_CORRELATION = (0.88, 0.91, 1.00)
PAPER_SIMULATION_CORRELATION = (0.87, 0.84, 0.94)


@dataclass(frozen=True)
class Mechanism:
    """One variant of the image chain.

    Attributes
    ----------
    name : str
        Short label of the table.
    change : str
        What the variant changes against the reference ("all on").
    patch : dict
        Deep-merged into the campaign file's parsed TOML (e.g. ``{"scene": {"effects": {...}}}``).
    class_terrain : dict
        Merged into every class's ``terrain`` table (e.g. ``{"relief": True}``).
    steady_attitude : bool
        Hold every trajectory's attitude at its first-image value, angular rates zero (no rotation
        between or during the frames).
    """

    name: str
    change: str
    patch: dict = field(default_factory=dict)
    class_terrain: dict = field(default_factory=dict)
    steady_attitude: bool = False


REFERENCE = Mechanism("all on", "the nominal image chain of the campaign file")
NOISE_OFF = Mechanism("photon + read noise off", "camera shot (photon, dark) and read noise off",
                      {"scene": {"camera_effects": {"shot_noise": False, "read_noise": False}}})
SENSORS_EXACT = Mechanism("attitude/altitude exact", "every sensor exact: rectification with the true attitude "
                          "and altitude ([sensors] perfect)", {"sensors": {"perfect": True}})
NO_ROTATION = Mechanism("no rotation", "attitude held at image 1's, no angular rate (no rotation between "
                        "or during frames)", steady_attitude=True)
BLUR_OFF = Mechanism("motion blur off", "one pose per CCD period ([scene.effects] motion_blur)",
                     {"scene": {"effects": {"motion_blur": False}}})
PSF_OFF = Mechanism("optics PSF off", "no optics point-spread function", {"scene": {"camera_effects": {"optics_psf": False}}})
PHOTOMETRY_OFF = Mechanism("photometry off", "no DIMES/MOC photometric ratio (phase-angle change, opposition "
                           "halo)", {"scene": {"effects": {"photometric_correction": False}}})
RELIEF_ON = Mechanism("relief on", "terrain height field rendered: parallax, occlusion, slope shading at each "
                      "view, cast shadows", class_terrain={"relief": True})
ATMOSPHERE_ON = Mechanism("atmosphere on (tau 0.5)", "dust column tau = 0.5: MOC haze removed, descent path "
                          "light and attenuation added", {"scene": {"atmosphere": {"orbital_optical_depth": 0.5}}})
HIGH_FIDELITY = Mechanism("fidelity high", "the high fidelity preset: exact rays and photometry per pixel, smear and "
                          "blur fields rendered, exact Poisson noise (simulator.fidelity)", {"scene": {"fidelity": "high"}})
REFERENCE_FIDELITY = Mechanism("fidelity reference", "the reference preset: every shortcut off, 3 x 3 rays per pixel, "
                               ">= 4 motion sub-poses per terrain pixel (simulator.fidelity)",
                               {"scene": {"fidelity": "reference"}})
GRAIN_OFF = Mechanism("MOC grain off", "the terrain strip without the MOC's shot-noise grain (grain_snr 1e6 instead "
                      "of 60): static texture of the orbital source, not of the ground", class_terrain={"overrides": {"grain_snr": 1e6}})
ALL_OFF = Mechanism("resampling only", "noise off, sensors exact, no rotation, no blur, no PSF: what remains is "
                    "the scale change and resampling between altitudes",
                    {"scene": {"camera_effects": {"shot_noise": False, "read_noise": False, "optics_psf": False},
                               "effects": {"motion_blur": False}},
                     "sensors": {"perfect": True}}, steady_attitude=True)

NO_EQUALISATION = Mechanism("estimator: no resolution equalisation", "the estimator does not blur the lower "
                            "images to the highest one's resolution before rectifying (metric protocol, not physics)",
                            {"estimator": {"equalize_resolution": False}})
NO_REFINEMENT = Mechanism("estimator: biquadratic peak", "correlation read from the biquadratic fit of the 3 x 3 "
                          "correlation values, no Lucas-Kanade refinement (metric protocol, not physics)",
                          {"estimator": {"subpixel_iterations": 0}})

MECHANISMS: dict[str, Mechanism] = {m.name: m for m in (
    REFERENCE, NOISE_OFF, SENSORS_EXACT, NO_ROTATION, BLUR_OFF, PSF_OFF, PHOTOMETRY_OFF, RELIEF_ON, ATMOSPHERE_ON,
    HIGH_FIDELITY, REFERENCE_FIDELITY, GRAIN_OFF, ALL_OFF, NO_EQUALISATION, NO_REFINEMENT)}


def _merge(base: dict, patch: dict) -> dict:
    """``base`` deep-merged with ``patch`` (a new dict; tables merged, values replaced)."""
    merged = copy.deepcopy(base)
    for key, value in patch.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def variant_data(data: dict, mechanism: Mechanism, contrast_scale: float = 1.0) -> dict:
    """The campaign file's parsed TOML ``data`` changed for ``mechanism``, its synthetic terrain's contrast
    multiplied by ``contrast_scale`` (``[site] terrain_contrast_scale``, times any the file gives)."""
    changed = _merge(data, mechanism.patch)
    site = changed.setdefault("site", {})
    if contrast_scale != 1.0:
        site["terrain_contrast_scale"] = float(site.get("terrain_contrast_scale", 1.0)) * contrast_scale
    for entry in site.get("classes", []):
        terrain = entry.get("terrain", {})
        if terrain.get("kind") == "synthetic":
            for key, value in mechanism.class_terrain.items():
                terrain[key] = {**terrain.get(key, {}), **value} if isinstance(value, dict) else value
    return changed


def steady_profile(profile):
    """``profile`` with its attitude held at the first image's and no angular rate."""

    attitude = np.asarray(profile.pose(float(profile.image_times_s[0])).attitude_quat, dtype=float)
    values = {f.name: getattr(profile, f.name) for f in dataclasses.fields(DescentProfile)}
    values["attitude_quat"] = np.repeat(attitude[None, :], len(profile.time_s), axis=0)
    values["angular_rate_radps"] = np.zeros_like(np.asarray(profile.angular_rate_radps, dtype=float))
    return DescentProfile(**values)


def run_mechanism(site_file: Path, mechanism: Mechanism, contrast_scale: float, plan: pd.DataFrame,
                  output_dir: Path) -> pd.DataFrame:
    """Every tracked template of the cases of ``plan`` under ``mechanism`` (one row each)."""

    data = variant_data(load_toml(site_file), mechanism, contrast_scale)
    config = campaign_config_from_data(data, site_file, output_dir=output_dir)
    resources = CampaignInputs(config, SharedInputs())
    if mechanism.steady_attitude:
        resources.profiles = [steady_profile(profile) for profile in resources.profiles]
    estimator = recording_estimator(resources.camera, config.estimator, resources.calibration().flat_field)
    rows: list[dict[str, Any]] = []
    for record in plan.to_dict("records"):
        rows.extend(case_features(resources, PlanRow.from_record(record), estimator))
    frame = pd.DataFrame(rows)
    frame.insert(0, "mechanism", mechanism.name)
    return frame


def first_cases(site_file: Path, cases_per_class: int, contrast_scale: float, output_dir: Path,
                classes: list[str] | None = None) -> pd.DataFrame:
    """The first ``cases_per_class`` cases of every class (or of ``classes``) of the site's plan (terrain at
    ``contrast_scale``)."""

    config = campaign_config_from_data(variant_data(load_toml(site_file), REFERENCE, contrast_scale), site_file,
                                       output_dir=output_dir)
    _, plan = plan_campaign(config)
    chosen = plan["case_in_class"] < cases_per_class
    if classes:
        chosen &= plan["class_name"].isin(classes)
    return plan[chosen].reset_index(drop=True)


def _percentiles(values: np.ndarray) -> tuple[float, float, float]:
    if values.size == 0:
        return (float("nan"),) * 3
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return float(p50), float(p10), float(p90)


def summarise(features: pd.DataFrame, reference: str = REFERENCE.name) -> pd.DataFrame:
    """Per mechanism: median and 10-90 % of the correlation (every tracked template, and matches that
    passed every check), of the first pair alone, the closed-form noise correlation ``1 / (1 + e)`` of
    the "ok" matches, contrast/brightness, and the change of the median against ``reference``."""
    rows = []
    for name, group in features.groupby("mechanism", sort=False):
        ok = group[group["status"] == "ok"]
        first = group[group["pair"] == 0]
        every = _percentiles(group["correlation"].to_numpy(float))
        passed = _percentiles(ok["correlation"].to_numpy(float))
        noise = 1.0 / (1.0 + ok["noise_decorrelation"].to_numpy(float))
        factor = ok["noise_factor"].to_numpy(float)
        grid = ok["grid_correlation"].to_numpy(float)
        grid = _percentiles(grid[np.isfinite(grid)])
        rows.append(dict(
            mechanism=name, templates=len(group), ok=len(ok),
            median_all=every[0], p10_all=every[1], p90_all=every[2],
            median_ok=passed[0], p10_ok=passed[1], p90_ok=passed[2],
            median_first_pair=_percentiles(first["correlation"].to_numpy(float))[0],
            median_noise_closed_form=_percentiles(factor[np.isfinite(factor)])[0],
            median_noise_pixel_model=_percentiles(noise)[0],
            median_grid=grid[0], p10_grid=grid[1], p90_grid=grid[2],
            contrast_percent=100.0 * float(np.median(group["contrast_dn"] / group["brightness_dn"])),
            valid_percent=100.0 * float(group.drop_duplicates("case_id")["valid"].mean())))
    table = pd.DataFrame(rows)
    if reference in set(table["mechanism"]):
        base = table.loc[table["mechanism"] == reference].iloc[0]
        table["change_all"] = table["median_all"] - base["median_all"]
        table["change_ok"] = table["median_ok"] - base["median_ok"]
    return table


def markdown(table: pd.DataFrame, changes: dict[str, str]) -> str:
    """The ablation table as markdown (median [10-90 %], change of the median against "all on")."""
    lines = ["| mechanism | change | templates (ok) | contrast/brightness | correlation, every tracked template "
             "| change | correlation, ok matches | pair 1 median | noise closed form, rectified (raw pixels) "
             "| ok matches, whole-pixel peak | % valid |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in table.itertuples():
        lines.append(
            f"| {row.mechanism} | {changes.get(row.mechanism, '')} | {row.templates} ({row.ok}) | "
            f"{row.contrast_percent:.2f} % | {row.median_all:.3f} [{row.p10_all:.3f}-{row.p90_all:.3f}] | "
            f"{getattr(row, 'change_all', float('nan')):+.3f} | {row.median_ok:.3f} [{row.p10_ok:.3f}-{row.p90_ok:.3f}] | "
            f"{row.median_first_pair:.3f} | {row.median_noise_closed_form:.3f} ({row.median_noise_pixel_model:.3f}) | "
            f"{row.median_grid:.3f} [{row.p10_grid:.3f}-{row.p90_grid:.3f}] | {row.valid_percent:.0f} % |")
    lines.append(f"| MER-A flight (paper Table 3, pair 1) | | 3 | 1.01-1.18 % | "
                 f"{', '.join(f'{v:.2f}' for v in FLIGHT_CORRELATION)} | | | | | | |")
    lines.append(f"| MOC2DIMES (paper Table 3, pair 1) | | 3 | 0.26-0.42 % | "
                 f"{', '.join(f'{v:.2f}' for v in PAPER_SIMULATION_CORRELATION)} | | | | | | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m campaign.studies.decorrelation", description=__doc__.split("\n")[0])
    parser.add_argument("site_file", nargs="?", default="sitedata/gusev.toml", type=Path,
                        help="campaign/site file (default sitedata/gusev.toml)")
    parser.add_argument("--cases-per-class", type=int, default=8, help="first N cases of each class (default 8)")
    parser.add_argument("--contrast-scale", type=float, default=1.0,
                        help="[site] terrain_contrast_scale: multiplies every synthetic class's contrast (default 1: the file's terrain)")
    parser.add_argument("--mechanisms", default=",".join(MECHANISMS),
                        help=f"comma-separated variants (default all: {', '.join(MECHANISMS)})")
    parser.add_argument("--classes", help="comma-separated classes (default every class of the site)")
    parser.add_argument("--features", type=Path, help="write every tracked template's row to this parquet file")
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/decorrelation"),
                        help="output directory given to the campaign configuration (nothing is written there)")
    parser.add_argument("--unresolved-texture", action="store_true",
                        help="instead: the sub-terrain-pixel texture experiment (unresolved_texture_experiment)")
    args = parser.parse_args(argv)
    if args.unresolved_texture:
        for label, value in unresolved_texture_experiment().items():
            print(f"ground texture {label}: median template correlation {value:.4f}")
        return 0
    names = [name.strip() for name in args.mechanisms.split(",") if name.strip()]
    unknown = [name for name in names if name not in MECHANISMS]
    if unknown:
        parser.error(f"unknown mechanism(s) {unknown}; allowed: {', '.join(MECHANISMS)}")
    classes = [name.strip() for name in args.classes.split(",")] if args.classes else None
    plan = first_cases(args.site_file, args.cases_per_class, args.contrast_scale, args.scratch, classes)
    print(f"{args.site_file}: {len(plan)} cases ({args.cases_per_class} per class), contrast scale "
          f"{args.contrast_scale:g}", file=sys.stderr)
    frames = []
    for name in names:
        started = time.perf_counter()
        frames.append(run_mechanism(args.site_file, MECHANISMS[name], args.contrast_scale, plan, args.scratch))
        print(f"  {name}: {len(frames[-1])} templates, {time.perf_counter() - started:.0f} s", file=sys.stderr)
    features = pd.concat(frames, ignore_index=True)
    if args.features is not None:
        features.to_parquet(args.features)
    print(markdown(summarise(features), {name: MECHANISMS[name].change for name in names}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
