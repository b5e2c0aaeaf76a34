"""Energetic particle hits: short charge tracks of random direction and length, new in every image.

Model (SI units; positions in pixels of the full-resolution array, row 0 first):

* Exposure window. A particle crossing the chip adds charge to a packet that is read out if it hits
  the packet while the packet exists on the chip. For a frame-transfer CCD with fast flush ``T_f``,
  exposure ``T_e``, frame transfer ``T_t`` and read-out ``T_r`` (charge moving toward the last row):

  - fast flush: a hit at row i, a fraction phi into the flush, survives if the packet is not
    clocked off before the flush ends (i < N phi): on average half the hits, landing in final row j
    with density proportional to j (the packets near the last row crossed most of the array);
  - exposure: every hit counts, uniform over the rows;
  - frame transfer: hits in the image area (final-row density ~ N - j) plus hits in the part of the
    storage area already filled (density ~ j): weight ``T_t``, uniform;
  - read-out: the storage area is shielded from light, not from particles; binned row k waits
    ``T_r (n - k) / n`` (see :func:`simulator.detector.charge_generation.storage_dark_e`), so half the hits
    count, with density proportional to ``N - j``.

  The effective window is ``T_eff = T_f / 2 + T_e + T_t + T_r / 2`` (0.113 s for MER, dominated by
  the read-out wait) and the rows follow the mixture above (mirrored when charge moves toward the
  first row); columns are uniform.
* Count: Poisson with mean ``rate_per_cm2_s * A * T_eff``, ``A = (W p)(H p)`` the array area
  (1.51 cm^2 for 1024 x 12 um).
* Direction: isotropic particles crossing a plane have polar angles with ``sin^2 theta`` uniform on
  [0, 1] (flux through a surface ~ cos theta); azimuth uniform. The track's projection on the array
  has length ``L = depth tan theta`` (``particle_hit_depth_m``: the charge-collection depth), capped
  at ``particle_hit_max_track_length_m``.
* Charge: ``Q = charge_e_per_m * sqrt(L^2 + depth^2)`` (the path through the collection depth; about
  100 e-/um of path for a minimum-ionising particle in silicon, 3.6 eV per pair), spread uniformly
  along the projected segment: the segment is cut into ``ceil(4 L / p)`` equal pieces (at least
  one), each piece's charge going to the pixel under its midpoint. Pieces off the array are lost;
  everything else is conserved exactly. Diffusion of the charge cloud is neglected.

The charge is added to the pixel charge after frame transfer (tracks are instantaneous, so they are
not smeared) and before blooming and binning.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flight_interface.camera import Camera

PIECES_PER_PIXEL = 4


@dataclass(frozen=True)
class ParticleHits:
    """One image's particle charge.

    Attributes
    ----------
    rows, cols : ndarray, shape (m,), int64
        Full-resolution pixels that got charge (unique).
    charge_e : ndarray, shape (m,), float64
        Charge of each pixel (e-).
    count : int
        Number of particles.
    """

    rows: np.ndarray
    cols: np.ndarray
    charge_e: np.ndarray
    count: int

    @property
    def max_pixel_charge_e(self) -> float:
        """Largest charge any pixel got (e-), 0 without hits."""
        return float(self.charge_e.max()) if self.charge_e.size else 0.0


def effective_window_s(camera: Camera) -> tuple[float, float, float]:
    """Window weights of the three row distributions, for charge moving toward the last row.

    Parameters
    ----------
    camera : Camera
        The camera (timing).

    Returns
    -------
    tuple of float
        (flush-like ~ j, uniform, read-out-like ~ N - j) weights (s); their sum is ``T_eff`` of the module doc.
    """
    timing = camera.timing
    return 0.5 * timing.fast_flush_s, timing.exposure_s + timing.frame_transfer_s, 0.5 * timing.readout_s


def expected_count(camera: Camera, rate_per_cm2_s: float) -> float:
    """Mean number of particles per image, ``rate * A * T_eff``.

    Parameters
    ----------
    camera : Camera
        The camera (array area, timing).
    rate_per_cm2_s : float
        Particle flux (cm^-2 s^-1).

    Returns
    -------
    float
        Mean count.
    """
    area_cm2 = (camera.width_px * camera.pixel_pitch_m * 1e2) * (camera.height_px * camera.pixel_pitch_m * 1e2)
    return rate_per_cm2_s * area_cm2 * sum(effective_window_s(camera))


def draw_rows(camera: Camera, rng: np.random.Generator, count: int) -> np.ndarray:
    """Final row coordinates of hits drawn from the window mixture (module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    rng : numpy.random.Generator
        The image's stream.
    count : int
        Number of hits.

    Returns
    -------
    ndarray, shape (count,), float64
        Row coordinate, 0 .. N.
    """
    rows = camera.height_px
    weights = np.array(effective_window_s(camera))
    kind = rng.choice(3, size=count, p=weights / weights.sum()) if weights.sum() > 0 else np.ones(count, int)
    uniform = rng.random(count)
    position = np.where(kind == 0, rows * np.sqrt(uniform),                   # density ~ j
                        np.where(kind == 1, rows * uniform,                   # uniform
                                 rows * (1.0 - np.sqrt(uniform))))            # density ~ N - j
    position = np.minimum(position, np.nextafter(rows, 0))
    return position if camera.timing.transfer_toward_last_row else rows - position


def deposit_tracks(shape: tuple[int, int], start_px: np.ndarray, delta_px: np.ndarray,
                   charge_e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spread each track's charge along its segment (module doc) and sum per pixel.

    Parameters
    ----------
    shape : (H, W)
    start_px : (n, 2) (column, row) start points (pixel centres at integers + 0.5 edges: pixel (r, c)
        covers rows r .. r+1, columns c .. c+1)
    delta_px : (n, 2) segment vectors (column, row), pixels
    charge_e : (n,) electrons per track

    Returns
    -------
    rows, cols, charge : unique pixels on the array and their summed charge (e-)
    """
    height, width = shape
    length = np.hypot(delta_px[:, 0], delta_px[:, 1])
    pieces = np.maximum(1, np.ceil(PIECES_PER_PIXEL * length)).astype(np.int64)
    track = np.repeat(np.arange(len(pieces)), pieces)
    first = np.cumsum(pieces) - pieces
    fraction = (np.arange(pieces.sum()) - first[track] + 0.5) / pieces[track]
    points = start_px[track] + fraction[:, None] * delta_px[track]
    cols = np.floor(points[:, 0]).astype(np.int64)
    rows = np.floor(points[:, 1]).astype(np.int64)
    piece_charge = charge_e[track] / pieces[track]
    on = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    flat, inverse = np.unique(rows[on] * width + cols[on], return_inverse=True)
    summed = np.bincount(inverse, weights=piece_charge[on], minlength=flat.size)
    return flat // width, flat % width, summed


def draw_particle_hits(camera: Camera, rng: np.random.Generator, rate_per_cm2_s: float, charge_e_per_m: float,
                       depth_m: float, max_track_length_m: float) -> ParticleHits:
    """Draw one image's particle hits (module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    rng : numpy.random.Generator
        The image's stream.
    rate_per_cm2_s : float
        Particle flux (cm^-2 s^-1).
    charge_e_per_m : float
        Charge deposited per metre of track (e-/m).
    depth_m : float
        Depth of the charge-collecting layer (m).
    max_track_length_m : float
        Longest track projected on the array (m).

    Returns
    -------
    ParticleHits
        The charge of the hit pixels.
    """
    count = int(rng.poisson(expected_count(camera, rate_per_cm2_s)))
    rows = draw_rows(camera, rng, count)
    draws = rng.random((count, 3))
    cols = camera.width_px * draws[:, 0]
    sin2 = draws[:, 1]
    tan_theta = np.sqrt(sin2 / np.maximum(1.0 - sin2, 1e-300))
    length_m = np.minimum(depth_m * tan_theta, max_track_length_m)
    azimuth = 2.0 * np.pi * draws[:, 2]
    length_px = length_m / camera.pixel_pitch_m
    delta = np.stack([length_px * np.cos(azimuth), length_px * np.sin(azimuth)], axis=-1)
    start = np.stack([cols, rows], axis=-1) - 0.5 * delta                   # the hit point is the track middle
    charge = charge_e_per_m * np.hypot(length_m, depth_m)
    hit_rows, hit_cols, hit_charge = deposit_tracks((camera.height_px, camera.width_px), start, delta, charge)
    return ParticleHits(hit_rows, hit_cols, hit_charge, count)


def add_to_pixels(pixel_e: np.ndarray, hits: ParticleHits) -> np.ndarray:
    """Add the hits to a full-resolution charge map in place (pixels are unique).

    Parameters
    ----------
    pixel_e : ndarray, shape (H, W)
        Charge per pixel (e-); changed in place.
    hits : ParticleHits
        The hits.

    Returns
    -------
    ndarray, shape (H, W)
        ``pixel_e``.
    """
    pixel_e[hits.rows, hits.cols] += hits.charge_e.astype(pixel_e.dtype)
    return pixel_e


def add_to_binned(binned_e: np.ndarray, hits: ParticleHits, binning_rows: int) -> np.ndarray:
    """Add the hits to a binned charge map in place.

    Parameters
    ----------
    binned_e : ndarray, shape (H / b, W)
        Charge per binned pixel (e-); changed in place.
    hits : ParticleHits
        The hits.
    binning_rows : int
        Rows per block ``b``.

    Returns
    -------
    ndarray, shape (H / b, W)
        ``binned_e``.
    """
    np.add.at(binned_e, (hits.rows // binning_rows, hits.cols), hits.charge_e.astype(binned_e.dtype))
    return binned_e
