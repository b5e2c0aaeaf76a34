"""Reference DIMES (Descent Image Motion Estimation System) velocity estimator.

Three descent images + measurements (attitude, radar altitude, biased IMU velocity, sun direction)
in; horizontal velocity at the last image, a valid flag with a reason code and per-feature
diagnostics out. See :mod:`dimes_velocity.estimator` for the steps and
:class:`dimes_velocity.config.EstimatorConfig` for the parameters.

    from dimes_velocity import DimesEstimator
    result = DimesEstimator(camera).estimate([dn1, dn2, dn3], measurements)

Image files (PNG, TIFF, .npy, raw, PDS3, VICAR, ISIS3; full frames binned as on chip; bit depth
declared, never guessed) are read by :mod:`file_formats.descent_images`.

The flight DIMES logic followed
-------------------------------
From the MER DIMES papers (Cheng, Johnson, Matthies, CVPR 2005, "MER-DIMES: a planetary landing
application of computer vision"; Johnson et al., IJCV 2007, "Design through operation of an
image-based velocity estimation system for Mars landing"):

* three images at about 2000, 1725 and 1450 m; each binned to 256 x 256, cleaned of the
  frame-transfer smear and flattened; the zero-phase zone (parachute and lander shadow in the
  opposition halo) and the predicted heat shield are masked;
* each image is rectified to a level ground plane from the measured attitude and radar altitude,
  so that a template changes between images by a translation only;
* feature selection: templates with high corner interest, spread over the overlap of the pair,
  away from the masks and with enough contrast (flight tracked two per pair: the paper's Table 3
  lists features 00, 01, 10, 11);
* pyramid correlation: a coarse search over a window sized from the velocity, attitude and altitude
  uncertainties, refined at full resolution to a sub-pixel peak;
* correlation metrics gate each template (the flight software reported brightness, contrast and
  correlation, paper Table 3);
* consistency between the two pairs: the image-pair displacements, compared through the IMU's
  velocity change, must agree (a constant IMU bias here), else the velocity is flagged invalid.

Where this reference differs (documented rather than copied; the flight thresholds are not
published): up to 8 templates per pair tracked until 4 agree, and two agreeing templates that share
no pixel required per pair (flight: two per pair, checked across pairs); the distinct-peak tests
(no other peak within 3 sigma of the best, sigma from the pixel noise; curvature) at the
coarse level where the search is done; a match within the
prior's circle; a residual consistent with the templates' noise; matches that do not move in the raw
image refused as marks on the optics; a stated uncertainty with every valid velocity.
"""
from typing import TYPE_CHECKING, Any

from dimes_velocity.config import EstimatorConfig, estimator_config_from_data
from dimes_velocity.result import REASONS, FeatureMetrics, PairResult, StageTimings, VelocityEstimate
from flight_interface.measurements import DescentMeasurements, ImageMeasurement, MeasurementError

if TYPE_CHECKING:
    from dimes_velocity.estimator import DimesEstimator, estimate_velocity


def __getattr__(name: str) -> Any:
    """Load ``DimesEstimator`` and ``estimate_velocity`` on first use.

    The estimator's compiled passes load numba, which imports scipy: reading an estimator's configuration
    (``dimes_velocity.config``) loads no numerical stack.
    """
    if name in ("DimesEstimator", "estimate_velocity"):
        from dimes_velocity import estimator

        return getattr(estimator, name)
    raise AttributeError(f"module 'dimes_velocity' has no attribute {name!r}")

__all__ = [
    "DimesEstimator", "estimate_velocity", "EstimatorConfig", "estimator_config_from_data", "DescentMeasurements",
    "ImageMeasurement", "MeasurementError", "REASONS", "FeatureMetrics", "PairResult", "StageTimings",
    "VelocityEstimate",
]
