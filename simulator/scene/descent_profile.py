"""Descent profile: the time-tagged lander state along an EDL trajectory, and poses at any time.

Frames and quaternion conventions are those of :mod:`flight_interface.frames` (world: x east, y north,
z up from the ground plane; attitude: body-to-world quaternion ``(w, x, y, z)``).

Image timing: ``image_times_s[k]`` is the *start of the exposure* of image k. The fast flush occupies
``[t - T_flush, t]``, the exposure ``[t, t + T_exp]`` and the frame transfer
``[t + T_exp, t + T_exp + T_transfer]`` (durations from the camera's :class:`~flight_interface.camera_file.Timing`).
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from functools import cached_property
from typing import NamedTuple

import numpy as np

from flight_interface.frames import (
    quat_from_axis_angle,
    quat_multiply,
    quat_normalize,
)


def unit_quat(quaternion: Sequence[float]) -> list[float]:
    """:func:`flight_interface.frames.quat_normalize` of one quaternion, in scalar arithmetic.

    Parameters
    ----------
    quaternion : sequence of 4 float
        (w, x, y, z), finite, non-zero.

    Returns
    -------
    list of 4 float
        The unit quaternion with w >= 0.
    """
    w, x, y, z = map(float, quaternion)
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not (norm > 0 and math.isfinite(norm)):
        raise ValueError(f"quaternion (w, x, y, z) must be finite with a non-zero norm; got {quaternion!r}")
    sign = -1.0 if w / norm < 0 else 1.0
    return [sign * w / norm, sign * x / norm, sign * y / norm, sign * z / norm]


def scalar_slerp(q0: Sequence[float], q1: Sequence[float], fraction: float) -> list[float]:
    """:func:`flight_interface.frames.slerp` of two quaternions, in scalar arithmetic.

    Parameters
    ----------
    q0, q1 : sequence of 4 floats
        Unit quaternions (w, x, y, z) at the ends.
    fraction : float
        Where between them, 0 .. 1.

    Returns
    -------
    list of 4 floats
        The unit quaternion (w >= 0).
    """
    return _slerp_between(_slerp_ends(q0, q1), fraction)


def _slerp_ends(q0: Sequence[float], q1: Sequence[float]) -> tuple[list[float], list[float], float, float]:
    """:func:`scalar_slerp`'s part that does not depend on the fraction (kept per profile interval).

    The unit ends (the second on the first's hemisphere), the angle between them and its sine.
    """
    start, end = unit_quat(q0), unit_quat(q1)
    dot = sum(a * b for a, b in zip(start, end))
    if dot < 0:
        end = [-value for value in end]
    theta = math.acos(min(max(abs(dot), -1.0), 1.0))
    return start, end, theta, math.sin(theta)


def _slerp_between(ends: tuple[list[float], list[float], float, float], fraction: float) -> list[float]:
    """:func:`scalar_slerp` at ``fraction`` from its :func:`_slerp_ends`."""
    start, end, theta, sin_theta = ends
    if sin_theta < 1e-9:
        w0, w1 = 1.0 - fraction, fraction
    else:
        w0, w1 = math.sin((1.0 - fraction) * theta) / sin_theta, math.sin(fraction * theta) / sin_theta
    return unit_quat([w0 * a + w1 * b for a, b in zip(start, end)])


@dataclass(frozen=True)
class Pose:
    """Lander state at one instant.

    Attributes
    ----------
    time_s : float
        Time (s).
    position_m : ndarray, shape (3,)
        World position of the lander body origin (m).
    velocity_mps : ndarray, shape (3,)
        World velocity (m/s).
    attitude_quat : ndarray, shape (4,)
        Body-to-world unit quaternion (w, x, y, z).
    angular_rate_radps : ndarray, shape (3,)
        Body-frame angular rate (rad/s).
    heat_shield_position_m : ndarray, shape (3,), or None
        World position of the heat shield centre (m), None when not tracked.
    """

    time_s: float
    position_m: np.ndarray          # (3,) world
    velocity_mps: np.ndarray        # (3,) world
    attitude_quat: np.ndarray       # (4,) body-to-world
    angular_rate_radps: np.ndarray  # (3,) body frame
    heat_shield_position_m: np.ndarray | None = None  # (3,) world, None when not tracked


class _Interval(NamedTuple):
    """Two consecutive profile samples as floats, what every pose between them reads (:meth:`DescentProfile._interval`)."""

    step_s: float                                   # time between the samples (s)
    position0_m: list[float]
    position1_m: list[float]
    velocity0_mps: list[float]
    velocity1_mps: list[float]
    rate0_radps: list[float]                        # body rates
    rate1_radps: list[float]
    heat_shield_m: tuple[list[float], list[float]] | None    # the heat shield's positions, when the profile has them
    attitude_ends: tuple[list[float], list[float], float, float]   # the attitude slerp's fixed part (_slerp_ends)


@dataclass(frozen=True)
class DescentProfile:
    """Time-tagged lander states (N samples, strictly increasing time).

    Attributes
    ----------
    time_s : (N,)
    position_m : (N, 3) world position of the lander body origin; z is the altitude above ground
    velocity_mps : (N, 3) world velocity
    attitude_quat : (N, 4) body-to-world unit quaternions
    angular_rate_radps : (N, 3) body-frame angular rate
    wind_mps : (N, 3) steady-state wind in the world frame (truth)
    heat_shield_position_m : (N, 3) or None, world position of the heat shield centre
    image_times_s : (K,) start-of-exposure times of the descent images
    name : str
    """

    time_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    attitude_quat: np.ndarray
    angular_rate_radps: np.ndarray
    wind_mps: np.ndarray
    heat_shield_position_m: np.ndarray | None
    image_times_s: np.ndarray
    name: str = "profile"

    def __post_init__(self):
        count = len(self.time_s)
        if count < 2:
            raise ValueError(f"profile {self.name}: needs at least 2 samples; got {count}")
        if not np.all(np.diff(self.time_s) > 0):
            raise ValueError(f"profile {self.name}: time_s must be strictly increasing")
        for label in ("position_m", "velocity_mps", "angular_rate_radps", "wind_mps"):
            if np.shape(getattr(self, label)) != (count, 3):
                raise ValueError(f"profile {self.name}: {label} must have shape ({count}, 3)")
        if np.shape(self.attitude_quat) != (count, 4):
            raise ValueError(f"profile {self.name}: attitude_quat must have shape ({count}, 4)")
        if self.heat_shield_position_m is not None and np.shape(self.heat_shield_position_m) != (count, 3):
            raise ValueError(f"profile {self.name}: heat_shield_position_m must have shape ({count}, 3)")

    @cached_property
    def _sample_times(self) -> list[float]:
        """:attr:`time_s` as floats (s)."""
        return self.time_s.tolist()

    @cached_property
    def _intervals(self) -> dict[int, _Interval]:
        """Per sample interval, what every pose in it reads (:meth:`_interval`), filled as poses are asked for."""
        return {}

    def _interval(self, index: int) -> _Interval:
        """The samples ``index`` and ``index + 1`` as floats (:class:`_Interval`), read once per interval.

        The poses of one image fall in one or two intervals: each interval's values are read from the arrays
        and normalised once (the same values every time).
        """
        found = self._intervals.get(index)
        if found is None:
            times, shield = self._sample_times, self.heat_shield_position_m
            found = self._intervals[index] = _Interval(
                times[index + 1] - times[index],
                self.position_m[index].tolist(), self.position_m[index + 1].tolist(),
                self.velocity_mps[index].tolist(), self.velocity_mps[index + 1].tolist(),
                self.angular_rate_radps[index].tolist(), self.angular_rate_radps[index + 1].tolist(),
                None if shield is None else (shield[index].tolist(), shield[index + 1].tolist()),
                _slerp_ends(self.attitude_quat[index].tolist(), self.attitude_quat[index + 1].tolist()))
        return found

    def _locate(self, time_s: float) -> tuple[int, float]:
        times = self._sample_times
        time_s = float(time_s)
        first, last = times[0], times[-1]
        if not (first <= time_s <= last):
            raise ValueError(f"profile {self.name}: time {time_s:.4f} s outside [{first:.4f}, {last:.4f}] s")
        index = min(max(bisect.bisect_right(times, time_s) - 1, 0), len(times) - 2)
        start = times[index]
        return index, (time_s - start) / (times[index + 1] - start)

    def pose(self, time_s: float) -> Pose:
        """Lander state at a time: linear interpolation of vectors, slerp of attitude.

        Position uses cubic Hermite interpolation with the sampled velocities, so a profile sampled
        coarsely still moves consistently with its own velocity. Scalar arithmetic on the two samples
        around ``time_s`` (a pose is a handful of numbers: numpy's per-call cost would be most of it).

        Parameters
        ----------
        time_s : float
            Time (s), within the profile's span.

        Returns
        -------
        Pose
            The interpolated state.
        """
        index, fraction = self._locate(time_s)
        attitude, rate = self._attitude_and_rate(index, fraction)
        return self._pose_with(time_s, index, fraction, np.array(attitude), np.array(rate))

    def _attitude_and_rate(self, index: int, fraction: float) -> tuple[list[float], list[float]]:
        """The slerped attitude quaternion and the interpolated body rate, as floats (:meth:`pose`).

        Between samples ``index`` and ``index + 1`` at ``fraction`` (:meth:`_locate`).
        """
        interval = self._interval(index)
        rate = [(1.0 - fraction) * a + fraction * b for a, b in zip(interval.rate0_radps, interval.rate1_radps)]
        return _slerp_between(interval.attitude_ends, fraction), rate

    def _pose_with(self, time_s: float, index: int, fraction: float, attitude_quat: np.ndarray,
                   angular_rate_radps: np.ndarray) -> Pose:
        """:meth:`pose` at ``time_s`` (located at ``index``, ``fraction``) with the given attitude and body rate."""
        interval = self._interval(index)
        step, shield = interval.step_s, interval.heat_shield_m
        p0, p1, v0, v1 = interval.position0_m, interval.position1_m, interval.velocity0_mps, interval.velocity1_mps
        s = fraction
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        position = [h00 * a + h10 * step * b + h01 * c + h11 * step * d for a, b, c, d in zip(p0, v0, p1, v1)]
        return Pose(
            time_s=float(time_s),
            position_m=np.array(position),
            velocity_mps=np.array([(1.0 - fraction) * a + fraction * b for a, b in zip(v0, v1)]),
            attitude_quat=attitude_quat,
            angular_rate_radps=angular_rate_radps,
            heat_shield_position_m=None if shield is None else np.array(
                [(1.0 - fraction) * a + fraction * b for a, b in zip(*shield)]),
        )

    def wind_at(self, time_s: float) -> np.ndarray:
        """Steady-state wind at a time.

        Parameters
        ----------
        time_s : float
            Time (s).

        Returns
        -------
        ndarray, shape (3,)
            World wind (m/s).
        """
        index, fraction = self._locate(time_s)
        return (1.0 - fraction) * self.wind_mps[index] + fraction * self.wind_mps[index + 1]

    def translated(self, offset_m: np.ndarray, name: str | None = None) -> DescentProfile:
        """The same profile moved horizontally: a placement on a terrain.

        Parameters
        ----------
        offset_m : ndarray, shape (2,)
            East, north offset (m).
        name : str, optional
            Name of the new profile (default: the same).

        Returns
        -------
        DescentProfile
            The moved profile.
        """
        shift = np.array([offset_m[0], offset_m[1], 0.0])
        return DescentProfile(
            time_s=self.time_s, position_m=self.position_m + shift, velocity_mps=self.velocity_mps,
            attitude_quat=self.attitude_quat, angular_rate_radps=self.angular_rate_radps, wind_mps=self.wind_mps,
            heat_shield_position_m=None if self.heat_shield_position_m is None else self.heat_shield_position_m + shift,
            image_times_s=self.image_times_s, name=name or self.name,
        )


    def placed(self, heading_rad: float, offset_m: np.ndarray, name: str | None = None) -> DescentProfile:
        """The profile turned about the world vertical through the origin, then moved horizontally.

        Positions, velocities, winds, attitudes and the heat shield turn together, so the trajectory is the
        same flight in another direction; the sun does not turn.

        Parameters
        ----------
        heading_rad : float
            Turn (rad), right-handed about +z: counter-clockwise seen from above.
        offset_m : ndarray, shape (2,)
            East, north offset after the turn (m).
        name : str, optional
            Name of the new profile (default: the same).

        Returns
        -------
        DescentProfile
            The placed profile.
        """
        turn = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), heading_rad)
        cos_h, sin_h = np.cos(heading_rad), np.sin(heading_rad)
        matrix = np.array([[cos_h, -sin_h, 0.0], [sin_h, cos_h, 0.0], [0.0, 0.0, 1.0]])
        shift = np.array([offset_m[0], offset_m[1], 0.0])
        return DescentProfile(
            time_s=self.time_s, position_m=self.position_m @ matrix.T + shift,
            velocity_mps=self.velocity_mps @ matrix.T,
            attitude_quat=quat_normalize(quat_multiply(turn, self.attitude_quat)),
            angular_rate_radps=self.angular_rate_radps, wind_mps=self.wind_mps @ matrix.T,
            heat_shield_position_m=(None if self.heat_shield_position_m is None
                                    else self.heat_shield_position_m @ matrix.T + shift),
            image_times_s=self.image_times_s, name=name or self.name,
        )


def constant_velocity_profile(start_position_m, velocity_mps, attitude_quat, duration_s: float,
                              image_times_s, wind_mps=(0.0, 0.0, 0.0),
                              samples: int = 2, name: str = "constant") -> DescentProfile:
    """A straight-line profile with fixed attitude (for tests and examples).

    Parameters
    ----------
    start_position_m : array_like, shape (3,)
        World position at time 0 (m).
    velocity_mps : array_like, shape (3,)
        World velocity (m/s).
    attitude_quat : array_like, shape (4,)
        Body-to-world quaternion.
    duration_s : float
        Length of the profile (s).
    image_times_s : array_like, shape (K,)
        Start-of-exposure times of the images (s).
    wind_mps : array_like, shape (3,), optional
        Steady wind (m/s).
    samples : int, optional
        Number of time samples.
    name : str, optional
        Profile name.

    Returns
    -------
    DescentProfile
        The profile.
    """
    time = np.linspace(0.0, duration_s, samples)
    velocity = np.asarray(velocity_mps, dtype=float)
    position = np.asarray(start_position_m, dtype=float) + time[:, None] * velocity
    return DescentProfile(
        time_s=time, position_m=position, velocity_mps=np.tile(velocity, (samples, 1)),
        attitude_quat=np.tile(quat_normalize(attitude_quat), (samples, 1)),
        angular_rate_radps=np.zeros((samples, 3)),
        wind_mps=np.tile(np.asarray(wind_mps, dtype=float), (samples, 1)),
        heat_shield_position_m=None, image_times_s=np.asarray(image_times_s, dtype=float), name=name,
    )


@dataclass(frozen=True)
class RateScaledProfile(DescentProfile):
    """A profile whose rotation about ``rate_centre_s`` runs ``rate_multiplier`` times faster.

    Off-nominal "high motion blur"; positions, velocities and the heat shield are unchanged.
    Attitude: ``q'(t) = q(tc) * exp(k * log(q(tc)^-1 q(t)))`` with ``tc = rate_centre_s`` and
    ``k = rate_multiplier``, so the attitude at ``tc`` is unchanged and the rotation relative to it is
    scaled by ``k`` (exactly ``k`` times the angle for rotation about a fixed body axis). The body
    angular rate reported is ``k`` times the profile's. Valid near ``tc`` (one image's flush, exposure
    and transfer): far from it the scaled relative rotation can exceed half a turn and wrap.
    Use :func:`scale_angular_rates` to build one; ``translated``/``placed`` return an unscaled profile.

    Attributes
    ----------
    rate_multiplier : float
        ``k``.
    rate_centre_s : float
        ``tc`` (s).
    """

    rate_multiplier: float = 1.0
    rate_centre_s: float = 0.0

    @cached_property
    def _centre_attitude(self) -> np.ndarray:
        """Attitude at the (clamped) rate centre: the same for every pose of this profile."""
        return DescentProfile.pose(self, float(np.clip(self.rate_centre_s, self.time_s[0], self.time_s[-1]))).attitude_quat

    @cached_property
    def _centre_attitude_values(self) -> list[float]:
        """:attr:`_centre_attitude` as floats."""
        return self._centre_attitude.tolist()

    def pose(self, time_s: float) -> Pose:
        """Lander state at a time, with the rotation about ``rate_centre_s`` scaled.

        Parameters
        ----------
        time_s : float
            Time (s).

        Returns
        -------
        Pose
            The state (angular rate times ``rate_multiplier``).
        """
        index, fraction = self._locate(time_s)
        (bw, bx, by, bz), rate = self._attitude_and_rate(index, fraction)
        # scalar arithmetic (a pose is a handful of numbers; the motion-blur checks ask for ~30 per image):
        # quat_to_rotation_vector(conj(c) * q), scaled by k, quat_from_rotation_vector, c * that, normalised
        cw, cx, cy, cz = self._centre_attitude_values
        rw, rx, ry, rz = unit_quat([cw * bw + cx * bx + cy * by + cz * bz, cw * bx - cx * bw - cy * bz + cz * by,
                                    cw * by + cx * bz - cy * bw - cz * bx, cw * bz - cx * by + cy * bx - cz * bw])
        sin_half = math.sqrt(rx * rx + ry * ry + rz * rz)
        to_vector = 2.0 * math.atan2(sin_half, rw) / sin_half if sin_half > 1e-12 else 2.0
        vx, vy, vz = (self.rate_multiplier * to_vector * value for value in (rx, ry, rz))
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        half = 0.5 * angle
        to_quat = math.sin(half) / angle if angle > 1e-8 else 0.5 - angle ** 2 / 48.0
        ew, ex, ey, ez = math.cos(half), to_quat * vx, to_quat * vy, to_quat * vz
        attitude = np.array(unit_quat([cw * ew - cx * ex - cy * ey - cz * ez, cw * ex + cx * ew + cy * ez - cz * ey,
                                       cw * ey - cx * ez + cy * ew + cz * ex, cw * ez + cx * ey - cy * ex + cz * ew]))
        return self._pose_with(time_s, index, fraction, attitude, self.rate_multiplier * np.array(rate))


def scale_angular_rates(profile: DescentProfile, multiplier: float, centre_time_s: float) -> DescentProfile:
    """The profile with its angular rates scaled about a time (see :class:`RateScaledProfile`).

    Parameters
    ----------
    profile : DescentProfile
        The profile.
    multiplier : float
        Rate multiplier ``k``.
    centre_time_s : float
        Time whose attitude is kept (s).

    Returns
    -------
    DescentProfile
        A :class:`RateScaledProfile`, or ``profile`` itself when ``multiplier == 1``.
    """
    if multiplier == 1.0:
        return profile
    if not (np.isfinite(multiplier) and multiplier >= 0):
        raise ValueError(f"angular rate multiplier: must be finite and >= 0; got {multiplier!r}")
    values = {f.name: getattr(profile, f.name) for f in fields(DescentProfile)}
    return RateScaledProfile(**values, rate_multiplier=float(multiplier), rate_centre_s=float(centre_time_s))
