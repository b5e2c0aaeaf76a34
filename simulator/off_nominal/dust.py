"""Dust on the front lens element: a fixed transmission map of soft, out-of-focus particle shadows.

Model (paper 3.3, "a random number of random sized particles distributed randomly on the front
surface"; lengths in m, image coordinates in pixels):

* Optics: focal length ``f`` (from the CAHVOR model, ``f = sqrt(hs vs) * pixel_pitch``), focal ratio
  ``N`` (f/12), so the entrance pupil has diameter ``D = f / N`` (1.22 mm for MER) and radius
  ``R = D / 2``. The front element is a plane perpendicular to the optical axis at ``d``
  (``dust_lens_distance_m``) in front of the entrance pupil.
* Light bundle of a pixel: light from a distant scene point reaches the pixel as a collimated beam
  filling the entrance pupil. On the front-element plane that beam is a disc of radius ``R``
  (the pupil's cos(theta) foreshortening and the plane's 1/cos(theta) stretch cancel) centred on
  the chief ray, at ``c = d * (tan theta_x, tan theta_y)`` where ``(tan theta_x, tan theta_y)`` are
  the pixel ray's components across the axis divided by its axial component (distortion included,
  from :attr:`Camera.pixel_rays`).
* A particle is an opaque disc of radius ``a`` at ``p`` on the front element. It removes the
  overlapping area of the two discs from the bundle::

      t(c) = 1 - A_overlap(R, a, |c - p|) / (pi R^2)

  ``A_overlap`` is the circle-circle intersection (lens) area. For ``a < R`` the shadow is a disc of
  flat depth ``(a / R)^2`` out to ``|c - p| = R - a``, rising to 1 at ``R + a``; in the image it is
  centred where the chief ray meets ``p`` (tan theta = p / d) with radius ``(R + a) f_px / d``
  pixels (about 95 px for R = 0.61 mm, d = 8 mm) - the soft disc seen in real out-of-focus dust.
  For ``a > R`` the core is black. The area integral of ``1 - t`` over the image plane is the
  particle area magnified by ``f_px / d``: ``pi a^2 (f_px / d)^2`` pixels (tested).
* Several particles: independent obscurations multiply, ``t = prod_k t_k``.
* Population (per case, fixed for the three images): the count is Poisson with mean
  ``dust_particle_count``; positions are uniform over the front element's clear aperture, the disc
  of radius ``d * tan(theta_corner) + R`` that every image pixel's beam lies in; diameters follow an
  exponential distribution of scale ``dust_particle_diameter_mean_m`` truncated at
  ``dust_particle_diameter_max_m`` (the truncated mean is slightly below the scale).

Diffraction by the particle edge and the glass's own reflections are neglected (geometric optics:
the particle is hundreds of wavelengths across and ~5000 pupil-to-wavelength Fresnel numbers away).

Cost: the map is evaluated on nodes every :data:`NODE_STEP_PX` pixels (one node beyond each edge), each
particle touching only the nodes in the bounding box of its shadow, and interpolated bilinearly to every
pixel once (one full-frame pass per case, whatever the particle count). The nodes take two compiled passes
(:mod:`simulator.off_nominal.dust_pairs`: each particle's core and band nodes, then the log sums particle by
particle) around numpy's arc cosines and logs of the band pairs. The shadow is smooth on that
scale: its transition band is ``2 a f_px / d`` pixels wide (~23 px at the mean diameter) and a band
narrower than the node step belongs to a particle whose depth ``(a / R)^2`` is below 1e-3; measured
against the per-pixel evaluation (:func:`transmission_map_exact`) on 100-particle populations: max
|difference| 1.3e-3, mean 5e-5 (tests: < 2e-3, < 1e-4).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flight_interface import cahvor
from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED
from simulator.scene import node_grid

NODE_STEP_PX = 4


@dataclass(frozen=True)
class DustParticles:
    """Dust particles on the front lens element.

    Attributes
    ----------
    positions_m : ndarray, shape (n, 2)
        Positions across the optical axis (along the image columns and rows), m.
    diameters_m : ndarray, shape (n,)
        Diameters (m).
    """

    positions_m: np.ndarray
    diameters_m: np.ndarray


def focal_length_m(camera: Camera) -> float:
    """Effective focal length of the CAHVOR model.

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    float
        Focal length (m).
    """
    return float(np.sqrt(camera.model.hs * camera.model.vs)) * camera.pixel_pitch_m


def entrance_pupil_radius_m(camera: Camera) -> float:
    """Radius of the entrance pupil, ``f / (2 N)``.

    Parameters
    ----------
    camera : Camera
        The camera (focal length, focal ratio N).

    Returns
    -------
    float
        Radius (m).
    """
    return 0.5 * focal_length_m(camera) / camera.radiometry.f_number


def _axis_basis(camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors (e1 along the image columns, e2 along the rows, optical axis O)."""
    axis = camera.model.o / np.linalg.norm(camera.model.o)
    e1 = camera.model.h - (camera.model.h @ axis) * axis
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1), axis


def beam_centres_m(camera: Camera, distance_m: float, rows: slice = slice(None),
                   cols: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel's chief ray crosses the front-element plane.

    Parameters
    ----------
    camera : Camera
        The camera.
    distance_m : float
        Distance of the front element from the entrance pupil (m).
    rows, cols : slice, optional
        Pixel window (default: the whole frame).

    Returns
    -------
    x, y : ndarray, shape (h, w)
        Crossing point of each pixel of the window (m).
    """
    e1, e2, axis = _axis_basis(camera)
    rays = camera.pixel_rays[rows, cols]
    along = rays @ axis
    return distance_m * (rays @ e1) / along, distance_m * (rays @ e2) / along


def clear_aperture_radius_m(camera: Camera, distance_m: float) -> float:
    """Radius of the front-element region crossed by any pixel's beam.

    Parameters
    ----------
    camera : Camera
        The camera.
    distance_m : float
        Distance of the front element from the entrance pupil (m).

    Returns
    -------
    float
        Radius (m).
    """
    corners = (slice(0, None, camera.height_px - 1), slice(0, None, camera.width_px - 1))
    x, y = beam_centres_m(camera, distance_m, *corners)
    return float(np.hypot(x, y).max()) + entrance_pupil_radius_m(camera)


def overlap_area(radius_a: float | np.ndarray, radius_b: float | np.ndarray, separation) -> np.ndarray:
    """Intersection area of two discs.

    Parameters
    ----------
    radius_a, radius_b : float or ndarray
        Radii of the discs (any one length unit).
    separation : float or ndarray
        Distance between their centres (same unit); arrays broadcast.

    Returns
    -------
    ndarray
        Area (the unit squared).
    """
    ra, rb = np.asarray(radius_a, dtype=float), np.asarray(radius_b, dtype=float)
    s = np.asarray(separation, dtype=float)
    small, large = np.minimum(ra, rb), np.maximum(ra, rb)
    inside = s <= large - small
    apart = s >= ra + rb
    safe = np.where(inside | apart, 1.0, s)
    cos_a = np.clip((safe**2 + ra**2 - rb**2) / (2 * safe * ra), -1.0, 1.0)
    cos_b = np.clip((safe**2 + rb**2 - ra**2) / (2 * safe * rb), -1.0, 1.0)
    kite = (-safe + ra + rb) * (safe + ra - rb) * (safe - ra + rb) * (safe + ra + rb)
    lens = ra**2 * np.arccos(cos_a) + rb**2 * np.arccos(cos_b) - 0.5 * np.sqrt(np.maximum(kite, 0.0))
    return np.where(apart, 0.0, np.where(inside, np.pi * small**2, lens))


def draw_particles(camera: Camera, rng: np.random.Generator, mean_count: float, diameter_scale_m: float,
                   diameter_max_m: float, distance_m: float) -> DustParticles:
    """A random dust population on the front element.

    Poisson count, uniform positions over the clear aperture, truncated exponential diameters (module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    rng : numpy.random.Generator
        The case's dust stream.
    mean_count : float
        Mean number of particles.
    diameter_scale_m : float
        Mean of the exponential diameter distribution (m).
    diameter_max_m : float
        Largest diameter (m).
    distance_m : float
        Distance of the front element from the entrance pupil (m).

    Returns
    -------
    DustParticles
        The particles.
    """
    count = int(rng.poisson(mean_count))
    radius = clear_aperture_radius_m(camera, distance_m)
    uniform = rng.random((count, 3))
    r = radius * np.sqrt(uniform[:, 0])
    phi = 2.0 * np.pi * uniform[:, 1]
    kept = -np.expm1(-diameter_max_m / diameter_scale_m)         # CDF at the maximum
    diameters = -diameter_scale_m * np.log1p(-uniform[:, 2] * kept)
    return DustParticles(np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1), diameters)


def _node_beam_centres_m(camera: Camera, distance_m: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Beam centres (x, y) on the front element at the nodes (cached per camera and distance).

    Node k along an axis sits at pixel ``(k + 0.5) step - 0.5``, k = -1 .. size / step; and the first node's pixel.
    """
    cache = DERIVED.of(camera, "dust")
    key = ("nodes", NODE_STEP_PX, float(distance_m))
    if key not in cache:
        first = -0.5 * NODE_STEP_PX - 0.5
        cols = first + NODE_STEP_PX * np.arange(camera.width_px // NODE_STEP_PX + 2)
        rows = first + NODE_STEP_PX * np.arange(camera.height_px // NODE_STEP_PX + 2)
        rays = cahvor.unproject(camera.model, np.stack(np.meshgrid(cols, rows), axis=-1))
        e1, e2, axis = _axis_basis(camera)
        along = rays @ axis
        cache[key] = (distance_m * (rays @ e1) / along, distance_m * (rays @ e2) / along, first)
    return cache[key]


def _map_optics(camera: Camera) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
    """The camera's constants of a map (cached per camera): pupil radius (m), focal length (px), axis basis."""
    cache = DERIVED.of(camera, "dust")
    if "optics" not in cache:
        cache["optics"] = (entrance_pupil_radius_m(camera), max(camera.model.hs, camera.model.vs),
                           *_axis_basis(camera))
    return cache["optics"]


def _band_log_transmission(band_terms: np.ndarray, pupil_m: float, pupil_area_m2: float) -> np.ndarray:
    """Log of the light left in the beam by each transition-band pair: the last steps of the lens area, in place.

    ``log(clip(1 - (R^2 acos(cos_a) + a^2 acos(cos_b) - half_root) / (pi R^2), 0, 1))``, each step the
    arithmetic of :func:`overlap_area`'s lens and of the blocked fraction (numpy's arc cosine and log).

    Parameters
    ----------
    band_terms : ndarray, shape (4, b)
        ``cos_a``, ``cos_b``, ``a^2`` (m^2), ``half_root`` (m^2) per band pair
        (:func:`simulator.off_nominal.dust_pairs.overlapping_nodes`); overwritten.
    pupil_m : float
        Beam (entrance pupil) radius R (m).
    pupil_area_m2 : float
        Beam area ``pi R^2`` (m^2).

    Returns
    -------
    ndarray, shape (b,)
        Natural log of the transmitted fraction (-inf where nothing passes); a view of ``band_terms``.
    """
    cos_a, cos_b, radius_squared, half_root = band_terms
    lens = np.arccos(cos_a, out=cos_a)
    lens *= np.asarray(pupil_m) ** 2
    lens += np.multiply(radius_squared, np.arccos(cos_b, out=cos_b), out=cos_b)
    lens -= half_root
    lens /= pupil_area_m2
    transmitted = np.subtract(1.0, lens, out=lens)
    with np.errstate(divide="ignore"):
        return np.log(np.clip(transmitted, 0.0, 1.0, out=transmitted), out=transmitted)


def transmission_map(camera: Camera, particles: DustParticles, distance_m: float) -> np.ndarray:
    """Relative transmission of every pixel, evaluated on the node grid and interpolated (module doc).

    Parameters
    ----------
    camera : Camera
        The camera.
    particles : DustParticles
        The dust on the front element.
    distance_m : float
        Distance of the front element from the entrance pupil (m).

    Returns
    -------
    ndarray, shape (H, W), float32
        Transmission, 1 where no particle shadows the pixel's beam.
    """
    x, y, first = _node_beam_centres_m(camera, distance_m)
    pupil, focal_px, e1, e2, axis = _map_optics(camera)
    radii = 0.5 * np.asarray(particles.diameters_m, dtype=float)
    positions = np.asarray(particles.positions_m, dtype=float).reshape(-1, 2)
    directions = (positions[:, :1] * e1 + positions[:, 1:] * e2) / distance_m + axis
    centres, in_front = cahvor.project(camera.model, camera.model.c + directions)
    seen = np.flatnonzero(np.atleast_1d(in_front))
    if not seen.size:
        return np.ones((camera.height_px, camera.width_px), dtype=np.float32)
    # each particle's box of nodes (its shadow's bounding box); the compiled pass lists the nodes whose beam the
    # particle overlaps, in its shadow's core (blocking the smaller disc) or transition band (a lens area)
    half = 1.1 * (pupil + radii[seen]) / distance_m * focal_px + 3.0 + NODE_STEP_PX
    col0 = np.maximum(((centres[seen, 0] - half - first) / NODE_STEP_PX).astype(np.int64), 0)
    col1 = np.minimum(((centres[seen, 0] + half - first) / NODE_STEP_PX).astype(np.int64) + 2, x.shape[1])
    row0 = np.maximum(((centres[seen, 1] - half - first) / NODE_STEP_PX).astype(np.int64), 0)
    row1 = np.minimum(((centres[seen, 1] + half - first) / NODE_STEP_PX).astype(np.int64) + 2, x.shape[0])
    from simulator.off_nominal.dust_pairs import node_log_sums, overlapping_nodes  # numba: with a map, not the config

    core_nodes, core_end, band_nodes, band_terms, band_end = overlapping_nodes(
        np.ascontiguousarray(x), np.ascontiguousarray(y), positions, radii, float(pupil), seen.astype(np.int64),
        row0, row1, col0, col1)
    if not (core_nodes.size or band_nodes.size):     # no beam overlaps a particle (all outside the frame)
        return np.ones((camera.height_px, camera.width_px), dtype=np.float32)
    pupil_area = np.pi * pupil**2
    with np.errstate(divide="ignore"):     # a black core (a > R) is log 0 = -inf: transmission 0
        core_log = np.log(np.clip(1.0 - np.pi * np.minimum(pupil, radii[seen])**2 / pupil_area, 0.0, 1.0))
        band_log = _band_log_transmission(band_terms, float(pupil), pupil_area)
    log_sum = node_log_sums(x.size, core_log, core_nodes, core_end, band_nodes, band_log, band_end)
    nodes = np.exp(log_sum).reshape(x.shape).astype(np.float32)
    return node_grid.upsample_nodes_contiguous(nodes, NODE_STEP_PX, camera.height_px, camera.width_px)


def transmission_map_exact(camera: Camera, particles: DustParticles, distance_m: float) -> np.ndarray:
    """Relative transmission of every pixel evaluated pixel by pixel (the reference of :func:`transmission_map`).

    Parameters
    ----------
    camera : Camera
        The camera.
    particles : DustParticles
        The dust on the front element.
    distance_m : float
        Distance of the front element from the entrance pupil (m).

    Returns
    -------
    ndarray, shape (H, W), float32
        Transmission, 1 where no particle shadows the pixel's beam.
    """
    transmission = np.ones((camera.height_px, camera.width_px), dtype=np.float32)
    pupil = entrance_pupil_radius_m(camera)
    e1, e2, axis = _axis_basis(camera)
    focal_px = max(camera.model.hs, camera.model.vs)
    for (px, py), diameter in zip(particles.positions_m, particles.diameters_m):
        a = 0.5 * float(diameter)
        direction = (px * e1 + py * e2) / distance_m + axis
        centre, in_front = cahvor.project(camera.model, camera.model.c + direction)
        if not in_front:
            continue
        half = 1.1 * (pupil + a) / distance_m * focal_px + 3.0
        col0, col1 = max(int(centre[0] - half), 0), min(int(centre[0] + half) + 2, camera.width_px)
        row0, row1 = max(int(centre[1] - half), 0), min(int(centre[1] + half) + 2, camera.height_px)
        if col1 <= col0 or row1 <= row0:
            continue
        x, y = beam_centres_m(camera, distance_m, slice(row0, row1), slice(col0, col1))
        blocked = overlap_area(pupil, a, np.hypot(x - px, y - py)) / (np.pi * pupil**2)
        transmission[row0:row1, col0:col1] *= (1.0 - blocked).astype(np.float32)
    return transmission
