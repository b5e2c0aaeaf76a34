"""Terrain: an orbital reflectance image (I/F) on a level ground grid.

With the photometric geometry under which the orbiter observed it.

Grid convention: the image is north-up. Pixel ``(row, col)`` has its centre at world coordinates
``x = origin_x_m + col * metres_per_pixel`` (east) and ``y = origin_y_m - row * metres_per_pixel``
(north); the ground is the plane z = 0 of the local level frame (see :mod:`flight_interface.frames`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Terrain:
    """An orbital terrain image.

    Attributes
    ----------
    reflectance_if : ndarray, float32, shape (rows, cols)
        I/F as measured by the orbiter (MOC), including its haze and grain.
    metres_per_pixel : float
        Ground sampling of the image (m).
    origin_m : ndarray, shape (2,)
        World (east, north) coordinates of the centre of pixel (0, 0), m.
    moc_incidence_rad, moc_emission_rad, moc_phase_rad : float
        Photometric geometry of the orbital observation (rad).
    name : str
    """

    reflectance_if: np.ndarray
    metres_per_pixel: float
    origin_m: np.ndarray
    moc_incidence_rad: float
    moc_emission_rad: float
    moc_phase_rad: float
    name: str = "terrain"

    def __post_init__(self):
        if self.reflectance_if.ndim != 2:
            raise ValueError(f"terrain {self.name}: reflectance_if must be 2-D; got shape {self.reflectance_if.shape}")
        if not self.metres_per_pixel > 0:
            raise ValueError(f"terrain {self.name}: metres_per_pixel must be > 0; got {self.metres_per_pixel}")

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the I/F image."""
        return self.reflectance_if.shape

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(west, east, south, north) bounds of the image's pixel edges, m."""
        rows, cols = self.shape
        half = 0.5 * self.metres_per_pixel
        west = self.origin_m[0] - half
        north = self.origin_m[1] + half
        return west, west + cols * self.metres_per_pixel, north - rows * self.metres_per_pixel, north

    def world_to_pixel(self, east_m: np.ndarray, north_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional image coordinates of world points.

        Parameters
        ----------
        east_m, north_m : ndarray
            World coordinates (m), equal shapes.

        Returns
        -------
        row, col : ndarray
            Fractional image coordinates.
        """
        col = (np.asarray(east_m) - self.origin_m[0]) / self.metres_per_pixel
        row = (self.origin_m[1] - np.asarray(north_m)) / self.metres_per_pixel
        return row, col

    def pixel_to_world(self, row: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates of fractional image coordinates.

        Parameters
        ----------
        row, col : ndarray
            Fractional image coordinates, equal shapes.

        Returns
        -------
        east, north : ndarray
            World coordinates (m).
        """
        east = self.origin_m[0] + np.asarray(col) * self.metres_per_pixel
        north = self.origin_m[1] - np.asarray(row) * self.metres_per_pixel
        return east, north
