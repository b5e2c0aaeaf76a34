"""The velocity error a campaign case cannot avoid: the attitude-knowledge floor (truth side, for reports).

A bias in the measured attitude common to the three images (the paper's absolute attitude bias,
by default 1 deg RMS of the total tilt: simulator/sensors.py) is invisible in the images: every image is projected onto the ground with the
same tilt error ``b``, which moves a ground point seen from altitude ``h`` by ``h tan b``. The
displacement error therefore changes by ``(h_1 - h_3) tan b`` between the first and the last image,
and the horizontal velocity derived from them is off by about

    v_floor = |tan b| (h_1 - h_3) / (t_3 - t_1)

where ``b`` is the horizontal (tilt) part of the bias, ``h_k`` the true altitudes and ``t_k`` the
mid-exposure times of images 1 and 3. No image-based estimator can remove it; a valid case whose
error is close to its floor is limited by the attitude knowledge, not by a wrong match. Measured on
full Gusev and Meridiani campaigns (README): valid errors follow it with slope 0.94-0.98 and a
residual scatter of 0.3-0.4 m/s.
"""
from __future__ import annotations

import math


def attitude_floor_mps(bias_east_rad: float, bias_north_rad: float, altitude_first_m: float,
                       altitude_last_m: float, time_first_s: float, time_last_s: float) -> float:
    """Horizontal velocity error (m/s) caused by an attitude bias common to the images.

    Parameters
    ----------
    bias_east_rad, bias_north_rad : float
        Attitude bias about the east and north axes (rad): the tilt part; a bias about the vertical
        turns the image and does not displace its centre.
    altitude_first_m, altitude_last_m : float
        True altitudes at the first and last image (m).
    time_first_s, time_last_s : float
        Mid-exposure times of the first and last image (s).
    """
    interval_s = time_last_s - time_first_s
    if interval_s <= 0.0:
        raise ValueError(f"the last image ({time_last_s} s) must come after the first ({time_first_s} s)")
    tilt_rad = math.hypot(bias_east_rad, bias_north_rad)
    return abs(math.tan(tilt_rad)) * abs(altitude_first_m - altitude_last_m) / interval_s
