"""CCD blooming: charge above a pixel's full well spills along its column, up and down.

Model (charge in electrons, full-resolution pixels, axis 0 is the CCD column direction):

* A pixel holds at most ``full_well_e``; its excess ``e = max(q - full_well, 0)`` leaves it, half
  toward row 0 ("up") and half toward the last row ("down"). The channel stops confine charge to the
  column, so nothing spills sideways.
* Spilled charge fills the next pixel along its direction up to full well, the rest moves on to the
  following pixel, and so on. Charge that passes the first or last row runs off the array (into the
  serial register / storage boundary, where it is lost to the image); :func:`bloom_columns` returns
  that amount so charge is accounted for exactly: ``sum(out) + lost == sum(in)``.
* Order: the up-going flows of a column are resolved first (one pass from the last row to row 0),
  then the down-going flows (row 0 to the last row) fill the capacity that is left. For one
  saturated pixel, or saturated runs farther apart than their spills reach, the result is symmetric;
  where an up flow and a down flow compete for the same pixels, the up flow fills first.

The charge is the pixel charge at the end of frame transfer (the smear of the bright region is
already in it); blooming during the transfer itself is not modelled.

Cost: nothing when no pixel exceeds full well (one comparison); otherwise two row-by-row passes over
only the columns that bloom.
"""
from __future__ import annotations

import numpy as np


def bloom_columns(pixel_e: np.ndarray, full_well_e: float) -> tuple[np.ndarray, float]:
    """Spread the charge above full well along each column (module doc).

    Parameters
    ----------
    pixel_e : (H, W) charge per pixel (e-)
    full_well_e : capacity of one pixel (e-)

    Returns
    -------
    bloomed : (H, W) same dtype, every pixel <= full well
    lost_e : charge that ran off the first or last row (e-)
    """
    full = pixel_e.dtype.type(full_well_e)
    over = pixel_e > full
    columns = np.flatnonzero(over.any(axis=0))
    if columns.size == 0:
        return pixel_e, 0.0
    over_rows = np.flatnonzero(over[:, columns].any(axis=1))
    first_row, last_row = int(over_rows[0]), int(over_rows[-1])
    block = pixel_e[:, columns].astype(np.float64)
    half_excess = 0.5 * np.maximum(block - full_well_e, 0.0)
    block = np.minimum(block, full_well_e)
    capacity = full_well_e - block
    rows = block.shape[0]
    lost = 0.0
    for order, stop_beyond in ((range(last_row, -1, -1), first_row), (range(first_row, rows), last_row)):
        carry = np.zeros(columns.size)
        going_up = order.step < 0
        for row in order:
            fill = np.minimum(carry, capacity[row])
            block[row] += fill
            capacity[row] -= fill
            carry += half_excess[row] - fill
            beyond = row < stop_beyond if going_up else row > stop_beyond
            if beyond and not carry.any():
                break
        lost += float(carry.sum())
    out = pixel_e.copy()
    out[:, columns] = block.astype(pixel_e.dtype)
    return out, lost
