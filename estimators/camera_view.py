"""The camera as an estimator receives it: the design, never the simulator's truth.

A camera TOML carries one field that only the simulator may know: ``radiometry.prnu_seed``, the seed of
the detector's realised pixel response non-uniformity (the true PRNU pattern). A flight estimator knows
the pixel response only through a measured flat field (:mod:`flight_interface.calibration`), so the
seed is withheld (:data:`TRUTH_FIELDS`) from everything an estimator gets:

* python plug-ins: :class:`~estimators.contract.EstimatorInputs` replaces its camera by
  :func:`estimator_camera` (the same camera whose ``radiometry`` has no ``prnu_seed`` attribute);
* command plug-ins: ``{camera}`` is :func:`write_design_camera`'s copy of the camera TOML in the case
  directory, without the withheld fields (:func:`load_design_camera` reads it back, as
  ``python -m estimators.run_python`` does).

``prnu_sigma`` (the datasheet's rms non-uniformity) is a design number and stays.
"""
from __future__ import annotations

import copy
from pathlib import Path

import tomli_w

from config_tables.models import parse
from config_tables.toml_file import load_toml
from flight_interface.camera import Camera, camera_from_file
from flight_interface.camera_file import CameraFile, Radiometry

#: table -> fields of a camera TOML that an estimator never receives (simulator truth).
TRUTH_FIELDS: dict[str, tuple[str, ...]] = {"radiometry": ("prnu_seed",)}
PLACEHOLDER_SEED = 0        # fills a withheld seed only to validate a design file; stripped again at once
_VIEWS: dict[int, tuple[Camera, Camera]] = {}     # id(camera) -> (camera, its estimator view), a few at most
_MAX_VIEWS = 8


def carries_truth(camera: Camera) -> bool:
    """Whether ``camera`` still has a withheld field (a simulator camera, not an estimator's view).

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    bool
        True when a field of :data:`TRUTH_FIELDS` can be read from it.
    """
    return any(hasattr(getattr(camera, table), name) for table, names in TRUTH_FIELDS.items() for name in names)


def estimator_camera(camera: Camera) -> Camera:
    """``camera`` without the withheld fields.

    One view per camera object is kept, so the cached derived arrays (rays, falloff) are computed once
    per process.

    Parameters
    ----------
    camera : Camera
        A camera, with or without the withheld fields.

    Returns
    -------
    Camera
        ``camera`` itself if it has none; else a shallow copy (the same read-only arrays) whose
        ``radiometry`` is a :class:`~flight_interface.camera_file.Radiometry` lacking ``prnu_seed``
        (reading it raises AttributeError; ``model_dump()`` leaves it out).
    """
    if not carries_truth(camera):
        return camera
    cached = _VIEWS.get(id(camera))
    if cached is not None and cached[0] is camera:
        return cached[1]
    design = {name: value for name, value in camera.radiometry.model_dump().items()
              if name not in TRUTH_FIELDS["radiometry"]}
    view = copy.copy(camera)
    object.__setattr__(view, "radiometry", Radiometry.model_construct(**design))
    if len(_VIEWS) >= _MAX_VIEWS:
        _VIEWS.clear()
    _VIEWS[id(camera)] = (camera, view)
    return view


def design_tables(camera_path: str | Path) -> dict:
    """The camera TOML's tables without the withheld fields.

    Parameters
    ----------
    camera_path : str or Path
        The camera TOML.

    Returns
    -------
    dict
        Its parsed tables, less :data:`TRUTH_FIELDS`.
    """
    data = load_toml(Path(camera_path))
    for table, names in TRUTH_FIELDS.items():
        if isinstance(data.get(table), dict):
            data[table] = {key: value for key, value in data[table].items() if key not in names}
    return data


def write_design_camera(path: Path, camera: Camera) -> Path:
    """Write the TOML of ``camera`` (read from ``camera.source``) without the withheld fields.

    Parameters
    ----------
    path : Path
        The file to write.
    camera : Camera
        The camera; its ``source`` is the camera TOML read.

    Returns
    -------
    Path
        ``path``.
    """
    path.write_text(toml_text(design_tables(camera.source)))
    return path


def load_design_camera(path: str | Path) -> Camera:
    """Load a camera TOML for an estimator, with or without the withheld fields.

    Withheld fields absent from the file get stand-in values so that the camera schema validates; the
    returned camera is stripped of them again, so no stand-in reaches the estimator.

    Parameters
    ----------
    path : str or Path
        The camera TOML.

    Returns
    -------
    Camera
        The camera, without the withheld fields (:func:`estimator_camera`).

    Raises
    ------
    ConfigError
        One line naming the file and field, like :func:`flight_interface.camera.load_camera`.
    """
    data = load_toml(Path(path))
    if isinstance(data.get("radiometry"), dict):
        data["radiometry"] = {"prnu_seed": PLACEHOLDER_SEED, **data["radiometry"]}
    return estimator_camera(camera_from_file(parse(CameraFile, data, str(path)), str(path)))


def toml_text(tables: dict) -> str:
    """A TOML document of ``tables``.

    Parameters
    ----------
    tables : dict
        Table -> key -> number, bool, string, list of those, or a sub-table.

    Returns
    -------
    str
        The TOML text.
    """
    return tomli_w.dumps(tables)
