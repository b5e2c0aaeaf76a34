"""Vectorised rasterisers for synthetic orbital terrain (used by :mod:`sitedata.terrain.synthetic_terrain`).

All functions are pure functions of arrays and a numpy Generator; image arrays are (rows, cols)
with row index increasing southward and column index increasing eastward (north-up, as
:class:`simulator.scene.terrain.Terrain`). Lengths are in pixels unless a name says otherwise.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np

#: Photometric function f(alpha) of Mars, paper equations (2)-(3) (alpha in degrees), normalised by
#: f(0) = 2.05 so that ``2 mu0 / (mu + mu0) * f(alpha) / f(0)`` is 1 at normal incidence and emission.
_PHASE_POLY_DEG = (2.05, -3.93e-2, 2.09e-3, -4.86e-5, 4.93e-7, -1.72e-9)


def phase_function(phase_rad: float) -> float:
    """Mars photometric phase function f(alpha) of the paper (dimensionless, f(0) = 2.05).

    Equation (2) below 10 deg, equation (3) (linear) above, floored at 0.1 past 60 deg where the
    paper's fit no longer applies.
    """
    alpha_deg = float(np.degrees(phase_rad))
    if alpha_deg < 10.0:
        return float(sum(c * alpha_deg**n for n, c in enumerate(_PHASE_POLY_DEG)))
    return max(0.1, 1.82 - 1.03e-2 * (alpha_deg - 10.0))


def gaussian_random_field(shape: tuple[int, int], spectral_exponent: float, outer_scale_px: float,
                          rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-RMS isotropic Gaussian field with power spectrum ``(k^2 + k0^2)^(-beta/2)``.

    Parameters
    ----------
    shape : (rows, cols)
    spectral_exponent : float
        beta, the power-law exponent of the 2-D power spectrum P(k) ~ k^-beta (k in cycles/px).
    outer_scale_px : float
        Wavelength 1/k0 above which the spectrum flattens (px).
    rng : numpy Generator

    Returns
    -------
    ndarray float32 (rows, cols), periodic along the rows.
    """
    import scipy.fft

    rows, cols = shape
    # A strip only ~3 outer scales wide would put a sizeable share of the large-scale power into
    # modes constant across it (horizontal bands): generate on a wider periodic grid and crop.
    wide_cols = scipy.fft.next_fast_len(max(cols, int(cols + 3 * outer_scale_px)), real=True)
    white = rng.standard_normal((rows, wide_cols), dtype=np.float32)
    spectrum = scipy.fft.rfft2(white, workers=2)
    k_row = np.fft.fftfreq(rows).astype(np.float32)[:, None]
    k_col = np.fft.rfftfreq(wide_cols).astype(np.float32)[None, :]
    k0_sq = np.float32(1.0 / outer_scale_px**2)
    amplitude = (k_row**2 + k_col**2 + k0_sq) ** np.float32(-spectral_exponent / 4.0)
    amplitude[0, 0] = 0.0
    field = scipy.fft.irfft2(spectrum * amplitude, s=(rows, wide_cols), workers=2)[:, :cols]
    field = field - field.mean()
    return (field / max(float(field.std()), 1e-30)).astype(np.float32)


def splat_features(shape: tuple[int, int], centre_rc: np.ndarray, semi_axes_px: np.ndarray,
                   orientation_rad: np.ndarray, reach: float,
                   profiles: Sequence[tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]],
                   max_entries: int = 2_000_000) -> list[np.ndarray]:
    """Sum elliptical features, each a radial profile of its normalised radius, onto image grids.

    Feature ``i`` contributes ``weight_i * profile(rho)`` with
    ``rho = |R(-theta_i) (p - c_i) / (a_i, b_i)|`` on the pixels within ``reach * max(a_i, b_i)``
    of its centre; pixels outside the image are dropped (features may straddle the border).
    Features sharing a patch size are evaluated together (no per-pixel Python loop).

    Parameters
    ----------
    shape : (rows, cols)
    centre_rc : ndarray (n, 2), fractional (row, col) centres.
    semi_axes_px : ndarray (n, 2), semi-axes (a along the orientation, b across), px.
    orientation_rad : ndarray (n,), angle of axis a from the column axis toward the row axis.
    reach : float, patch half-size in units of the larger semi-axis.
    profiles : sequence of (profile, weights): profile maps rho (any shape) to values; weights (n,).

    Returns
    -------
    list of ndarray float32 (rows, cols), one per profile.
    """
    rows, cols = shape
    outputs = [np.zeros(rows * cols, dtype=np.float64) for _ in profiles]
    if len(centre_rc) == 0:
        return [out.reshape(shape).astype(np.float32) for out in outputs]
    half = np.ceil(reach * semi_axes_px.max(axis=1)).astype(np.int64)
    pending_idx: list[np.ndarray] = []
    pending_val: list[list[np.ndarray]] = [[] for _ in profiles]
    pending = 0

    def flush():
        nonlocal pending
        if pending_idx:
            idx = np.concatenate(pending_idx)
            for out, vals in zip(outputs, pending_val):
                out += np.bincount(idx, weights=np.concatenate(vals), minlength=rows * cols)
                vals.clear()
            pending_idx.clear()
        pending = 0

    for w in np.unique(half):
        members = np.flatnonzero(half == w)
        per = (2 * w + 1) ** 2
        chunk = max(1, max_entries // per)
        offsets = np.arange(-w, w + 1, dtype=np.float32)
        for start in range(0, len(members), chunk):
            sel = members[start:start + chunk]
            base_r = np.round(centre_rc[sel, 0]).astype(np.int64)
            base_c = np.round(centre_rc[sel, 1]).astype(np.int64)
            d_row = offsets[None, :, None] - (centre_rc[sel, 0] - base_r).astype(np.float32)[:, None, None]
            d_col = offsets[None, None, :] - (centre_rc[sel, 1] - base_c).astype(np.float32)[:, None, None]
            cos_t = np.cos(orientation_rad[sel]).astype(np.float32)[:, None, None]
            sin_t = np.sin(orientation_rad[sel]).astype(np.float32)[:, None, None]
            along = (d_col * cos_t + d_row * sin_t) / semi_axes_px[sel, 0].astype(np.float32)[:, None, None]
            across = (-d_col * sin_t + d_row * cos_t) / semi_axes_px[sel, 1].astype(np.float32)[:, None, None]
            rho = np.sqrt(along**2 + across**2)
            pix_r = base_r[:, None, None] + offsets.astype(np.int64)[None, :, None]
            pix_c = base_c[:, None, None] + offsets.astype(np.int64)[None, None, :]
            inside = (pix_r >= 0) & (pix_r < rows) & (pix_c >= 0) & (pix_c < cols)
            inside = np.broadcast_to(inside, rho.shape)
            pending_idx.append((pix_r * cols + pix_c)[inside])
            for vals, (profile, weights) in zip(pending_val, profiles):
                vals.append((profile(rho) * weights[sel].astype(np.float32)[:, None, None])[inside])
            pending += rho.size
            if pending >= max_entries:
                flush()
    flush()
    return [out.reshape(shape).astype(np.float32) for out in outputs]


def draw_tracks(shape: tuple[int, int], total_length_px: float, width_range_px: tuple[float, float],
                azimuth_rad: float, azimuth_spread_rad: float, mean_length_px: float,
                rng: np.random.Generator) -> np.ndarray:
    """Anti-aliased mask (0..1) of gently wandering linear tracks (dust devil tracks).

    Tracks start uniformly over (and around) the image with heading ``azimuth +- spread``
    (clockwise from north), exponential lengths of mean ``mean_length_px`` until their total
    length reaches ``total_length_px``; heading random-walks by ~2.5 deg per 10 px. Each track has an
    age-faded strength in [0.35, 1]; overlapping tracks take the stronger value.
    """
    rows, cols = shape
    canvas = np.zeros(shape, dtype=np.uint8)
    tracks = []
    drawn = 0.0
    while drawn < total_length_px:
        length = min(rng.exponential(mean_length_px), 6.0 * mean_length_px) + 20.0
        steps = max(2, int(length / 10.0))
        heading = azimuth_rad + azimuth_spread_rad * rng.standard_normal()
        headings = heading + np.cumsum(np.radians(2.5) * rng.standard_normal(steps))
        start = rng.uniform((-0.2 * rows, -0.2 * cols), (1.2 * rows, 1.2 * cols))
        # heading clockwise from north: d(col) = sin, d(row) = -cos
        path = start + 10.0 * np.cumsum(np.stack([-np.cos(headings), np.sin(headings)], axis=1), axis=0)
        width = rng.uniform(*width_range_px)
        strength = rng.uniform(0.35, 1.0)
        tracks.append((strength, width, path))
        drawn += length
    for strength, width, path in sorted(tracks, key=lambda t: t[0]):
        points = np.round(path[:, ::-1] * 16.0).astype(np.int32).reshape(-1, 1, 2)  # (x=col, y=row)
        cv2.polylines(canvas, [points], False, int(round(255 * strength)), thickness=max(1, int(round(width))),
                      lineType=cv2.LINE_AA, shift=4)
    mask = canvas.astype(np.float32) / 255.0
    return cv2.GaussianBlur(mask, (0, 0), 1.0)


def cast_shadow_fraction(height_m: np.ndarray, metres_per_pixel: float, sun_azimuth_rad: float,
                         sun_elevation_rad: float) -> np.ndarray:
    """Fraction (0..1) of each pixel in cast shadow of the height field, for a sun at infinity.

    A pixel p is shadowed when some point q toward the sun at horizontal distance t rises above the
    sun ray: ``h(q) > h(p) + t tan(elevation)``. The image is sheared so that the rays toward the
    sun run along one image axis; a running maximum of ``h - s tan(elevation)`` (s = distance
    toward the sun) then finds every occluder in one vectorised pass. Points beyond the image do
    not cast shadows.

    Parameters
    ----------
    height_m : ndarray (rows, cols), m.
    metres_per_pixel : float
    sun_azimuth_rad : float, clockwise from north. sun_elevation_rad : float, above the horizon.
    """
    toward_sun_row, toward_sun_col = -np.cos(sun_azimuth_rad), np.sin(sun_azimuth_rad)
    transpose = abs(toward_sun_row) > abs(toward_sun_col)
    height = np.ascontiguousarray(height_m.T if transpose else height_m, dtype=np.float32)
    step_main, step_cross = (toward_sun_row, toward_sun_col) if transpose else (toward_sun_col, toward_sun_row)
    # In the (possibly transposed) image the sun lies along +-axis 1; cross-axis drift per column:
    slope = step_cross / step_main
    direction = 1.0 if step_main > 0 else -1.0
    rows, cols = height.shape
    extra = int(np.ceil(abs(slope) * (cols - 1))) + 1
    offset = extra if slope > 0 else 0
    # sheared row r' holds height[r' - offset + slope*c, c]
    sheared_rows = rows + extra
    col_grid = np.arange(cols, dtype=np.float32)[None, :]
    map_row = (np.arange(sheared_rows, dtype=np.float32)[:, None] - offset + np.float32(slope) * col_grid)
    map_col = np.broadcast_to(col_grid, map_row.shape).astype(np.float32)
    low = np.float32(float(height.min()) - 1e6)
    # interpolate with replicated edges (no blending with the fill value at the border), then mark the
    # canvas samples that lie wholly outside the image as unable to cast shadows
    sheared = cv2.remap(height, map_col, map_row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = cv2.remap(np.ones_like(height), map_col, map_row, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    sheared[inside <= 0.0] = low
    path_m = metres_per_pixel * np.hypot(1.0, slope)
    toward_sun_m = (direction * path_m) * np.arange(cols, dtype=np.float32)[None, :]
    potential = sheared - np.float32(np.tan(sun_elevation_rad)) * toward_sun_m
    if direction > 0:   # occluders at larger column: running max from the right, excluding self
        running = np.maximum.accumulate(potential[:, ::-1], axis=1)[:, ::-1]
        occluder = np.concatenate([running[:, 1:], np.full((sheared_rows, 1), low, np.float32)], axis=1)
    else:
        running = np.maximum.accumulate(potential, axis=1)
        occluder = np.concatenate([np.full((sheared_rows, 1), low, np.float32), running[:, :-1]], axis=1)
    shadow_sheared = (occluder > potential + 1e-3).astype(np.float32)
    del sheared, inside, potential, running, occluder, map_row, map_col
    back_row = (np.arange(rows, dtype=np.float32)[:, None] + offset - np.float32(slope) * col_grid)
    back_col = np.broadcast_to(col_grid, back_row.shape).astype(np.float32)
    shadow = cv2.remap(shadow_sheared, back_col, back_row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    shadow = np.clip(shadow, 0.0, 1.0)
    return np.ascontiguousarray(shadow.T) if transpose else shadow
