"""Estimator parameters: a frozen :class:`EstimatorConfig` with documented defaults, and a reader
for the ``[estimator]`` table of a campaign TOML file.

Angles are degrees only here, at the configuration edge; the estimator converts them with the
``*_rad`` properties. Pixel sizes are in pixels of the 256 x 256 binned, rectified image.

How the search window is sized
------------------------------
A ground point seen in image A is predicted in image B from the measured attitudes and altitudes and
the IMU-propagated horizontal displacement. The prediction error is bounded by::

    R = max_velocity_bias_mps * dt                       (unknown constant IMU velocity bias)
      + attitude_uncertainty_deg * |H_A - H_B|           (a common attitude error shifts by H tan e)
      + relative_attitude_uncertainty_deg * (H_A + H_B)   (image-to-image attitude noise)
      + altitude_uncertainty_fraction * (H_A + H_B) * tan(off-nadir)
      + search_margin_px * ground sample

and the coarse (half-resolution) search covers ``R`` (capped at ``max_search_radius_px``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from flight_interface.tomlfields import ConfigError, Table


@dataclass(frozen=True)
class EstimatorConfig:
    """Parameters of the reference DIMES estimator (defaults in brackets).

    Pre-processing
        remove_dark [True]: subtract the modelled dark charge (image area and storage readout ramp).
        remove_smear [True]: invert the fast-flush / frame-transfer smear (scene assumed static over the
            three CCD periods).
        remove_falloff [True]: divide by the binned flat field (a calibration product given to the
            estimator), or by the design cos^4 falloff when it has none.
        saturation_margin_dn [8]: a raw pixel within this many DN of the saturation level is saturated.
        min_signal_dn [40.0]: flattened binned pixels below this (DN, 4x4 binned) are "no signal" (sky,
            deep shadow) and excluded.
    Rectification
        rectified_size_px [256]: side of the square rectified (level ground) image.
        ground_sample_scale [1.0]: ground sampling = this x the nadir sampling of the highest image.
        equalize_resolution [True]: before rectification, blur each image with a Gaussian of
            ``resolution_blur * sqrt(r^2 - 1)`` binned pixels, r = common ground sampling / the image's
            own nadir sampling, so that images from different altitudes have the same resolution on
            the ground grid (and less aliasing when the lower images are down-sampled); capped at
            8 binned pixels.
        resolution_blur [0.5]: see equalize_resolution (0.5 = box pixel plus bilinear kernel).
        rectification_knots [17]: exact CAHVOR projection on a knots x knots grid, Catmull-Rom in between.
        max_off_nadir_deg [60.0]: boresight further than this from nadir -> the image is unusable.
        min_ground_coverage [0.25]: minimum valid fraction of a rectified image.
    Feature selection
        template_size_px [15]: fine-level template side (odd).
        coarse_template_size_px [11]: half-resolution template side (odd; covers twice the ground).
        feature_grid [4]: the overlap is split into feature_grid x feature_grid cells; the best
            corner (largest minimum eigenvalue of the gradient structure tensor over the template) of
            each cell is a candidate.
        features_per_pair [8]: most templates tracked per image pair, in order of interest.
        agreeing_features_to_stop [4]: tracking stops as soon as this many good matches all agree.
        min_feature_spacing_px [12]: minimum distance between selected template centres.
        border_margin_px [4]: templates keep this far from the rectified image's valid border.
        min_contrast_to_noise [2.5]: standard deviation of the template minus its best-fit plane / expected
            pixel noise (shot + read).
        zero_phase_half_angle_deg [4.3]: half angle of the excluded zone around the zero-phase
            (anti-sun) direction (paper section 3).
        heat_shield_radius_m [2.65]: heat shield radius (5.3 m diameter) for its exclusion cone.
        heat_shield_margin_deg [1.0]: extra half angle around the heat shield cone.
    Matching
        max_velocity_bias_mps [25.0]: largest expected IMU horizontal velocity bias.
        attitude_uncertainty_deg [3.0]: absolute attitude knowledge (3 sigma of 1 deg).
        relative_attitude_uncertainty_deg [0.3]: image-to-image attitude noise plus alignment (3 sigma).
        altitude_uncertainty_fraction [0.001]: radar altitude (3 sigma of 0.03 %).
        search_margin_px [2.0]: added to the search radius.
        max_search_radius_px [48]: cap on the search radius (fine-level pixels).
        fine_search_radius_px [2]: full-resolution refinement range around the coarse peak.
        subpixel_iterations [2]: Gauss-Newton (Lucas-Kanade) steps refining the sub-pixel peak.
    Quality checks (each failure has its reason code; :mod:`dimes_velocity.matching`)
        min_correlation [0.7]: normalised correlation peak at full resolution.
        max_second_peak_ratio [0.9]: second-highest coarse-level local maximum / main peak.
        second_peak_exclusion_px [2]: local maxima this close (coarse pixels) to the main peak are not a second peak.
        min_coarse_peak_curvature [0.02]: smallest principal curvature of the coarse-level peak, where
            the search is done (1 / coarse px^2).
        min_peak_curvature [0.02]: smallest principal curvature of the fine-level peak (1/px^2).
        max_noise_decorrelation_ratio [3.0], decorrelation_allowance [0.05]: the residual must be
            consistent with the template's noise: ``1 - correlation <= ratio x e + allowance`` with
            ``e = 1 / (CNR^2 - 1)`` the decorrelation that pixel noise alone causes (CNR: template
            standard deviation over its expected pixel noise, both images alike) and the allowance
            for what the model does not capture (resampling, resolution and rectification errors).
        min_image_motion_px [1.0]: a match that moved less than this in the image (binned pixels,
            between the raw positions of template and match) is on the optics or detector (dust, hot
            pixel, glint), not on the ground.
    Solution
        feature_agreement_px [1.5]: features of one pair must agree within this (fine pixels).
        require_feature_majority [True]: the agreeing group must hold more than half the matches.
        min_features_per_pair [2]: agreeing features needed for a pair to count.
        min_group_span_px [15]: the agreeing features must include two templates at least this far
            apart (fine pixels): with the template size, two templates that share no pixel, i.e.
            independent evidence (the selection keeps centres ``min_feature_spacing_px`` apart only).
        pair_agreement_mps [4.0]: the IMU bias from the two pairs must agree within this. The
            image-to-image attitude noise alone (0.05 deg per axis) makes the difference scatter by
            sqrt(H1^2 + 4 H2^2 + H3^2) * 0.05 deg / dt ~ 1 m/s per axis at 2000/1725/1450 m, so 4 m/s
            is ~4 sigma (a false rejection in ~0.03 % of cases); a wrong match is off by several
            pixels (>= 2 m/s per pixel of 6.5 m over 3.8 s).
        require_both_pairs [True]: both pairs must be valid (else one valid pair is enough).
    """

    remove_dark: bool = True
    remove_smear: bool = True
    remove_falloff: bool = True
    saturation_margin_dn: float = 8.0
    min_signal_dn: float = 40.0
    rectified_size_px: int = 256
    ground_sample_scale: float = 1.0
    equalize_resolution: bool = True
    resolution_blur: float = 0.5
    rectification_knots: int = 17
    max_off_nadir_deg: float = 60.0
    min_ground_coverage: float = 0.25
    template_size_px: int = 15
    coarse_template_size_px: int = 11
    feature_grid: int = 4
    features_per_pair: int = 8
    agreeing_features_to_stop: int = 4
    min_feature_spacing_px: int = 12
    border_margin_px: int = 4
    min_contrast_to_noise: float = 2.5
    zero_phase_half_angle_deg: float = 4.3
    heat_shield_radius_m: float = 2.65
    heat_shield_margin_deg: float = 1.0
    max_velocity_bias_mps: float = 25.0
    attitude_uncertainty_deg: float = 3.0
    relative_attitude_uncertainty_deg: float = 0.3
    altitude_uncertainty_fraction: float = 0.001
    search_margin_px: float = 2.0
    max_search_radius_px: int = 48
    fine_search_radius_px: int = 2
    subpixel_iterations: int = 2
    min_correlation: float = 0.7
    max_second_peak_ratio: float = 0.9
    second_peak_exclusion_px: int = 2
    min_coarse_peak_curvature: float = 0.02
    min_peak_curvature: float = 0.02
    max_noise_decorrelation_ratio: float = 3.0
    decorrelation_allowance: float = 0.05
    min_image_motion_px: float = 1.0
    feature_agreement_px: float = 1.5
    require_feature_majority: bool = True
    min_features_per_pair: int = 2
    min_group_span_px: int = 15
    pair_agreement_mps: float = 4.0
    require_both_pairs: bool = True

    def __post_init__(self):
        for name, (low, high) in _RANGES.items():
            value = getattr(self, name)
            if not (low <= value <= high) or (isinstance(value, float) and not math.isfinite(value)):
                raise ConfigError(f"EstimatorConfig.{name} = {value!r} is out of range; allowed: {low:g} to {high:g}")
        for name in ("template_size_px", "coarse_template_size_px"):
            if getattr(self, name) % 2 == 0:
                raise ConfigError(f"EstimatorConfig.{name} = {getattr(self, name)} must be odd")

    @property
    def zero_phase_half_angle_rad(self) -> float:
        return math.radians(self.zero_phase_half_angle_deg)

    @property
    def heat_shield_margin_rad(self) -> float:
        return math.radians(self.heat_shield_margin_deg)

    @property
    def max_off_nadir_rad(self) -> float:
        return math.radians(self.max_off_nadir_deg)

    @property
    def attitude_uncertainty_rad(self) -> float:
        return math.radians(self.attitude_uncertainty_deg)

    @property
    def relative_attitude_uncertainty_rad(self) -> float:
        return math.radians(self.relative_attitude_uncertainty_deg)


# Allowed ranges (inclusive) of the numeric fields; the TOML reader and __post_init__ both use them.
_RANGES: dict[str, tuple[float, float]] = {
    "saturation_margin_dn": (0.0, 4096.0),
    "min_signal_dn": (0.0, 1e6),
    "rectified_size_px": (64, 1024),
    "ground_sample_scale": (0.25, 4.0),
    "resolution_blur": (0.0, 4.0),
    "rectification_knots": (3, 129),
    "max_off_nadir_deg": (0.0, 85.0),
    "min_ground_coverage": (0.0, 1.0),
    "template_size_px": (5, 63),
    "coarse_template_size_px": (3, 63),
    "feature_grid": (1, 16),
    "features_per_pair": (1, 64),
    "agreeing_features_to_stop": (1, 64),
    "min_feature_spacing_px": (0, 256),
    "border_margin_px": (0, 64),
    "min_contrast_to_noise": (0.0, 1e3),
    "zero_phase_half_angle_deg": (0.0, 45.0),
    "heat_shield_radius_m": (0.0, 100.0),
    "heat_shield_margin_deg": (0.0, 45.0),
    "max_velocity_bias_mps": (0.0, 200.0),
    "attitude_uncertainty_deg": (0.0, 30.0),
    "relative_attitude_uncertainty_deg": (0.0, 30.0),
    "altitude_uncertainty_fraction": (0.0, 0.5),
    "search_margin_px": (0.0, 64.0),
    "max_search_radius_px": (2, 256),
    "fine_search_radius_px": (1, 16),
    "subpixel_iterations": (0, 10),
    "min_correlation": (-1.0, 1.0),
    "max_second_peak_ratio": (0.0, 1.0),
    "second_peak_exclusion_px": (1, 32),
    "min_coarse_peak_curvature": (0.0, 10.0),
    "min_peak_curvature": (0.0, 10.0),
    "max_noise_decorrelation_ratio": (0.0, 1e3),
    "decorrelation_allowance": (0.0, 2.0),
    "min_image_motion_px": (0.0, 64.0),
    "feature_agreement_px": (0.0, 100.0),
    "min_features_per_pair": (1, 64),
    "min_group_span_px": (0, 1024),
    "pair_agreement_mps": (0.0, 100.0),
}


def config_from_table(table: Table) -> EstimatorConfig:
    """Build an :class:`EstimatorConfig` from an ``[estimator]`` TOML table.

    Every field of the dataclass may be given under its own name; missing fields keep their
    defaults; unknown keys, wrong types and out-of-range values raise a one-line
    :class:`~flight_interface.tomlfields.ConfigError` naming the file and field.
    """
    defaults = EstimatorConfig()
    known = {field.name: field for field in fields(EstimatorConfig)}
    for key in table.data:
        if key not in known:
            raise table.fail(key, f"is not an estimator parameter; allowed: {', '.join(sorted(known))}")
    values = {}
    for name in known:
        if not table.has(name):
            continue
        default = getattr(defaults, name)
        if isinstance(default, bool):
            values[name] = table.boolean(name)
        elif isinstance(default, int):
            low, high = _RANGES[name]
            values[name] = table.integer(name, minimum=int(low), maximum=int(high))
        else:
            low, high = _RANGES[name]
            values[name] = table.number(name, minimum=low, maximum=high)
    try:
        return EstimatorConfig(**values)
    except ConfigError as exc:
        raise ConfigError(f"{table.source}: {table.path or 'estimator'}: {exc}") from None
