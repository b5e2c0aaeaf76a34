"""Field types shared by the scene and detector stages: radiance per CCD period, and row-block means.

The scene stage (:mod:`simulator.scene`) produces :class:`RadianceFields`; the detector stage
(:mod:`simulator.detector`) turns them into DN. Both sides import this module, neither imports the other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RadianceFields:
    """Radiance seen by each pixel, averaged over each CCD period, W m^-2 sr^-1 um^-1, (height, width)."""

    flush: np.ndarray
    exposure: np.ndarray
    transfer: np.ndarray


def bin_rows(charge_e: np.ndarray, binning_rows: int) -> np.ndarray:
    """Sum charge over blocks of ``binning_rows`` rows (on-chip binning in the serial register)."""
    rows, width = charge_e.shape
    return charge_e.reshape(rows // binning_rows, binning_rows, width).sum(axis=1)


def block_means(values: np.ndarray, binning_rows: int) -> np.ndarray:
    """Mean of each ``binning_rows``-row block, (N, W) -> (N / b, W): the per-block form of a rate or
    field that the smear only sees through block sums."""
    return bin_rows(values, binning_rows) / np.float32(binning_rows)
