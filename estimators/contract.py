"""The estimator contract: what every velocity estimator gets and must give back.

An estimator sees only what a flight system has. It never imports :mod:`simulator` or :mod:`campaign`
and never receives simulator truth (the campaign passes the true flat field only when a campaign asks
for it with ``[estimator] flat_field = "truth"``, to measure what calibration costs).

Inputs (:class:`EstimatorInputs`)
---------------------------------
``images``
    The descent images in time order (three for DIMES), as the camera reads them out: DN, unsigned
    16-bit integers, shape ``camera.binned_shape`` (256 rows binned on chip x 1024 columns for MER).
``image_times_s``
    Start of each image's exposure (s), equal to ``measurements.images[k].time_s``.
``measurements``
    :class:`flight_interface.measurements.DescentMeasurements`: per image the measured attitude
    (lander body-to-world quaternion w, x, y, z), angular rate, radar altitude, IMU velocity (biased)
    and optionally IMU position and predicted heat-shield offset; the sun direction. World frame x
    east, y north, z up. As JSON: the schema in :mod:`file_formats.measurements_json`.
``camera``
    :class:`flight_interface.camera.Camera`: the camera model as designed (CAHVOR, mounting, timing,
    radiometry, electronics), read from the camera TOML (``camera.source``), without the simulator-only
    ``radiometry.prnu_seed`` (:mod:`estimators.camera_view`).
``calibration``
    :class:`flight_interface.calibration.CalibrationProducts`: the flat field (relative response per
    read-out pixel, shape ``camera.binned_shape``, about 1 on axis) or None.
``parameters``
    The estimator's own parameters from its ``[[estimators]]`` entry (a plain dict, JSON types).

Output (:class:`EstimatorOutput`; as JSON an object with these keys)
--------------------------------------------------------------------
``velocity_east_mps``, ``velocity_north_mps`` : number
    Horizontal velocity of the lander at the last image (world frame, m/s). Finite when valid; may be
    ``null`` when not valid.
``valid`` : bool
    True only when the estimator vouches for the velocity.
``reason`` : str
    ``"ok"`` when valid, else a short non-empty code saying why not (the estimator's own vocabulary).
``velocity_uncertainty_mps`` : number, optional
    The estimator's own stated 1-sigma horizontal velocity uncertainty (m/s), stored in the campaign's
    ``velocity_uncertainty_mps`` column (null, read as NaN, when not given or not valid).
``features`` : list of objects, optional
    Per-feature metrics, each with optional numbers ``brightness_dn``, ``contrast_dn``,
    ``correlation`` (paper Table 3) and an optional string ``status`` (``"ok"`` for a feature that
    was used); stored in the campaign's ``feature_*`` columns.

Other keys are allowed and ignored (diagnostics, timings). Anything else is a contract violation
(:class:`ContractViolation`): a missing key, a wrong type, an empty reason, ``valid`` with a reason
other than ``"ok"``; an implausible answer (:class:`ImplausibleOutput`, :func:`check_plausible`) is a
valid result with a non-finite velocity or a horizontal speed not below the campaign's bound, or a
stated uncertainty that is negative or not finite. The campaign records a violation, any exception
(``SystemExit`` and ``KeyboardInterrupt`` included), a non-zero exit or a timeout as *that*
estimator's failed result for the case (reason ``estimator_failed``, or ``implausible``), with the
message; the other estimators' results for the case are kept. Loading the estimator is not part of a
case: a module that does not import, bad parameters or a program that cannot be started is a set-up error
(:class:`estimators.plugins.EstimatorSetupError`) that stops a campaign run and records nothing.

Every estimator gets its inputs read-only (:func:`read_only_inputs`: the arrays are read-only views, so
a write raises ``ValueError`` inside the estimator; the campaign's cached flat field and camera arrays
are read-only at their source).

Ways in (``[[estimators]]`` entries of a campaign file, :mod:`estimators.entries`)
----------------------------------------------------------------------------------
``kind = "reference"``  the reference DIMES estimator (:mod:`dimes_velocity`), parameters = its
                        ``EstimatorConfig`` fields; the default when a campaign names no estimator.
``kind = "python"``     ``callable = "package.module:function"``, called as
                        ``function(inputs: EstimatorInputs) -> EstimatorOutput | Mapping``; with
                        ``isolate = true`` it runs in its own process like a command (timeout, crash-proof).
``kind = "command"``    an external program (:mod:`estimators.command`): ``argv`` with placeholders
                        for the image files, the measurements JSON, the camera TOML, the flat field
                        file and the output JSON, and ``timeout_s``; it writes the output JSON above.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from estimators.camera_view import estimator_camera
from flight_interface.calibration import CalibrationProducts
from flight_interface.camera import Camera
from flight_interface.measurements import DescentMeasurements

FEATURE_METRICS = ("brightness_dn", "contrast_dn", "correlation")
REQUIRED_KEYS = ("velocity_east_mps", "velocity_north_mps", "valid", "reason")


class ContractViolation(Exception):
    """An estimator broke the contract (bad output, crash, non-zero exit, timeout); one-line message."""


class ImplausibleOutput(ContractViolation):
    """A well-formed answer that cannot be right.

    See :func:`check_plausible`: a valid velocity that is not finite or faster than the bound, a negative or
    non-finite stated uncertainty; the message names the check.
    """


@dataclass(frozen=True)
class EstimatorInputs:
    """Everything an estimator receives for one case (the module docstring says more).

    Parameters
    ----------
    images : tuple of ndarray, each shape ``camera.binned_shape``, uint16
        The descent images in time order (DN).
    image_times_s : ndarray, shape (n_images,)
        Start of each image's exposure (s).
    measurements : DescentMeasurements
        Measured attitude, rates, radar altitude, IMU velocity per image; the sun direction.
    camera : Camera
        The camera as designed; replaced by its estimator view (:func:`estimators.camera_view.estimator_camera`).
    calibration : CalibrationProducts, optional
        The flat field (or none).
    parameters : Mapping, optional
        The estimator's own parameters (JSON types).
    """

    images: tuple
    image_times_s: np.ndarray
    measurements: DescentMeasurements
    camera: Camera
    calibration: CalibrationProducts = CalibrationProducts()
    parameters: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # the simulator's truth never reaches an estimator: the camera without radiometry.prnu_seed
        object.__setattr__(self, "camera", estimator_camera(self.camera))


@dataclass(frozen=True)
class EstimatorOutput:
    """An estimator's answer (the module docstring says more).

    Parameters
    ----------
    velocity_east_mps, velocity_north_mps : float or None
        Horizontal velocity at the last image, world frame (m/s); None when not valid.
    valid : bool
        True only when the estimator vouches for the velocity.
    reason : str
        ``"ok"`` when valid, else a short code saying why not.
    features : tuple of dict, optional
        Per-feature metrics (:data:`FEATURE_METRICS`, floats) and ``status`` (str).
    velocity_uncertainty_mps : float or None, optional
        The estimator's stated 1-sigma horizontal velocity uncertainty (m/s).
    """

    velocity_east_mps: float | None
    velocity_north_mps: float | None
    valid: bool
    reason: str
    features: tuple = ()          # of dicts with (some of) FEATURE_METRICS, floats, and "status", str
    velocity_uncertainty_mps: float | None = None


def _number(data: Mapping, key: str, allow_null: bool) -> float | None:
    value = data[key]
    if value is None and allow_null:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ContractViolation(f"field {key!r} must be a number; got {type(value).__name__} {value!r}"[:200])
    value = float(value)
    if not allow_null and not math.isfinite(value):
        raise ImplausibleOutput(f"field {key!r} must be finite when valid; got {value!r}")
    return value if math.isfinite(value) else None


def validate_output(result: Any) -> EstimatorOutput:
    """Check an estimator's answer and return it as an :class:`EstimatorOutput`.

    Parameters
    ----------
    result : EstimatorOutput or Mapping
        The answer, or a mapping such as parsed JSON.

    Returns
    -------
    EstimatorOutput
        The checked answer (features reduced to the known metrics, reason stripped).

    Raises
    ------
    ContractViolation
        Naming the field at fault (:class:`ImplausibleOutput` for a non-finite valid velocity or a bad
        uncertainty).
    """
    data: Mapping[str, Any]
    if isinstance(result, EstimatorOutput):
        data = {"velocity_east_mps": result.velocity_east_mps, "velocity_north_mps": result.velocity_north_mps,
                "valid": result.valid, "reason": result.reason, "features": list(result.features),
                "velocity_uncertainty_mps": result.velocity_uncertainty_mps}
    elif isinstance(result, Mapping):
        data = result
    else:
        raise ContractViolation(f"result must be an object with {', '.join(REQUIRED_KEYS)}; got {type(result).__name__}")
    missing = [key for key in REQUIRED_KEYS if key not in data]
    if missing:
        raise ContractViolation(f"missing field{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))}")
    valid = data["valid"]
    if not isinstance(valid, (bool, np.bool_)):
        raise ContractViolation(f"field 'valid' must be true or false; got {type(valid).__name__} {valid!r}"[:200])
    valid = bool(valid)
    reason = data["reason"]
    if not isinstance(reason, str) or not reason.strip():
        raise ContractViolation(f"field 'reason' must be a non-empty string; got {reason!r}"[:200])
    if valid and reason != "ok":
        raise ContractViolation(f"field 'reason' must be 'ok' when valid; got {reason!r}"[:200])
    east = _number(data, "velocity_east_mps", allow_null=not valid)
    north = _number(data, "velocity_north_mps", allow_null=not valid)
    features = data.get("features", None)
    if features is None:
        features = []
    if not isinstance(features, (list, tuple)):
        raise ContractViolation(f"field 'features' must be a list of objects; got {type(features).__name__}")
    checked = []
    for index, feature in enumerate(features):
        if not isinstance(feature, Mapping):
            raise ContractViolation(f"features[{index}] must be an object; got {type(feature).__name__}")
        record: dict[str, float | str] = {}
        for key in FEATURE_METRICS:
            if key in feature and feature[key] is not None:
                value = feature[key]
                if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                    raise ContractViolation(f"features[{index}].{key} must be a number; got {value!r}"[:200])
                record[key] = float(value)
        if feature.get("status") is not None:
            if not isinstance(feature["status"], str):
                raise ContractViolation(f"features[{index}].status must be a string; got {feature['status']!r}"[:200])
            record["status"] = feature["status"]
        checked.append(record)
    uncertainty = None
    if data.get("velocity_uncertainty_mps") is not None:
        _number(data, "velocity_uncertainty_mps", allow_null=True)         # the type check
        uncertainty = float(data["velocity_uncertainty_mps"])
        if not (math.isfinite(uncertainty) and uncertainty >= 0):
            raise ImplausibleOutput(f"field 'velocity_uncertainty_mps' must be finite and >= 0 when given; "
                                    f"got {uncertainty!r}")
    return EstimatorOutput(velocity_east_mps=east, velocity_north_mps=north, valid=valid, reason=reason.strip(),
                           features=tuple(checked), velocity_uncertainty_mps=uncertainty)


def output_to_dict(output: EstimatorOutput) -> dict:
    """The JSON form of an :class:`EstimatorOutput`.

    Parameters
    ----------
    output : EstimatorOutput
        The answer.

    Returns
    -------
    dict
        The output's keys (module docstring) with JSON values.
    """
    return {"velocity_east_mps": output.velocity_east_mps, "velocity_north_mps": output.velocity_north_mps,
            "valid": output.valid, "reason": output.reason, "features": [dict(f) for f in output.features],
            "velocity_uncertainty_mps": output.velocity_uncertainty_mps}


def check_plausible(output: EstimatorOutput, max_horizontal_speed_mps: float | None) -> EstimatorOutput:
    """Check that an answer is plausible.

    A valid velocity must be finite (also checked by :func:`validate_output`) with a horizontal speed
    below the bound, a stated uncertainty finite and >= 0. An invalid answer's velocity is not used, so
    it is not checked.

    Parameters
    ----------
    output : EstimatorOutput
        The answer.
    max_horizontal_speed_mps : float or None
        Bound on a valid answer's horizontal speed (m/s); None: no bound.

    Returns
    -------
    EstimatorOutput
        ``output`` itself.

    Raises
    ------
    ImplausibleOutput
        Naming the check that failed.
    """
    if output.velocity_uncertainty_mps is not None and not (
            math.isfinite(output.velocity_uncertainty_mps) and output.velocity_uncertainty_mps >= 0):
        raise ImplausibleOutput(f"field 'velocity_uncertainty_mps' must be finite and >= 0 when given; "
                                f"got {output.velocity_uncertainty_mps!r}")
    if not output.valid:
        return output
    east, north = output.velocity_east_mps, output.velocity_north_mps
    if east is None or north is None or not (math.isfinite(east) and math.isfinite(north)):
        raise ImplausibleOutput(f"valid velocity must be finite; got ({east!r}, {north!r}) m/s")
    speed = math.hypot(east, north)
    if max_horizontal_speed_mps is not None and not speed < max_horizontal_speed_mps:
        raise ImplausibleOutput(f"horizontal speed {speed:.4g} m/s of a valid answer is not below the bound "
                                f"{max_horizontal_speed_mps:.4g} m/s")
    return output


def read_only(array: Any) -> Any:
    """A read-only view of an ndarray; anything else unchanged.

    Parameters
    ----------
    array : Any
        An ndarray or any other value.

    Returns
    -------
    Any
        A read-only view of the array (writing through it raises ``ValueError: assignment destination
        is read-only``), or ``array`` itself.
    """
    if not isinstance(array, np.ndarray):
        return array
    view = array.view()
    view.setflags(write=False)
    return view


def _read_only_fields(record: Any) -> Any:
    """A copy of a dataclass record whose ndarray fields are read-only views."""
    return replace(record, **{item.name: read_only(getattr(record, item.name)) for item in fields(record)
                              if isinstance(getattr(record, item.name), np.ndarray)})


def read_only_inputs(inputs: EstimatorInputs) -> EstimatorInputs:
    """``inputs`` as every estimator receives them.

    A write into an input then raises inside the estimator and fails only its own result, never another
    estimator's or a later case's.

    Parameters
    ----------
    inputs : EstimatorInputs
        A case's inputs.

    Returns
    -------
    EstimatorInputs
        The images, image times, measurement arrays and flat field as read-only views (no data copied),
        the parameters a deep copy.
    """
    measurements = inputs.measurements
    measurements = replace(measurements, images=tuple(_read_only_fields(image) for image in measurements.images),
                           sun_direction_world=read_only(measurements.sun_direction_world))
    return replace(inputs, images=tuple(read_only(image) for image in inputs.images),
                   image_times_s=read_only(inputs.image_times_s), measurements=measurements,
                   calibration=replace(inputs.calibration, flat_field=read_only(inputs.calibration.flat_field)),
                   parameters=copy.deepcopy(dict(inputs.parameters)))
