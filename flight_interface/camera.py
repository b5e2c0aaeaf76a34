"""The runtime camera: a validated camera file (:mod:`flight_interface.camera_file`) as a frozen
:class:`Camera`, with the CAHVOR model and mounting as arrays and the per-pixel rays, field angles and
design falloff derived from them (computed once, read-only, shared by the simulator and the estimators).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from flight_interface import cahvor
from flight_interface.camera_file import CameraFile, Detector, Electronics, Optics, Radiometry, Timing
from flight_interface.frames import quat_normalize, quat_to_matrix
from flight_interface.tomlfields import load


@dataclass(frozen=True)
class Camera:
    """A descent camera: the validated file tables plus the CAHVOR model in the camera frame and the
    mounting on the lander (arrays)."""

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
        return self.detector.width_px

    @property
    def height_px(self) -> int:
        return self.detector.height_px

    @property
    def pixel_pitch_m(self) -> float:
        return self.detector.pixel_pitch_m

    @property
    def binning_rows(self) -> int:
        return self.detector.binning_rows

    @property
    def binned_shape(self) -> tuple[int, int]:
        """(rows, columns) of the read-out image."""
        return self.height_px // self.binning_rows, self.width_px

    @property
    def camera_to_lander_matrix(self) -> np.ndarray:
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
        """Pickle the camera as designed: the derived arrays of the cached properties below (tens of MiB)
        are left out and recomputed, bit for bit, where they are next needed."""
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
        measured flat field (:mod:`flight_interface.calibration`)."""
        return _read_only((np.cos(self.field_angle_rad) ** 4).astype(np.float32))

    def fov_deg(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view between the outer pixel edges (deg)."""
        return cahvor.field_of_view_deg(self.model, self.width_px, self.height_px)


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array`` itself, read-only (a camera's derived arrays are shared like the camera)."""
    array.setflags(write=False)
    return array


def camera_from_file(tables: CameraFile, source: str) -> Camera:
    """The runtime :class:`Camera` of validated camera tables."""
    return Camera(
        name=tables.camera.name, source=source, detector=tables.detector,
        model=tables.geometry.to_cahvor(tables.detector),
        camera_to_lander_quaternion=quat_normalize(np.array(tables.mounting.camera_to_lander_quaternion)),
        camera_position_in_lander_m=np.array(tables.mounting.camera_position_in_lander_m),
        timing=tables.timing, radiometry=tables.radiometry, electronics=tables.electronics, optics=tables.optics)


def load_camera(path: str | Path) -> Camera:
    """Load and validate a camera TOML file (fields: :class:`CameraFile`).

    Raises
    ------
    ConfigError
        One line naming the file, the field and the allowed values (unknown keys included).
    """
    return camera_from_file(load(CameraFile, path), str(path))


#: The cached properties of :class:`Camera` that a pickle leaves out (see ``Camera.__getstate__``).
_DERIVED_PROPERTIES = frozenset(("pixel_rays", "field_angle_rad", "falloff_map"))
