"""Field types shared by the scene and detector stages: radiance per CCD period, and row-block means.

The scene stage (:mod:`simulator.scene`) produces :class:`RadianceFields`; the detector stage
(:mod:`simulator.detector`) turns them into DN. Both sides import this module, neither imports the other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RadianceFields:
    """Radiance seen by each pixel, averaged over each CCD period.

    Parameters
    ----------
    flush, exposure, transfer : ndarray, shape (height, width) or (height / b, width), float32
        Radiance (W m^-2 sr^-1 um^-1) during the fast flush, the exposure and the frame transfer; a
        field given per binning block holds each block's mean. One array may stand for several periods.
    """

    flush: np.ndarray
    exposure: np.ndarray
    transfer: np.ndarray


def bin_rows(charge_e: np.ndarray, binning_rows: int) -> np.ndarray:
    """Sum charge over blocks of ``binning_rows`` rows (on-chip binning in the serial register).

    Parameters
    ----------
    charge_e : ndarray, shape (N, W)
        Charge per pixel (e-).
    binning_rows : int
        Rows per block ``b``; divides N.

    Returns
    -------
    ndarray, shape (N / b, W)
        Charge per binned pixel (e-), the dtype of ``charge_e``.
    """
    rows, width = charge_e.shape
    return charge_e.reshape(rows // binning_rows, binning_rows, width).sum(axis=1)


def block_means(values: np.ndarray, binning_rows: int) -> np.ndarray:
    """Mean of each ``binning_rows``-row block.

    The per-block form of a rate or field that the smear only sees through block sums.

    Parameters
    ----------
    values : ndarray, shape (N, W)
        Per-pixel values (a rate, a radiance, a gain).
    binning_rows : int
        Rows per block ``b``; divides N.

    Returns
    -------
    ndarray, shape (N / b, W)
        Block means, in the units of ``values``.
    """
    return bin_rows(values, binning_rows) / np.float32(binning_rows)
