"""Reference DIMES (Descent Image Motion Estimation System) velocity estimator.

Three descent images + measurements (attitude, radar altitude, biased IMU velocity, sun direction)
in; horizontal velocity at the last image, a valid flag with a reason code and per-feature
diagnostics out. See :mod:`dimes_velocity.estimator` for the steps and
:class:`dimes_velocity.config.EstimatorConfig` for the parameters.

    from dimes_velocity import DimesEstimator
    result = DimesEstimator(camera).estimate([dn1, dn2, dn3], measurements)
"""
from .config import EstimatorConfig, config_from_table
from .estimator import DimesEstimator, estimate_velocity
from flight_interface.measurements import DescentMeasurements, ImageMeasurement, MeasurementError
from .result import REASONS, FeatureMetrics, PairResult, StageTimings, VelocityEstimate

__all__ = [
    "DimesEstimator", "estimate_velocity", "EstimatorConfig", "config_from_table", "DescentMeasurements",
    "ImageMeasurement", "MeasurementError", "REASONS", "FeatureMetrics", "PairResult", "StageTimings",
    "VelocityEstimate",
]
