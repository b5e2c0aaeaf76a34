"""EDL descent profiles: the stand-in for the ADAMS multi-body runs behind MOC2DIMES (paper 2.2, 5).

Model (equations in :mod:`sitedata.edl.dynamics`)
-------------------------------------------------
* The parachute + backshell (the bridle's *pivot*) flies at terminal velocity ``V_t`` (~72 m/s) and
  follows the air with the linearised quadratic-drag time constants ``tau_h = V_t / g`` horizontally
  and ``tau_v = V_t / (2 g)`` vertically. The air is the steady wind (per profile: a reference
  vector plus a linear shear with altitude) plus Ornstein-Uhlenbeck gusts.
* The lander hangs ``L`` = 20 m below on the bridle: a damped spherical pendulum driven by the
  pivot's acceleration (steady wind catch-up and gusts), started from the swing left by heat-shield
  release. It twists about the bridle as a damped torsional oscillator driven by the crosswind on
  the asymmetric lander.
* The heat shield falls ahead (below) of the lander; its path is the constant-acceleration curve
  through the drawn separations at the three images (axial = vertical, lateral = horizontal), on the
  upwind side (the lander drifts downwind of the denser heat shield).

Integration is a fixed-step RK4 (``integration_step_s``) with the bridle constraint restored after
every step; gusts are exact OU updates held over a step. Each profile draws everything from its own
``Generator(PCG64(SeedSequence(seed, spawn_key=(index, attempt))))`` in a fixed order, so profile
``index`` is the same bits whatever the batch. A draw whose sampled profile leaves the paper's
envelope (``[limits]``) is redrawn with ``attempt + 1``.

Output (see :mod:`sitedata.edl.trajectory_io`): time origin at the first sample; images 1 and 2 where
the lander passes ``altitudes_m``; image 3 ``last_image_after_previous_s`` after image 2; samples
every ``dense_step_s`` within ``dense_half_window_s`` of each image and every ``coarse_step_s``
between; x, y = 0 at the lander's nadir point at image 1 (within 1e-4 m). Attitude between coarse
samples is slerped by :class:`~simulator.scene.descent_profile.DescentProfile`, so use the dense windows
(where the images are) for anything that needs the attitude to better than ~0.2 deg.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from config_tables.errors import ConfigError
from simulator.scene.descent_profile import DescentProfile
from sitedata.edl.dynamics import (
    G_MARS_MPS2,
    pendulum_acceleration,
    project_onto_sphere,
    swing_twist_attitude,
    swing_twist_body_rate,
    tilt_angle_rad,
    twist_angle_rad,
)
from sitedata.edl.parameters import EdlParameters, load_edl_parameters

__all__ = ["EdlParameters", "generate_profiles", "load_edl_parameters", "profile_statistics", "within_limits"]



@dataclass(frozen=True)
class _Draws:
    """Per-profile random draws (batch axis first)."""

    terminal_velocity: np.ndarray   # (M,)
    wind_reference: np.ndarray      # (M, 2) at the first image altitude
    shear: np.ndarray               # (M, 2) per metre of altitude
    relative_velocity: np.ndarray   # (M, 2)
    swing_tilt: np.ndarray          # (M, 2) rad, about east-ish and north-ish axes
    swing_rate: np.ndarray          # (M, 2) rad/s
    roll: np.ndarray                # (M,)
    roll_rate: np.ndarray           # (M,)
    asymmetry_angle: np.ndarray     # (M,)
    heat_shield: np.ndarray         # (M, 5): axial1, axial growth, lateral1, lateral growth, direction noise
    gust_initial: np.ndarray        # (M, 3) standard normal
    gust_innovation: np.ndarray     # (M, steps, 3) standard normal


def _steps(params: EdlParameters) -> int:
    images, sampling = params.images, params.sampling
    drop = images.altitudes_m[0] - images.altitudes_m[1]
    duration = (params.descent.time_before_first_image_s + 1.25 * drop / params.descent.terminal_velocity_mean_mps
                + images.last_image_after_previous_s + sampling.margin_s + sampling.dense_half_window_s + 1.0)
    record = int(round(sampling.dense_step_s / sampling.integration_step_s))
    return int(np.ceil(duration / sampling.integration_step_s / record)) * record


def _draw(params: EdlParameters, keys: list[tuple[int, int]]) -> _Draws:
    steps = _steps(params)
    rows = []
    for index, attempt in keys:
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(params.seed, spawn_key=(index, attempt))))
        scalars = rng.standard_normal(14)
        uniforms = rng.random(5)
        gust = rng.standard_normal((steps + 1, 3))
        rows.append((scalars, uniforms, gust))
    scalars = np.stack([r[0] for r in rows])
    uniforms = np.stack([r[1] for r in rows])
    gust = np.stack([r[2] for r in rows])
    p = params

    def between(bounds, u):
        return bounds[0] + (bounds[1] - bounds[0]) * u

    shield = p.heat_shield
    heat_shield = np.stack([between(shield.axial_at_first_image_m, uniforms[:, 0]),
                            between(shield.axial_growth_to_last_image_m, uniforms[:, 1]),
                            between(shield.lateral_at_first_image_m, uniforms[:, 2]),
                            between(shield.lateral_growth_to_last_image_m, uniforms[:, 3]),
                            shield.lateral_direction_sigma_rad * scalars[:, 12]], axis=-1)
    return _Draws(
        terminal_velocity=p.descent.terminal_velocity_mean_mps + p.descent.terminal_velocity_sigma_mps * scalars[:, 0],
        wind_reference=p.wind.steady_sigma_mps * scalars[:, 1:3], shear=p.wind.shear_sigma_mps_per_m * scalars[:, 3:5],
        relative_velocity=p.descent.initial_relative_horizontal_velocity_sigma_mps * scalars[:, 5:7],
        swing_tilt=p.pendulum.initial_swing_sigma_rad * scalars[:, 7:9],
        swing_rate=p.pendulum.initial_swing_rate_sigma_radps * scalars[:, 9:11],
        roll=p.twist.initial_roll_sigma_rad * scalars[:, 11], roll_rate=p.twist.initial_roll_rate_sigma_radps * scalars[:, 13],
        asymmetry_angle=2.0 * np.pi * uniforms[:, 4], heat_shield=heat_shield,
        gust_initial=gust[:, 0, :], gust_innovation=gust[:, 1:, :],
    )


_BATCH = 200  # profiles integrated together (batch size does not change any profile's bits)
_STATE = 14   # pivot position (3), pivot velocity (3), bridle vector r (3), dr/dt (3), roll, roll rate


def _integrate(p: EdlParameters, d: _Draws) -> tuple[float, np.ndarray]:
    """Fixed-step RK4 of the batch; returns the record step (s) and records (M, R, 14) every dense_step_s."""
    g, h, length = G_MARS_MPS2, p.sampling.integration_step_s, p.pendulum.bridle_length_m
    steps, every = _steps(p), int(round(p.sampling.dense_step_s / p.sampling.integration_step_s))
    vt = d.terminal_velocity
    tau_h, tau_v = vt / g, vt / (2.0 * g)
    damping = 2.0 * p.pendulum.damping_ratio * np.sqrt(g / length)
    omega_t = 2.0 * np.pi / p.twist.natural_period_s
    stiffness, twist_damping = omega_t**2, 2.0 * p.twist.damping_ratio * omega_t
    alt1 = p.images.altitudes_m[0]
    phi = np.exp(-h / p.wind.gust_correlation_time_s)
    gust_sigma = np.array([p.wind.gust_horizontal_sigma_mps, p.wind.gust_horizontal_sigma_mps, p.wind.gust_vertical_sigma_mps])
    gust_scale = gust_sigma * np.sqrt(1.0 - phi * phi)
    asymmetry = np.stack([np.cos(d.asymmetry_angle), np.sin(d.asymmetry_angle)], axis=-1)

    def rates(y: np.ndarray, gust: np.ndarray) -> np.ndarray:
        velocity, r, u = y[:, 3:6], y[:, 6:9], y[:, 9:12]
        air_h = d.wind_reference + d.shear * (y[:, 2:3] - alt1) + gust[:, :2]
        pivot_accel = np.empty_like(velocity)
        pivot_accel[:, :2] = (air_h - velocity[:, :2]) / tau_h[:, None]
        pivot_accel[:, 2] = (gust[:, 2] - vt - velocity[:, 2]) / tau_v
        specific = -pivot_accel
        specific[:, 2] -= g
        crosswind = air_h - velocity[:, :2] - u[:, :2]
        roll_accel = (-stiffness * y[:, 12] - twist_damping * y[:, 13] + p.twist.crosswind_torque_radps2_per_mps
                      * (asymmetry[:, 0] * crosswind[:, 0] + asymmetry[:, 1] * crosswind[:, 1]))
        return np.concatenate([velocity, pivot_accel, u, pendulum_acceleration(r, u, specific, length, damping),
                               y[:, 13:14], roll_accel[:, None]], axis=1)

    count = len(vt)
    up = np.concatenate([d.swing_tilt, np.ones((count, 1))], axis=1)
    up /= np.sqrt(np.sum(up * up, axis=1, keepdims=True))
    omega = np.concatenate([d.swing_rate, np.zeros((count, 1))], axis=1)
    y = np.empty((count, _STATE))
    y[:, 0:2] = 0.0
    y[:, 2] = alt1 + vt * p.descent.time_before_first_image_s + length
    y[:, 3:5] = d.wind_reference + d.shear * (y[:, 2:3] - alt1) + d.relative_velocity
    y[:, 5] = -vt
    y[:, 6:9] = -length * up
    y[:, 9:12] = -length * np.cross(omega, up)
    y[:, 12], y[:, 13] = d.roll, d.roll_rate
    gust = gust_sigma * d.gust_initial
    records = np.empty((count, steps // every + 1, _STATE))
    for n in range(steps):
        if n % every == 0:
            records[:, n // every] = y
        k1 = rates(y, gust)
        k2 = rates(y + (0.5 * h) * k1, gust)
        k3 = rates(y + (0.5 * h) * k2, gust)
        k4 = rates(y + h * k3, gust)
        y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        y[:, 6:9], y[:, 9:12] = project_onto_sphere(y[:, 6:9], y[:, 9:12], length)
        gust = phi * gust + gust_scale * d.gust_innovation[:, n]
    records[:, -1] = y
    return every * h, records


def _crossing_time(time_s: np.ndarray, altitude_m: np.ndarray, level_m: float) -> float | None:
    below = np.nonzero((altitude_m[:-1] >= level_m) & (altitude_m[1:] < level_m))[0]
    if len(below) == 0:
        return None
    j = below[0]
    return float(time_s[j] + (altitude_m[j] - level_m) / (altitude_m[j] - altitude_m[j + 1]) * (time_s[j + 1] - time_s[j]))


def _build_profile(p: EdlParameters, step_s: float, rec: np.ndarray, draws: _Draws, row: int,
                   name: str) -> DescentProfile | None:
    """Sampled profile of one integrated draw, or None when the images do not fall inside the run."""
    count = rec.shape[0]
    time = np.arange(count) * step_s
    lander = rec[:, 0:3] + rec[:, 6:9]
    t1 = _crossing_time(time, lander[:, 2], p.images.altitudes_m[0])
    t2 = _crossing_time(time, lander[:, 2], p.images.altitudes_m[1])
    if t1 is None or t2 is None:
        return None
    images = np.array([t1, t2, t2 + p.images.last_image_after_previous_s])
    lo = int(np.floor((t1 - p.sampling.margin_s) / step_s))
    hi = int(np.ceil((images[-1] + p.sampling.margin_s) / step_s))
    if lo < 0 or hi >= count:
        return None
    coarse = int(round(p.sampling.coarse_step_s / p.sampling.dense_step_s))
    keep = np.zeros(count, dtype=bool)
    keep[lo:hi + 1:coarse] = True
    keep[[lo, hi]] = True
    for t in images:
        keep[max(lo, int(np.floor((t - p.sampling.dense_half_window_s) / step_s))):
             min(hi, int(np.ceil((t + p.sampling.dense_half_window_s) / step_s))) + 1] = True
    index = np.nonzero(keep)[0]
    s = rec[index]
    length = p.pendulum.bridle_length_m
    up, up_rate = -s[:, 6:9] / length, -s[:, 9:12] / length
    attitude = swing_twist_attitude(up, s[:, 12])
    body_rate = swing_twist_body_rate(up, up_rate, s[:, 12], s[:, 13])
    position = s[:, 0:3] + s[:, 6:9]
    velocity = s[:, 3:6] + s[:, 9:12]
    wind = np.zeros_like(position)
    wind[:, :2] = draws.wind_reference[row] + draws.shear[row] * (position[:, 2:3] - p.images.altitudes_m[0])

    def lander_at(t: float) -> np.ndarray:
        return np.array([np.interp(t, time, lander[:, axis]) for axis in range(3)])

    at_images = np.stack([lander_at(t) for t in images])
    axial1, axial_growth, lateral1, lateral_growth, direction_noise = draws.heat_shield[row]
    wind_ref = draws.wind_reference[row]
    speed = float(np.hypot(*wind_ref))
    upwind = -wind_ref / speed if speed > 1e-9 else np.array([1.0, 0.0])
    c, sn = np.cos(direction_noise), np.sin(direction_noise)
    lateral_dir = np.array([c * upwind[0] - sn * upwind[1], sn * upwind[0] + c * upwind[1], 0.0])
    fraction = (images - images[0]) / (images[-1] - images[0])
    offsets = ((lateral1 + lateral_growth * fraction)[:, None] * lateral_dir
               - (axial1 + axial_growth * fraction)[:, None] * np.array([0.0, 0.0, 1.0]))
    targets = at_images + offsets
    sample_time = time[index]
    basis = np.stack([np.prod([(sample_time - images[m]) / (images[k] - images[m]) for m in range(3) if m != k], axis=0)
                      for k in range(3)], axis=-1)
    heat_shield = basis @ targets
    origin = np.array([at_images[0, 0], at_images[0, 1], 0.0])
    start = lo * step_s
    return DescentProfile(
        time_s=(index - lo) * step_s, position_m=position - origin, velocity_mps=velocity, attitude_quat=attitude,
        angular_rate_radps=body_rate, wind_mps=wind, heat_shield_position_m=heat_shield - origin,
        image_times_s=images - start, name=name)


def profile_statistics(profile: DescentProfile) -> dict[str, float]:
    """Envelope and image-time statistics of one profile (degrees and m/s for reading; SI otherwise).

    Maxima run over every stored sample of the profile; per-image values use ``profile.pose``.
    Heat-shield separations: axial = lander altitude minus heat-shield altitude, lateral = horizontal
    distance, both at the images.
    """
    poses = [profile.pose(float(t)) for t in profile.image_times_s]
    stats: dict[str, float] = {}
    for k, pose in enumerate(poses, start=1):
        stats[f"altitude_image{k}_m"] = float(pose.position_m[2])
        stats[f"vertical_speed_image{k}_mps"] = float(-pose.velocity_mps[2])
        stats[f"horizontal_speed_image{k}_mps"] = float(np.hypot(*pose.velocity_mps[:2]))
        stats[f"wind_speed_image{k}_mps"] = float(np.hypot(*profile.wind_at(pose.time_s)[:2]))
        if pose.heat_shield_position_m is not None:
            relative = pose.position_m - pose.heat_shield_position_m
            stats[f"heat_shield_axial_image{k}_m"] = float(relative[2])
            stats[f"heat_shield_lateral_image{k}_m"] = float(np.hypot(*relative[:2]))
    if len(poses) >= 3:
        stats["image2_to_3_s"] = float(profile.image_times_s[2] - profile.image_times_s[1])
    stats["off_nadir_max_deg"] = float(np.degrees(np.max(tilt_angle_rad(profile.attitude_quat))))
    stats["roll_max_deg"] = float(np.degrees(np.max(np.abs(twist_angle_rad(profile.attitude_quat)))))
    stats["angular_rate_max_dps"] = float(np.degrees(np.max(np.linalg.norm(profile.angular_rate_radps, axis=1))))
    stats["horizontal_speed_max_mps"] = float(np.max(np.hypot(profile.velocity_mps[:, 0], profile.velocity_mps[:, 1])))
    return stats


def within_limits(p: EdlParameters, stats: dict[str, float]) -> bool:
    """True when a profile's envelope lies inside the set's ``[limits]`` (strictly)."""
    return (stats["off_nadir_max_deg"] < p.limits.off_nadir_max_deg
            and stats["roll_max_deg"] < p.limits.roll_max_deg
            and stats["angular_rate_max_dps"] < p.limits.angular_rate_max_dps
            and stats["horizontal_speed_max_mps"] < p.limits.horizontal_speed_max_mps)


def generate_profiles(p: EdlParameters, indices=None, max_attempts: int = 50) -> tuple[list[DescentProfile], list[int]]:
    """Profiles ``indices`` (default ``range(p.set.profiles)``) of a site's set, in order, and the attempt
    number each needed (0 = first draw accepted; >0 = earlier draws left the paper's envelope)."""
    indices = list(range(p.set.profiles)) if indices is None else [int(i) for i in indices]
    accepted: dict[int, tuple[DescentProfile, int]] = {}
    pending = [(i, 0) for i in indices]
    while pending:
        batch, pending = pending[:_BATCH], pending[_BATCH:]
        draws = _draw(p, batch)
        step_s, records = _integrate(p, draws)
        for row, (index, attempt) in enumerate(batch):
            profile = _build_profile(p, step_s, records[row], draws, row, f"{p.name}-{index:04d}")
            if profile is not None and within_limits(p, profile_statistics(profile)):
                accepted[index] = (profile, attempt)
            elif attempt + 1 >= max_attempts:
                raise ConfigError(f"{p.source}: limits: profile {index} of set {p.name!r} left the [limits] envelope in "
                                  f"{max_attempts} draws; allowed: statistics ([descent], [pendulum], [twist], [wind]) "
                                  "consistent with the limits")
            else:
                pending.append((index, attempt + 1))
    return [accepted[i][0] for i in indices], [accepted[i][1] for i in indices]
