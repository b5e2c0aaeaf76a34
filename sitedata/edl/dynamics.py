"""Equations of motion of a lander hanging on a bridle under a parachute (the ADAMS stand-in's core).

The parachute + backshell is lumped into a *pivot* (the bridle's upper end) that flies at its own
terminal velocity and follows the air with drag time constants; the lander is a point mass on a
massless bridle of length ``L`` below the pivot (a spherical pendulum in the pivot's accelerating
frame) and twists about the bridle axis as a damped torsional oscillator.

Pendulum (per unit lander mass, in the pivot frame, ``r`` = lander minus pivot, ``u = dr/dt``)::

    f     = -g e_z - a_pivot - c u                 (gravity, pseudo-force of the pivot, damping)
    du/dt = f - (f . r_hat) r_hat - (|u|^2 / L) r_hat

which keeps ``|r| = L`` (the bridle tension supplies the radial part). Small-angle period
``T0 = 2 pi sqrt(L / g)``; the swing amplitude decays as ``exp(-c t / 2)``, i.e. damping ratio
``zeta = c / (2 omega0)``.

Attitude: the lander's body z axis points up the bridle (``d = -r / L``); the attitude is the
minimal ("swing") rotation taking world z onto ``d`` followed by a twist ``psi`` about body z::

    q = q_swing(d) * q_z(psi)

so the off-nadir angle is ``acos(d_z)`` and the roll is ``psi`` (the twist angle of the swing-twist
decomposition, ``2 atan2(q_z, q_w)``). All functions are vectorised over a leading batch axis and use
only arithmetic and ``sqrt`` in the integration path, so results are bit-identical whatever the batch.
"""
from __future__ import annotations

import numpy as np

from flight_interface.frames import quat_to_matrix

G_MARS_MPS2 = 3.71  # surface gravity of Mars, m s^-2


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (..., 3) arrays written out (a fixed summation order)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def pendulum_acceleration(relative_position_m: np.ndarray, relative_velocity_mps: np.ndarray,
                          specific_force_mps2: np.ndarray, length_m: np.ndarray | float,
                          damping_per_s: np.ndarray | float) -> np.ndarray:
    """Acceleration of a point mass on a rigid link of length ``length_m`` about a pivot.

    Parameters
    ----------
    relative_position_m, relative_velocity_mps : (M, 3)
        Lander position and velocity relative to the pivot (m, m/s); ``|r| = L``.
    specific_force_mps2 : (M, 3)
        Non-constraint force per unit mass in the pivot frame (gravity minus pivot acceleration), m s^-2.
    length_m : float or (M,)
    damping_per_s : float or (M,)
        Viscous swing damping coefficient ``c`` (s^-1).

    Returns
    -------
    (M, 3) relative acceleration, m s^-2.
    """
    length = np.asarray(length_m, dtype=float)
    damping = np.asarray(damping_per_s, dtype=float)
    if length.ndim:
        length = length[:, None]
    if damping.ndim:
        damping = damping[:, None]
    radial = relative_position_m / length
    force = specific_force_mps2 - damping * relative_velocity_mps
    along = _dot(force, radial)[..., None]
    speed_sq = _dot(relative_velocity_mps, relative_velocity_mps)[..., None]
    return force - along * radial - (speed_sq / length) * radial


def project_onto_sphere(relative_position_m: np.ndarray, relative_velocity_mps: np.ndarray,
                        length_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Restore the bridle constraint: ``|r| = L`` and ``u . r = 0`` (removes integration drift)."""
    length = np.asarray(length_m, dtype=float)
    if length.ndim:
        length = length[:, None]
    norm = np.sqrt(_dot(relative_position_m, relative_position_m))[..., None]
    radial = relative_position_m / norm
    velocity = relative_velocity_mps - _dot(relative_velocity_mps, radial)[..., None] * radial
    return radial * length, velocity


def _swing_quaternion_unnormalised(direction: np.ndarray) -> np.ndarray:
    """``(1 + d_z, e_z x d)``: twice cos(a/2) times the minimal rotation from e_z to unit ``d``."""
    return np.stack([1.0 + direction[..., 2], -direction[..., 1], direction[..., 0],
                     np.zeros_like(direction[..., 0])], axis=-1)


def swing_twist_attitude(direction_up: np.ndarray, twist_rad: np.ndarray) -> np.ndarray:
    """Body-to-world quaternions (M, 4) with body z along ``direction_up`` (M, 3) and twist (M,) rad."""
    n = _swing_quaternion_unnormalised(direction_up)
    swing = n / np.sqrt(np.sum(n * n, axis=-1, keepdims=True))
    half = 0.5 * np.asarray(twist_rad, dtype=float)
    c, s = np.cos(half), np.sin(half)
    w0, x0, y0 = swing[..., 0], swing[..., 1], swing[..., 2]
    # swing * (c, 0, 0, s), swing has no z component
    return np.stack([w0 * c, x0 * c + y0 * s, -x0 * s + y0 * c, w0 * s], axis=-1)


def swing_twist_body_rate(direction_up: np.ndarray, direction_rate: np.ndarray, twist_rad: np.ndarray,
                          twist_rate_radps: np.ndarray) -> np.ndarray:
    """Body-frame angular rate (M, 3) rad/s of :func:`swing_twist_attitude` given d, dd/dt, psi, dpsi/dt."""
    n = _swing_quaternion_unnormalised(direction_up)
    n_dot = np.stack([direction_rate[..., 2], -direction_rate[..., 1], direction_rate[..., 0],
                      np.zeros_like(direction_rate[..., 0])], axis=-1)
    norm = np.sqrt(np.sum(n * n, axis=-1, keepdims=True))
    swing = n / norm
    swing_dot = n_dot / norm - n * np.sum(n * n_dot, axis=-1, keepdims=True) / norm**3
    # world angular velocity of the swing rotation: vector part of 2 q_dot * conj(q)
    w, x, y, z = (swing[..., i] for i in range(4))
    dw, dx, dy, dz = (swing_dot[..., i] for i in range(4))
    omega_swing_world = 2.0 * np.stack([
        -dw * x + dx * w - dy * z + dz * y,
        -dw * y + dx * z + dy * w - dz * x,
        -dw * z - dx * y + dy * x + dz * w,
    ], axis=-1)
    omega_world = omega_swing_world + np.asarray(twist_rate_radps)[..., None] * direction_up
    attitude = swing_twist_attitude(direction_up, twist_rad)
    # body rate = R^T omega_world
    matrix = quat_to_matrix(attitude)
    return np.einsum("...ji,...j->...i", matrix, omega_world)


def tilt_angle_rad(attitude_quat: np.ndarray) -> np.ndarray:
    """Off-nadir angle (rad) of body z from world z for quaternions (..., 4): ``acos(1 - 2 (x^2 + y^2))``."""
    q = np.asarray(attitude_quat, dtype=float)
    norm_sq = np.sum(q * q, axis=-1)
    return np.arccos(np.clip(1.0 - 2.0 * (q[..., 1] ** 2 + q[..., 2] ** 2) / norm_sq, -1.0, 1.0))


def twist_angle_rad(attitude_quat: np.ndarray) -> np.ndarray:
    """Roll: twist angle about body z of the swing-twist decomposition, in (-pi, pi] rad."""
    q = np.asarray(attitude_quat, dtype=float)
    angle = 2.0 * np.arctan2(q[..., 3], q[..., 0])
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def free_pendulum_swing(length_m: float, damping_ratio: float, initial_angle_rad: float, duration_s: float,
                        step_s: float, gravity_mps2: float = G_MARS_MPS2) -> tuple[np.ndarray, np.ndarray]:
    """Planar swing of the bridle pendulum about a fixed pivot, released from rest (for checks).

    Integrates :func:`pendulum_acceleration` with the same fixed-step RK4 + projection as the
    generator. Returns ``(time_s (N,), swing_angle_rad (N,))`` with the signed angle in the x-z plane.
    """
    omega0 = np.sqrt(gravity_mps2 / length_m)
    damping = 2.0 * damping_ratio * omega0
    position = np.array([[length_m * np.sin(initial_angle_rad), 0.0, -length_m * np.cos(initial_angle_rad)]])
    velocity = np.zeros((1, 3))
    gravity = np.array([[0.0, 0.0, -gravity_mps2]])
    steps = int(round(duration_s / step_s))
    angles = np.empty(steps + 1)
    angles[0] = initial_angle_rad

    def accel(p, v):
        return pendulum_acceleration(p, v, gravity, length_m, damping)

    for index in range(steps):
        k1v, k1a = velocity, accel(position, velocity)
        k2v = velocity + 0.5 * step_s * k1a
        k2a = accel(position + 0.5 * step_s * k1v, k2v)
        k3v = velocity + 0.5 * step_s * k2a
        k3a = accel(position + 0.5 * step_s * k2v, k3v)
        k4v = velocity + step_s * k3a
        k4a = accel(position + step_s * k3v, k4v)
        position = position + step_s / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        velocity = velocity + step_s / 6.0 * (k1a + 2 * k2a + 2 * k3a + k4a)
        position, velocity = project_onto_sphere(position, velocity, length_m)
        angles[index + 1] = np.arctan2(position[0, 0], -position[0, 2])
    return np.arange(steps + 1) * step_s, angles
