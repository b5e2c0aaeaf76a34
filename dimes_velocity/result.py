"""What the estimator returns: the velocity, a valid flag with a reason code, and diagnostics.

Reason codes (``VelocityEstimate.reason``; ``PairResult.reason``)
-----------------------------------------------------------------
ok                      valid estimate
bad_attitude            an image's boresight is further than ``max_off_nadir_deg`` from nadir (or
                        the camera would be below the ground)
sky                     too little of the rectified ground grid is seen by the camera (mostly sky)
no_signal               too much of the ground has no signal (dark image, sky)
saturated               too much of the ground is saturated
excluded_zone           the zero-phase zone / heat shield cover too much of the ground
no_overlap              no template fits in the overlap of the pair together with its search window
low_contrast            no template has enough contrast over noise (bland or textureless scene)
no_match_within_prior   no match within the prior: check attitude/IMU. Every tracked template of a
                        pair failed (or too few matched), most often because its correlation peak lay
                        on the edge of its search window or further from its prediction than the prior
                        allows: the ground is not where the measured attitude, IMU velocity (or
                        position) and radar altitude put it, beyond their configured uncertainties
                        (``max_velocity_bias_mps``, ``attitude_uncertainty_deg``, ...), or the images
                        do not show the same ground
search_outside          (every tracked template failed, most often for this reason:) the search
                        window left the image
ambiguous_match         another coarse-level displacement, outside the best peak's lobe, correlated not
                        significantly worse than the best (``ambiguity_confidence_sigma``)
flat_peak               the coarse or fine correlation peak was not sharp enough
low_correlation         the correlation peak was below ``min_correlation``
match_in_excluded_area  the match fell on excluded ground (zone, saturated, no signal, off image)
camera_fixed            the match did not move in the raw image: a mark on the optics or detector
residual_exceeds_noise  the match decorrelates more than the template's and match's noise explain
too_few_features        fewer good matches than ``min_features_per_pair``
features_disagree       the matches of one pair do not agree (no majority within tolerance)
features_clustered      the agreeing matches are closer together than ``min_group_span_px`` (their
                        templates overlap: not independent evidence)
pairs_disagree          the IMU velocity biases from the image pairs disagree beyond tolerance
imu_bias_implausible    the answer implies an IMU velocity bias the IMU's error model does not allow at
                        ``implied_bias_confidence`` (``imu_velocity_bias_sigma_mps``; e.g. a shadow
                        moving with the wind tracked as ground)
sun_below_horizon       the measured sun direction is at or below the horizon: there is no sunlit
                        ground to track, whatever the images show (the estimator answers invalid,
                        as flight software must, rather than refusing the input)

Per-feature statuses (``FeatureMetrics.status``) keep the finer codes: ``search_border`` (the
correlation peak was on the edge of the search window) and ``outside_prior`` (the match lay further
from its prediction than the prior allows) are the two that make up ``no_match_within_prior``.

When the estimate is invalid, the velocity is the uncorrected IMU velocity at the last image and
the bias is zero (never NaN).
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass

REASONS = (
    "ok", "bad_attitude", "sky", "no_signal", "saturated", "excluded_zone", "no_overlap", "low_contrast",
    "no_match_within_prior", "search_outside", "ambiguous_match", "flat_peak", "low_correlation",
    "match_in_excluded_area", "camera_fixed", "residual_exceeds_noise", "too_few_features", "features_disagree",
    "features_clustered", "pairs_disagree", "sun_below_horizon", "imu_bias_implausible",
)

#: Per-feature statuses saying the match was not found where the prior put it (on the search window's edge,
#: or further from the prediction than the prior allows).
PRIOR_FAILURES = ("search_border", "outside_prior")


def failed_pair_reason(statuses: list[str], otherwise: str | None = None) -> str:
    """A failed pair's reason from its templates' statuses.

    Parameters
    ----------
    statuses : list of str
        Each template's status (``"ok"`` or a rejection reason).
    otherwise : str or None, optional
        The reason to give instead of the most common failure, unless that is the prior's.

    Returns
    -------
    str
        ``no_match_within_prior`` when the prior's failures (:data:`PRIOR_FAILURES`, counted together)
        are the most common failure, else the most common failure (``otherwise``, when given, instead);
        ``otherwise`` or ``too_few_features`` when no template failed.
    """
    failures = [status for status in statuses if status != "ok"]
    if not failures:
        return otherwise or "too_few_features"
    counts = Counter("no_match_within_prior" if status in PRIOR_FAILURES else status for status in failures)
    reason, count = counts.most_common(1)[0]
    if counts["no_match_within_prior"] == count:       # ties go to the prior: it explains them all
        return "no_match_within_prior"
    return otherwise or reason


@dataclass(frozen=True)
class FeatureMetrics:
    """One tracked template (paper Table 3: brightness, contrast, correlation) and its match.

    Attributes
    ----------
    pair, index : int
        Image pair (0: images 0-1, 1: images 1-2) and rank of the template in the pair.
    column_px, row_px : int
        Template centre in the rectified first image of the pair.
    east_m, north_m : float
        Its ground position in the estimator's frame (IMU-predicted lander at image 0 at the origin).
    brightness_dn, contrast_dn : float
        Mean and standard deviation of the template (flattened, binned DN).
    contrast_to_noise : float
        Standard deviation of the template minus its best-fit plane, over the expected pixel noise.
    correlation : float
        Normalised correlation at the sub-pixel peak.
    second_peak_ratio : float
        Second-best / best coarse correlation peak.
    peak_curvature_per_px2 : float
        Smallest principal curvature of the fine correlation peak (1/px^2).
    coarse_peak_curvature_per_px2 : float
        The same at the coarse level, where the search is done (1 / coarse px^2).
    noise_decorrelation : float
        ``1 - correlation`` that the pixel noise of template and match alone would cause.
    image_motion_px : float
        Distance between the raw-image (binned) positions of the template and its match (0 when
        not matched).
    displacement_east_m, displacement_north_m : float
        Ground offset of the match from the IMU prediction (m); zero when not matched.
    status : str
        "ok" or the rejection reason of this match.
    used : bool
        Part of the agreeing group that gives the pair's displacement.
    """

    pair: int
    index: int
    column_px: int
    row_px: int
    east_m: float
    north_m: float
    brightness_dn: float
    contrast_dn: float
    contrast_to_noise: float
    correlation: float
    second_peak_ratio: float
    peak_curvature_per_px2: float
    coarse_peak_curvature_per_px2: float
    noise_decorrelation: float
    image_motion_px: float
    displacement_east_m: float
    displacement_north_m: float
    status: str
    used: bool


@dataclass(frozen=True)
class PairResult:
    """One image pair.

    ``displacement_*_m`` is the ground offset of the matches from their IMU-predicted positions
    (mean of the agreeing group), ``bias_*_mps`` = displacement / time between the images, the
    pair's estimate of the IMU horizontal velocity bias, ``displacement_sigma_m`` the standard error
    of that mean (per axis, m). Zero when the pair is not valid.

    Attributes
    ----------
    first_image, second_image : int
        Indices of the pair's images.
    valid : bool
        The pair gave a bias estimate.
    reason : str
        ``"ok"`` or one of :data:`REASONS`.
    displacement_east_m, displacement_north_m : float
        Ground offset of the matches from their IMU-predicted positions (m).
    bias_east_mps, bias_north_mps : float
        The pair's IMU horizontal velocity bias estimate (m/s).
    displacement_sigma_m : float
        Standard error of the mean displacement, per axis (m).
    search_radius_px : float
        Radius of the template search (rectified fine pixels).
    features_matched : int
        Templates whose match passed every check.
    features_used : int
        Matches in the agreeing group.
    """

    first_image: int
    second_image: int
    valid: bool
    reason: str
    displacement_east_m: float
    displacement_north_m: float
    bias_east_mps: float
    bias_north_mps: float
    displacement_sigma_m: float
    search_radius_px: float
    features_matched: int
    features_used: int


@dataclass(frozen=True)
class StageTimings:
    """Wall time of each stage, ms.

    Attributes
    ----------
    preprocess_ms, rectify_ms, select_ms, match_ms, solve_ms : float
        Binning and flattening; rectification; template selection; matching; the solution (ms).
    total_ms : float
        The whole estimate (ms).
    """

    preprocess_ms: float
    rectify_ms: float
    select_ms: float
    match_ms: float
    solve_ms: float
    total_ms: float


@dataclass(frozen=True)
class VelocityEstimate:
    """The estimator's answer.

    Attributes
    ----------
    velocity_east_mps, velocity_north_mps : float
        Horizontal velocity at the last image (IMU velocity minus the estimated bias).
    valid : bool
    reason : str
        "ok" when valid, else one of :data:`REASONS`.
    velocity_uncertainty_mps : float
        Stated uncertainty (RMS of the horizontal error magnitude, m/s) when valid, 0 when invalid:
        see :func:`dimes_velocity.solution.velocity_uncertainty`.
    imu_bias_east_mps, imu_bias_north_mps : float
        Estimated constant bias of the IMU horizontal velocity.
    ground_sample_m : float
        Ground sampling of the rectified images (m per pixel).
    pairs : tuple of PairResult
    features : tuple of FeatureMetrics
    timings : StageTimings
    """

    velocity_east_mps: float
    velocity_north_mps: float
    valid: bool
    reason: str
    velocity_uncertainty_mps: float
    imu_bias_east_mps: float
    imu_bias_north_mps: float
    ground_sample_m: float
    pairs: tuple[PairResult, ...]
    features: tuple[FeatureMetrics, ...]
    timings: StageTimings

    def to_dict(self) -> dict:
        """Plain JSON-ready dictionary.

        Returns
        -------
        dict
            The fields (floats finite, nested lists for pairs and features).
        """
        return _finite(asdict(self))


def _finite(value):
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return 0.0
    return value
