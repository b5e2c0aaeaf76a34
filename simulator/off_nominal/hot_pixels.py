"""Hot pixels ("dark spikes"): a sparse set of image-area pixels with a large extra dark current.

Model (units e-/s per pixel):

* Which pixels: each of the ``H * W`` image-area pixels is hot independently with probability
  ``hot_pixel_fraction``; the count is drawn as Binomial(H W, fraction) and the positions uniformly
  without replacement (the same distribution).
* Amplitude: an extra dark generation rate drawn from an exponential distribution with mean
  ``hot_pixel_amplitude_mean_e_per_s`` *at the camera's dark reference temperature*; it follows the
  same doubling rule as the ordinary dark current (:meth:`Electronics.dark_current_e_per_s`)::

      D_hot(T) = D_hot,ref * 2 ** ((T - T_ref) / T_double)

* Where it acts: the rate is added to the pixel's generation rate in all three CCD periods, so a hot
  pixel also smears along its column during fast flush and frame transfer, exactly as a bright
  scene pixel would. Defects of the storage area are not modelled. Hot pixels are a fixed defect
  of the case (the same in the three images) and are independent of the ``dark_current`` switch
  and ``dark_current_scale``.

Cost: a sparse add of ``count`` values per generation-rate map; nothing full-frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flight_interface.camera import Camera


@dataclass(frozen=True)
class HotPixels:
    """The hot pixels of a case.

    Attributes
    ----------
    flat_index : ndarray, shape (n,), int64
        Index into the (H, W) image area (row-major, sorted).
    rate_e_per_s : ndarray, shape (n,), float32
        Extra dark rate at the camera's CCD temperature (e-/s).
    """

    flat_index: np.ndarray
    rate_e_per_s: np.ndarray


def temperature_factor(camera: Camera) -> float:
    """Dark-rate multiplier from the reference temperature to the CCD temperature (doubling rule).

    Parameters
    ----------
    camera : Camera
        The camera (its electronics).

    Returns
    -------
    float
        The multiplier.
    """
    electronics = camera.electronics
    return float(2.0 ** ((electronics.ccd_temperature_k - electronics.dark_reference_temperature_k)
                         / electronics.dark_doubling_temperature_k))


def draw_hot_pixels(camera: Camera, rng: np.random.Generator, fraction: float,
                    amplitude_mean_e_per_s: float) -> HotPixels:
    """Draw the hot pixels of one case (module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    rng : numpy.random.Generator
        The case's hot-pixel stream.
    fraction : float
        Probability of a pixel being hot.
    amplitude_mean_e_per_s : float
        Mean extra dark rate at the reference temperature (e-/s).

    Returns
    -------
    HotPixels
        The hot pixels.
    """
    pixels = camera.height_px * camera.width_px
    count = int(rng.binomial(pixels, fraction))
    flat_index = np.sort(rng.choice(pixels, size=count, replace=False)).astype(np.int64)
    rate = rng.exponential(amplitude_mean_e_per_s, size=count) * temperature_factor(camera)
    return HotPixels(flat_index, rate.astype(np.float32))


def add_to_rate(rate_e_per_s: np.ndarray, hot: HotPixels) -> np.ndarray:
    """Add the hot pixels' dark rate to a generation-rate map in place.

    Parameters
    ----------
    rate_e_per_s : ndarray, shape (H, W), float32
        Generation rate (e-/s); changed in place.
    hot : HotPixels
        The hot pixels.

    Returns
    -------
    ndarray, shape (H, W)
        ``rate_e_per_s``.
    """
    flat = rate_e_per_s.reshape(-1)
    if not np.shares_memory(flat, rate_e_per_s):   # not contiguous: index in 2-D instead
        rows, cols = np.divmod(hot.flat_index, rate_e_per_s.shape[1])
        rate_e_per_s[rows, cols] += hot.rate_e_per_s
        return rate_e_per_s
    flat[hot.flat_index] += hot.rate_e_per_s     # indices are unique
    return rate_e_per_s


def add_to_block_rate(block_rate_e_per_s: np.ndarray, hot: HotPixels, binning_rows: int) -> np.ndarray:
    """Add the hot pixels' dark rate to a rate given per binning block in place.

    Each hot pixel adds ``rate / b`` to its block's mean.

    Parameters
    ----------
    block_rate_e_per_s : ndarray, shape (H / b, W), float32
        Mean generation rate of each block (e-/s); changed in place.
    hot : HotPixels
        The hot pixels.
    binning_rows : int
        Rows per block ``b``.

    Returns
    -------
    ndarray, shape (H / b, W)
        ``block_rate_e_per_s``.
    """
    rows, cols = np.divmod(hot.flat_index, block_rate_e_per_s.shape[1])
    np.add.at(block_rate_e_per_s, (rows // binning_rows, cols), hot.rate_e_per_s / np.float32(binning_rows))
    return block_rate_e_per_s
