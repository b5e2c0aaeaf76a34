"""A compiled :func:`flight_interface.cahvor.unproject` for the few pixels of the warp's checks.

The warp-and-accumulate checks (:mod:`simulator.scene.blur_warp`) unproject a handful of small pixel
sets per image (a doubling level's moved positions, the self-moving points, a mask's centre): numpy's
per-call cost, ~20 calls per Newton step on arrays of 1 to 150 elements, was ~90 us per set. This pass
repeats :func:`~flight_interface.cahvor.unproject`'s float64 operations in the same order, element by
element (no fused multiply-add: numba rounds each product and sum as numpy does; ``sqrt`` is correctly
rounded in both), with the same Newton iteration of the distortion inversion: every element takes the
same number of steps, until the whole set has converged, as the array code does. So it gives the same
bits; :func:`unproject` checks that once per process and camera model against the array code on a probe
set and uses the array code where they differ (another numba or CPU).

Kept apart so that the configuration's imports load no numba.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from flight_interface import cahvor
from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED

TOLERANCE_RAD = 1e-12    # cahvor.unproject's defaults
MAX_ITERATIONS = 50


@njit(cache=True, nogil=True, boundscheck=False, error_model="numpy")
def _unproject_kernel(pixels, vectors, scalars, flags, out):
    """:func:`flight_interface.cahvor.unproject` of ``pixels`` (n, 2) into ``out`` (n, 3), operation by operation.

    ``vectors``: V x H, -(V x A), -(A x H), A, O (5, 3); ``scalars``: R0, R1, R2, the turning point, the
    threshold beyond which the inversion returns it, the tolerance; ``flags``: distortion, finite turning
    point, largest number of Newton steps.
    """
    base, per_column, per_row, a, o = vectors[0], vectors[1], vectors[2], vectors[3], vectors[4]
    r0, r1, r2, turning, beyond_threshold, tolerance = scalars[0], scalars[1], scalars[2], scalars[3], scalars[4], scalars[5]
    distorted, finite_turning, max_iterations = flags[0] != 0, flags[1] != 0, flags[2]
    count = pixels.shape[0]
    for i in range(count):
        column, row = pixels[i, 0], pixels[i, 1]
        for k in range(3):
            out[i, k] = base[k] + column * per_column[k] + row * per_row[k]
        x, y, z = out[i, 0], out[i, 1], out[i, 2]
        sign = (-1.0 if x * a[0] + y * a[1] + z * a[2] < 0 else 1.0) / np.sqrt(x * x + y * y + z * z)
        out[i, 0], out[i, 1], out[i, 2] = x * sign, y * sign, z * sign
    if not distorted:
        return
    omega = np.empty(count)
    lam = np.empty((count, 3))
    u_distorted = np.empty(count)
    u = np.empty(count)
    one_plus_r0, three_r1, five_r2 = 1.0 + r0, 3.0 * r1, 5.0 * r2
    for i in range(count):
        x, y, z = out[i, 0], out[i, 1], out[i, 2]
        omega[i] = x * o[0] + y * o[1] + z * o[2]
        for k in range(3):
            lam[i, k] = out[i, k] - omega[i] * o[k]
        lx, ly, lz = lam[i, 0], lam[i, 1], lam[i, 2]
        u_distorted[i] = np.sqrt(lx * lx + ly * ly + lz * lz) / omega[i]
        start = u_distorted[i] / one_plus_r0          # np.minimum(start, turning): NaN propagates
        value = start if (start < turning or start != start) else turning
        if finite_turning and u_distorted[i] >= beyond_threshold:
            value = turning
        u[i] = value
    for _ in range(max_iterations):
        converged = True
        for i in range(count):
            value = u[i]
            u2 = value * value
            residual = value * (one_plus_r0 + r1 * u2 + r2 * u2 * u2) - u_distorted[i]
            slope = one_plus_r0 + three_r1 * u2 + five_r2 * u2 * u2
            step = residual / slope if slope > 0 else 0.0
            moved = value - step
            if moved == moved:                        # np.clip(moved, 0, turning); NaN stays NaN
                moved = moved if moved > 0.0 else 0.0
                moved = moved if moved < turning else turning
            if not abs(moved - value) < tolerance:
                converged = False
            u[i] = moved
        if converged:
            break
    for i in range(count):
        scale = u[i] / u_distorted[i] if u_distorted[i] > 0 else 1.0
        for k in range(3):
            out[i, k] = omega[i] * o[k] + scale * lam[i, k]
        x, y, z = out[i, 0], out[i, 1], out[i, 2]
        length = np.sqrt(x * x + y * y + z * z)
        out[i, 0], out[i, 1], out[i, 2] = x / length, y / length, z / length


def _parameters(model: cahvor.Cahvor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's ``vectors``, ``scalars`` and ``flags`` for a model (as cahvor.unproject derives them)."""
    r0, r1, r2 = (float(value) for value in model.r)
    turning = cahvor.distortion_turning_point(model.r)
    finite = bool(np.isfinite(turning))
    # cahvor._undistort_tangent's threshold, in its own (Python float) arithmetic
    threshold = turning * (1.0 + r0 + r1 * turning**2 + r2 * turning**4) if finite else 0.0
    vectors = np.array([cahvor._cross(model.v, model.h), [-value for value in cahvor._cross(model.v, model.a)],
                        [-value for value in cahvor._cross(model.a, model.h)],
                        np.asarray(model.a, dtype=float), np.asarray(model.o, dtype=float)], dtype=float)
    scalars = np.array([r0, r1, r2, turning, threshold, TOLERANCE_RAD])
    flags = np.array([int(bool(np.any(model.r))), int(finite), MAX_ITERATIONS], dtype=np.int64)
    for array in (vectors, scalars, flags):
        array.setflags(write=False)
    return vectors, scalars, flags


def _compiled(model: cahvor.Cahvor, pixels: np.ndarray,
              parameters: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The compiled pass on ``pixels`` (..., 2); the rays (..., 3)."""
    pixels = np.asarray(pixels, dtype=float)
    flat = np.ascontiguousarray(pixels.reshape(-1, 2))
    out = np.empty((len(flat), 3))
    _unproject_kernel(flat, *(_parameters(model) if parameters is None else parameters), out)
    return out.reshape(*pixels.shape[:-1], 3)


def _matches(model: cahvor.Cahvor, parameters: tuple[np.ndarray, np.ndarray, np.ndarray]) -> bool:
    """The compiled pass gives the array code's bits for this model on a probe set."""
    centre = np.array([float(model.h @ model.a), float(model.v @ model.a)])
    probes = [centre[None, :], centre[None, :] + 1e-9]
    rng = np.random.default_rng(0)
    for count in (1, 2, 7, 64, 300):
        probes.append(centre + rng.uniform(-3000.0, 3000.0, size=(count, 2)))
    probes.append(np.stack(np.meshgrid(np.linspace(-500.0, 2500.0, 31), np.linspace(-500.0, 2500.0, 29)), axis=-1))
    with np.errstate(all="ignore"):
        return all(_compiled(model, pixels, parameters).tobytes() == cahvor.unproject(model, pixels).tobytes()
                   for pixels in probes)


def unproject(model: cahvor.Cahvor, pixels: np.ndarray) -> np.ndarray:
    """:func:`flight_interface.cahvor.unproject` (default tolerance and iterations), compiled.

    The kernel's parameters and its check against the array code (:func:`_matches`) are kept per model
    object (:data:`simulator.derived_cache.DERIVED`).

    Parameters
    ----------
    model : Cahvor
        The camera model.
    pixels : ndarray, shape (..., 2)
        ``(column, row)`` image coordinates (px).

    Returns
    -------
    ndarray, shape (..., 3)
        Unit directions, as :func:`~flight_interface.cahvor.unproject` returns them (its bits; its own
        result where the compiled pass does not match it on this model).
    """
    cache = DERIVED.of(model, "unproject_compiled")
    parameters = cache.get("parameters", False)
    if parameters is False:
        parameters = _parameters(model)
        parameters = cache["parameters"] = parameters if _matches(model, parameters) else None
    if parameters is None:
        return cahvor.unproject(model, pixels)
    return _compiled(model, pixels, parameters)


def prime_pixel_rays(camera: Camera) -> None:
    """Give ``camera`` its full-frame rays (:attr:`flight_interface.camera.Camera.pixel_rays`) by the compiled pass.

    The camera computes them with the array code on first use, 0.40 s for 1024 x 1024 pixels; the compiled
    pass gives the same bits (:func:`unproject`) in 0.08 s. They are kept where the camera's cached property
    keeps its value (the instance dict, as :func:`functools.cached_property` stores it), read-only as the
    camera makes them, so ``pixel_rays``, ``field_angle_rad`` and ``falloff_map`` read them from then on.
    Nothing is done when the camera already holds its rays.

    Parameters
    ----------
    camera : Camera
        The camera (a frozen dataclass whose derived arrays are cached properties).

    Returns
    -------
    None
    """
    if "pixel_rays" in vars(camera):
        return
    rays = unproject(camera.model, cahvor.pixel_grid(camera.width_px, camera.height_px))
    rays.setflags(write=False)
    vars(camera)["pixel_rays"] = rays
