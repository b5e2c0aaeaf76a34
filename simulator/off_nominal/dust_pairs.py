"""The dust map's compiled passes: which node beams each particle overlaps, then the nodes' log-transmission sums.

:func:`simulator.off_nominal.dust.transmission_map` calls :func:`overlapping_nodes` (which also does the transition
band's lens-area arithmetic up to the arc cosines), takes the arc cosines and logs with numpy (vectorised: several
times faster than one libm call per pair, and numpy's bits), then :func:`node_log_sums`.

Kept apart from :mod:`simulator.off_nominal.dust` so that declaring ``[scene.off_nominal]`` (which imports the
dust module's particle types) loads no numba: :func:`~simulator.off_nominal.dust.transmission_map` imports this
module when it first makes a map.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: relative margin of the squared-distance pre-tests: a node whose squared distance exceeds the squared reach by this
#: much is beyond the reach, one whose squared distance is below the squared core edge by this much is inside the
#: core, whatever the rounding of ``hypot`` and of the squares (each good to a few 1e-16); only the nodes between
#: the margins take ``hypot``, which decides as the distance it returns says
SQUARED_MARGIN = 1e-9


@njit(cache=True, nogil=True)
def overlapping_nodes(x: np.ndarray, y: np.ndarray, positions: np.ndarray, radii: np.ndarray, pupil: float,
                      particles: np.ndarray, row0: np.ndarray, row1: np.ndarray, col0: np.ndarray,
                      col1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The nodes whose beam disc each particle's disc overlaps, split into the shadow's core and transition band.

    A pair overlaps when the separation ``s = hypot(node - particle)`` is below ``pupil + radius``; it is in the
    core when ``s <= |pupil - radius|`` (one disc inside the other: the blocked area is the smaller disc), in the
    band otherwise (the blocked area is the lens of two crossing circles). Particles in the given order, each box
    row by row. For a band pair, the terms of the lens area of :func:`simulator.off_nominal.dust.overlap_area`
    (same arithmetic, step for step; ``R`` the pupil, ``a`` the radius)::

        lens = R^2 acos(cos_a) + a^2 acos(cos_b) - half_root
        cos_a = clip((s^2 + R^2 - a^2) / (2 s R), -1, 1),  cos_b = clip((s^2 + a^2 - R^2) / (2 s a), -1, 1)
        half_root = sqrt(max((-s + R + a)(s + R - a)(s - R + a)(s + R + a), 0)) / 2

    Parameters
    ----------
    x, y : ndarray, shape (ny, nx)
        Beam centres of the nodes on the front element (m).
    positions : ndarray, shape (n, 2)
        Particle centres (m).
    radii : ndarray, shape (n,)
        Particle radii (m).
    pupil : float
        Beam (entrance pupil) radius (m).
    particles : ndarray, shape (k,), int64
        The particles to pair (indices into ``positions`` and ``radii``), in order.
    row0, row1, col0, col1 : ndarray, shape (k,), int64
        Each particle's box of nodes (end exclusive; empty when end <= start).

    Returns
    -------
    core_nodes : ndarray, shape (c,), int32
        Flat node index of each core pair.
    core_end : ndarray, shape (k,), int64
        End of each particle's run in ``core_nodes`` (particle i's run starts at ``core_end[i - 1]``, or 0).
    band_nodes : ndarray, shape (b,), int32
        Flat node index of each band pair.
    band_terms : ndarray, shape (4, b)
        Per band pair: ``cos_a``, ``cos_b``, ``a^2`` (m^2) and ``half_root`` (m^2).
    band_end : ndarray, shape (k,), int64
        End of each particle's run in the band arrays.
    """
    box_nodes = 0
    for index in range(particles.size):
        box_nodes += max(row1[index] - row0[index], 0) * max(col1[index] - col0[index], 0)
    core_nodes = np.empty(box_nodes, dtype=np.int32)
    band_nodes = np.empty(box_nodes, dtype=np.int32)
    band_terms = np.empty((4, box_nodes))
    core_end = np.empty(particles.size, dtype=np.int64)
    band_end = np.empty(particles.size, dtype=np.int64)
    core_count = band_count = 0
    width = x.shape[1]
    for index in range(particles.size):
        particle = particles[index]
        centre_x, centre_y, particle_radius = positions[particle, 0], positions[particle, 1], radii[particle]
        reach = pupil + particle_radius
        core_edge = abs(pupil - particle_radius)
        reach_squared_bound = reach * reach * (1.0 + SQUARED_MARGIN)
        core_squared_bound = core_edge * core_edge * (1.0 - SQUARED_MARGIN)
        pupil_squared, radius_squared = pupil * pupil, particle_radius * particle_radius
        for row in range(row0[index], row1[index]):
            for col in range(col0[index], col1[index]):
                offset_x, offset_y = x[row, col] - centre_x, y[row, col] - centre_y
                distance_squared = offset_x * offset_x + offset_y * offset_y
                if distance_squared > reach_squared_bound:
                    continue
                if distance_squared >= core_squared_bound:
                    distance = np.hypot(offset_x, offset_y)
                    if distance >= reach:
                        continue
                    if distance > core_edge:
                        band_nodes[band_count] = row * width + col
                        separation_squared = distance * distance
                        band_terms[0, band_count] = min(max(
                            (separation_squared + pupil_squared - radius_squared) / (2.0 * distance * pupil), -1.0), 1.0)
                        band_terms[1, band_count] = min(max(
                            (separation_squared + radius_squared - pupil_squared) / (2.0 * distance * particle_radius),
                            -1.0), 1.0)
                        kite = ((-distance + pupil + particle_radius) * (distance + pupil - particle_radius)
                                * (distance - pupil + particle_radius) * (distance + pupil + particle_radius))
                        band_terms[2, band_count] = radius_squared
                        band_terms[3, band_count] = 0.5 * np.sqrt(max(kite, 0.0))
                        band_count += 1
                        continue
                core_nodes[core_count] = row * width + col
                core_count += 1
        core_end[index] = core_count
        band_end[index] = band_count
    return core_nodes[:core_count], core_end, band_nodes[:band_count], band_terms[:, :band_count], band_end


@njit(cache=True, nogil=True)
def node_log_sums(node_count: int, core_log: np.ndarray, core_nodes: np.ndarray, core_end: np.ndarray,
                  band_nodes: np.ndarray, band_log: np.ndarray, band_end: np.ndarray) -> np.ndarray:
    """Sum at every node the log transmission of the particles overlapping its beam, particle by particle.

    Each node takes at most one term per particle, and the terms arrive in particle order: the order, hence the
    bits, of a ``bincount`` over the pairs listed particle by particle.

    Parameters
    ----------
    node_count : int
        Number of nodes (ny nx).
    core_log : ndarray, shape (k,)
        Log of the transmitted fraction in each particle's core (-inf for a black core).
    core_nodes, core_end, band_nodes, band_end : ndarray
        The pairs of :func:`overlapping_nodes`.
    band_log : ndarray, shape (b,)
        Log of the transmitted fraction of each band pair (-inf when nothing passes).

    Returns
    -------
    ndarray, shape (node_count,), float64
        Log of each node's transmission (0 where no particle overlaps the beam).
    """
    log_sum = np.zeros(node_count)
    core_start = band_start = 0
    for index in range(core_end.size):
        particle_core_log = core_log[index]
        for pair in range(core_start, core_end[index]):
            log_sum[core_nodes[pair]] += particle_core_log
        for pair in range(band_start, band_end[index]):
            log_sum[band_nodes[pair]] += band_log[pair]
        core_start, band_start = core_end[index], band_end[index]
    return log_sum
