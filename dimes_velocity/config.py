"""Estimator parameters: :class:`EstimatorConfig`.

The one declaration of the reference estimator's ``[estimator]`` parameters of a campaign TOML file (names, types,
ranges, defaults; ``campaign schema estimator`` prints it).

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

from pydantic import Field, field_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, parse


class EstimatorConfig(ConfigModel):
    """``[estimator]``: parameters of the reference DIMES estimator.

    Angles in degrees at this edge; ``*_rad`` properties for the code. Groups: pre-processing, rectification,
    feature selection, matching, quality checks (each failure has its reason code; :mod:`dimes_velocity.matching`),
    solution.
    """

    remove_dark: bool = True
    """Subtract the modelled dark charge (image area and storage readout ramp)."""
    remove_smear: bool = True
    """Invert the fast-flush / frame-transfer smear (scene assumed static over the three CCD periods)."""
    remove_falloff: bool = True
    """Divide by the binned flat field (a calibration product given to the estimator), or by the design cos^4
    falloff when it has none."""
    saturation_margin_dn: float = Field(8.0, ge=0.0, le=4096.0)
    """A raw pixel within this many DN of the saturation level is saturated."""
    min_signal_dn: float = Field(40.0, ge=0.0, le=1e6)
    """Flattened binned pixels below this (DN, 4x4 binned) are "no signal" (sky, deep shadow) and excluded."""
    rectified_size_px: int = Field(256, ge=64, le=1024)
    """Side of the square rectified (level ground) image."""
    ground_sample_scale: float = Field(1.0, ge=0.25, le=4.0)
    """Ground sampling = this x the nadir sampling of the highest image."""
    equalize_resolution: bool = True
    """Before rectification, blur each image with a Gaussian of ``resolution_blur * sqrt(r^2 - 1)`` binned
    pixels, r = common ground sampling / the image's own nadir sampling, so that images from different
    altitudes have the same resolution on the ground grid (and less aliasing when the lower images are
    down-sampled); capped at 8 binned pixels."""
    resolution_blur: float = Field(0.5, ge=0.0, le=4.0)
    """See equalize_resolution (0.5 = box pixel plus bilinear kernel)."""
    rectification_knots: int = Field(17, ge=3, le=129)
    """Exact CAHVOR projection on a knots x knots grid, Catmull-Rom in between."""
    max_off_nadir_deg: float = Field(60.0, ge=0.0, le=85.0)
    """Boresight further than this from nadir -> the image is unusable."""
    min_ground_coverage: float = Field(0.25, ge=0.0, le=1.0)
    """Minimum valid fraction of a rectified image."""
    template_size_px: int = Field(15, ge=5, le=63)
    """Fine-level template side (odd)."""
    coarse_template_size_px: int = Field(11, ge=3, le=63)
    """Half-resolution template side (odd; covers twice the ground)."""
    feature_grid: int = Field(4, ge=1, le=16)
    """The overlap is split into feature_grid x feature_grid cells; the best corner (largest minimum eigenvalue
    of the gradient structure tensor over the template) of each cell is a candidate."""
    features_per_pair: int = Field(8, ge=1, le=64)
    """Most templates tracked per image pair, in order of interest."""
    agreeing_features_to_stop: int = Field(4, ge=1, le=64)
    """Tracking stops as soon as this many good matches all agree."""
    min_feature_spacing_px: int = Field(12, ge=0, le=256)
    """Minimum distance between selected template centres."""
    border_margin_px: int = Field(4, ge=0, le=64)
    """Templates keep this far from the rectified image's valid border."""
    min_contrast_to_noise: float = Field(2.5, ge=0.0, le=1e3)
    """Standard deviation of the template minus its best-fit plane / expected pixel noise (shot + read)."""
    min_template_contrast_dn: float = Field(0.0, ge=0.0, le=1e5)
    """A template whose standard deviation (flattened DN of the binned block, the flight software's Table 3
    "contrast") is below this is refused for contrast, like the flight DIMES's contrast gate (0 = off)."""
    zero_phase_half_angle_deg: float = Field(4.3, ge=0.0, le=45.0)
    """Half angle of the excluded zone around the zero-phase (anti-sun) direction (paper section 3)."""
    heat_shield_radius_m: float = Field(2.65, ge=0.0, le=100.0)
    """Heat shield radius (5.3 m diameter) for its exclusion cone."""
    heat_shield_margin_deg: float = Field(1.0, ge=0.0, le=45.0)
    """Extra half angle around the heat shield cone."""
    max_velocity_bias_mps: float = Field(25.0, ge=0.0, le=200.0)
    """Largest expected IMU horizontal velocity bias."""
    attitude_uncertainty_deg: float = Field(3.0, ge=0.0, le=30.0)
    """Absolute attitude knowledge (3 sigma of 1 deg)."""
    relative_attitude_uncertainty_deg: float = Field(0.3, ge=0.0, le=30.0)
    """Image-to-image attitude noise plus alignment (3 sigma)."""
    altitude_uncertainty_fraction: float = Field(0.001, ge=0.0, le=0.5)
    """Radar altitude (3 sigma of 0.03 %)."""
    search_margin_px: float = Field(2.0, ge=0.0, le=64.0)
    """Added to the search radius."""
    max_search_radius_px: int = Field(48, ge=2, le=256)
    """Cap on the search radius (fine-level pixels)."""
    fine_search_radius_px: int = Field(2, ge=1, le=16)
    """Full-resolution refinement range around the coarse peak."""
    subpixel_iterations: int = Field(2, ge=0, le=10)
    """Gauss-Newton (Lucas-Kanade) steps refining the sub-pixel peak."""
    min_correlation: float = Field(0.7, ge=-1.0, le=1.0)
    """Normalised correlation peak at full resolution."""
    max_second_peak_ratio: float = Field(1.0, ge=0.0, le=1.0)
    """A match is ambiguous when the second-highest coarse-level local maximum exceeds this fraction of the main
    peak (1 = off, the default: the distinct-peak test of ``ambiguity_confidence_sigma`` decides; the flight-like
    file ``sitedata/estimators/dimes_flight.toml`` sets 0.98)."""
    ambiguity_confidence_sigma: float = Field(3.0, ge=0.0, le=10.0)
    """Distinct-peak test at the coarse level, in standard deviations ``k`` of the correlation's noise (0 = off): a
    match is ambiguous when the coarse correlation surface reaches ``best - k sigma`` outside the best peak's own
    connected lobe, ``sigma`` the standard deviation of the difference of two correlations that the pixel noise
    of template and window causes (:func:`dimes_velocity.matching.distinct_peak_level`). 3: a competitor is
    refused unless it is 3 sigma below the best (one-sided 0.13 % chance that noise alone put it below)."""
    second_peak_exclusion_px: int = Field(2, ge=1, le=32)
    """Local maxima this close (coarse pixels) to the main peak are not a second peak."""
    min_coarse_peak_curvature: float = Field(0.02, ge=0.0, le=10.0)
    """Smallest principal curvature of the coarse-level peak, where the search is done (1 / coarse px^2)."""
    min_peak_curvature: float = Field(0.02, ge=0.0, le=10.0)
    """Smallest principal curvature of the fine-level peak (1/px^2)."""
    max_noise_decorrelation_ratio: float = Field(3.0, ge=0.0, le=1e3)
    """The residual must be consistent with the template's noise: ``1 - correlation <= ratio x e + allowance``
    with ``e = 1 / (CNR^2 - 1)`` the decorrelation that pixel noise alone causes (CNR: template standard
    deviation over its expected pixel noise, both images alike) and the allowance for what the model does
    not capture (resampling, resolution and rectification errors)."""
    decorrelation_allowance: float = Field(0.05, ge=0.0, le=2.0)
    """The allowance of the residual test (see max_noise_decorrelation_ratio): what the noise model does
    not capture (resampling, resolution and rectification errors)."""
    min_image_motion_px: float = Field(1.0, ge=0.0, le=64.0)
    """A match that moved less than this in the image (binned pixels, between the raw positions of template and
    match) is on the optics or detector (dust, hot pixel, glint), not on the ground."""
    feature_agreement_px: float = Field(1.5, ge=0.0, le=100.0)
    """Features of one pair must agree within this (fine pixels)."""
    require_feature_majority: bool = True
    """The agreeing group must hold more than half the matches."""
    min_features_per_pair: int = Field(2, ge=1, le=64)
    """Agreeing features needed for a pair to count."""
    min_group_span_px: int = Field(15, ge=0, le=1024)
    """The agreeing features must include two templates at least this far apart (fine pixels): with the
    template size, two templates that share no pixel, i.e. independent evidence (the selection keeps centres
    ``min_feature_spacing_px`` apart only)."""
    pair_agreement_mps: float = Field(4.0, ge=0.0, le=100.0)
    """The IMU bias from the two pairs must agree within this. The image-to-image attitude noise alone (0.05
    deg per axis) makes the difference scatter by sqrt(H1^2 + 4 H2^2 + H3^2) * 0.05 deg / dt ~ 1 m/s per
    axis at 2000/1725/1450 m, so 4 m/s is ~4 sigma (a false rejection in ~0.03 % of cases); a wrong match is
    off by several pixels (>= 2 m/s per pixel of 6.5 m over 3.8 s)."""
    require_both_pairs: bool = True
    """Both pairs must be valid (else one valid pair is enough)."""
    imu_velocity_bias_sigma_mps: float = Field(2.0, ge=0.0, le=50.0)
    """The IMU's error model: its horizontal velocity bias, 1 sigma per axis (m/s; the campaigns' sensor
    model draws 2 m/s). With the answer's stated uncertainty it bounds the IMU bias a valid answer may
    imply (``implied_bias_confidence``)."""
    implied_bias_confidence: float = Field(0.999, ge=0.5, le=1.0)
    """Confidence at which the implied IMU bias must be one the IMU's error model allows (1 = no check). The
    implied bias ``b = v_IMU - v`` of a right answer is normal with per-axis variance ``s_b^2 + s_v^2 / 2``
    (``s_b`` = ``imu_velocity_bias_sigma_mps``, ``s_v`` the stated RMS horizontal uncertainty), so ``|b|^2``
    over that variance is chi-square with 2 degrees of freedom: ``|b| > sqrt(-2 ln(1 - c))`` times its
    per-axis sigma is refused, ``imu_bias_implausible`` (0.999: 3.72 sigma, 1 right answer in 1000 refused)."""

    @field_validator("template_size_px", "coarse_template_size_px")
    @classmethod
    def _odd(cls, value: int) -> int:
        if value % 2 == 0:
            raise FieldProblem("", f"= {value} must be odd")
        return value

    @property
    def zero_phase_half_angle_rad(self) -> float:
        """``zero_phase_half_angle_deg`` (rad)."""
        return math.radians(self.zero_phase_half_angle_deg)

    @property
    def heat_shield_margin_rad(self) -> float:
        """``heat_shield_margin_deg`` (rad)."""
        return math.radians(self.heat_shield_margin_deg)

    @property
    def max_off_nadir_rad(self) -> float:
        """``max_off_nadir_deg`` (rad)."""
        return math.radians(self.max_off_nadir_deg)

    @property
    def attitude_uncertainty_rad(self) -> float:
        """``attitude_uncertainty_deg`` (rad)."""
        return math.radians(self.attitude_uncertainty_deg)

    @property
    def relative_attitude_uncertainty_rad(self) -> float:
        """``relative_attitude_uncertainty_deg`` (rad)."""
        return math.radians(self.relative_attitude_uncertainty_deg)


def estimator_config_from_data(data, source: str, path: str = "estimator") -> EstimatorConfig:
    """Validate an ``[estimator]`` table of reference-estimator parameters into an :class:`EstimatorConfig`.

    Parameters
    ----------
    data : Any
        The parsed table (every field optional).
    source : str
        The file (or other source) named in errors.
    path : str, optional
        Dotted path of the table in its file, prefixed to field names in errors.

    Returns
    -------
    EstimatorConfig
        The validated parameters.

    Raises
    ------
    ConfigError
        One line naming ``source``, the field (under ``path``) and the allowed values.
    """
    return parse(EstimatorConfig, data, source, path)
