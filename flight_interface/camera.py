"""The runtime camera: a validated camera file as a frozen :class:`Camera`.

The file's tables are declared in :mod:`flight_interface.camera_file`. A :class:`Camera` holds them with
the CAHVOR model and mounting as arrays, and derives the per-pixel rays, field angles and design falloff
(computed once, read-only, shared by the simulator and the estimators).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from config_tables.models import load
from flight_interface import cahvor
from flight_interface.camera_file import CameraFile, Detector, Electronics, Optics, Radiometry, Timing
from flight_interface.frames import quat_normalize, quat_to_matrix


@dataclass(frozen=True)
class Camera:
    """A descent camera: the validated file tables, the CAHVOR model and the mounting (arrays).

    Parameters
    ----------
    name : str
        Human-readable camera name (``[camera] name``).
    source : str
        The camera file's path (or another description of where the camera came from).
    detector : Detector
        The CCD array and its on-chip binning.
    model : Cahvor
        CAHVOR model in the camera frame.
    camera_to_lander_quaternion : ndarray, shape (4,)
        Camera-to-lander rotation, unit quaternion (w, x, y, z); read-only.
    camera_position_in_lander_m : ndarray, shape (3,)
        Camera position in the lander body frame (m); read-only.
    timing : Timing
        Frame-transfer CCD timing (s).
    radiometry : Radiometry
        Optics and CCD photo response.
    electronics : Electronics
        Dark current, wells and ADC.
    optics : Optics, optional
        The point-spread function of the optics.
    """

    name: str
    source: str
    detector: Detector
    model: cahvor.Cahvor
    camera_to_lander_quaternion: np.ndarray
    camera_position_in_lander_m: np.ndarray
    timing: Timing
    radiometry: Radiometry
    electronics: Electronics
    optics: Optics = Optics()

    @property
    def width_px(self) -> int:
        """Columns of the array (px)."""
        return self.detector.width_px

    @property
    def height_px(self) -> int:
        """Rows of the array, before binning (px)."""
        return self.detector.height_px

    @property
    def pixel_pitch_m(self) -> float:
        """Pixel pitch (m)."""
        return self.detector.pixel_pitch_m

    @property
    def binning_rows(self) -> int:
        """Rows summed on chip."""
        return self.detector.binning_rows

    @property
    def binned_shape(self) -> tuple[int, int]:
        """(rows, columns) of the read-out image."""
        return self.height_px // self.binning_rows, self.width_px

    @property
    def camera_to_lander_matrix(self) -> np.ndarray:
        """Camera-to-lander rotation matrix, shape (3, 3)."""
        return quat_to_matrix(self.camera_to_lander_quaternion)

    @property
    def responsivity_e_per_s(self) -> float:
        """On-axis photo-electrons per second per unit spectral radiance (W m^-2 sr^-1 um^-1)."""
        return self.radiometry.responsivity_e_per_s(self.pixel_pitch_m**2)

    def __post_init__(self) -> None:
        # shared by the simulator and every estimator of a process: no one may change it for the others
        for value in (*vars(self).values(), *vars(self.model).values()):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    def __getstate__(self) -> dict[str, object]:
        """Pickle the camera as designed.

        The derived arrays of the cached properties below (tens of MiB) are left out and recomputed, bit for bit,
        where they are next needed.
        """
        return {name: value for name, value in self.__dict__.items() if name not in _DERIVED_PROPERTIES}

    @cached_property
    def pixel_rays(self) -> np.ndarray:
        """Unit ray of every pixel centre in the camera frame, shape (height, width, 3), float64."""
        return _read_only(cahvor.unproject(self.model, cahvor.pixel_grid(self.width_px, self.height_px)))

    @cached_property
    def field_angle_rad(self) -> np.ndarray:
        """Angle of each pixel's ray from the optical axis O, shape (height, width)."""
        return _read_only(np.arccos(np.clip(self.pixel_rays @ self.model.o, -1.0, 1.0)))

    @cached_property
    def falloff_map(self) -> np.ndarray:
        """Design relative illumination: cos^4 of the field angle, shape (height, width), float32.

        A property of the optics as designed (an estimator may use it when it has no flat field); the
        pixel response non-uniformity is realised only by the simulator
        (:func:`simulator.detector.charge_generation.prnu_map`) and reaches an estimator only through a
        measured flat field (:mod:`flight_interface.calibration`).
        """
        return _read_only((np.cos(self.field_angle_rad) ** 4).astype(np.float32))

    def fov_deg(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view between the outer pixel edges.

        Returns
        -------
        tuple of float
            Horizontal and vertical field of view (deg).
        """
        return cahvor.field_of_view_deg(self.model, self.width_px, self.height_px)


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array`` itself, read-only (a camera's derived arrays are shared like the camera)."""
    array.setflags(write=False)
    return array


def camera_from_file(tables: CameraFile, source: str) -> Camera:
    """The runtime :class:`Camera` of validated camera tables.

    Parameters
    ----------
    tables : CameraFile
        The validated tables of a camera file.
    source : str
        Where they came from (the file's path), kept as ``Camera.source``.

    Returns
    -------
    Camera
        The camera, its quaternion normalised.
    """
    return Camera(
        name=tables.camera.name, source=source, detector=tables.detector,
        model=tables.geometry.to_cahvor(tables.detector),
        camera_to_lander_quaternion=quat_normalize(np.array(tables.mounting.camera_to_lander_quaternion)),
        camera_position_in_lander_m=np.array(tables.mounting.camera_position_in_lander_m),
        timing=tables.timing, radiometry=tables.radiometry, electronics=tables.electronics, optics=tables.optics)


def load_camera(path: str | Path) -> Camera:
    """Load and validate a camera TOML file (fields: :class:`~flight_interface.camera_file.CameraFile`).

    Parameters
    ----------
    path : str or Path
        The camera file.

    Returns
    -------
    Camera
        The camera, ``source`` the path as given.

    Raises
    ------
    ConfigError
        One line naming the file, the field and the allowed values (unknown keys included).
    """
    return camera_from_file(load(CameraFile, path), str(path))


#: The cached properties of :class:`Camera` that a pickle leaves out (see ``Camera.__getstate__``).
_DERIVED_PROPERTIES = frozenset(("pixel_rays", "field_angle_rad", "falloff_map"))
