"""The dust map's compiled pass: the overlapping (node, particle) pairs of a transmission map.

:func:`simulator.off_nominal.dust.transmission_map` calls :func:`near_pairs`.

Kept apart from :mod:`simulator.off_nominal.dust` so that declaring ``[scene.off_nominal]`` (which imports the
dust module's particle types) loads no numba: :func:`~simulator.off_nominal.dust.transmission_map` imports this
module when it first makes a map.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def near_pairs(x: np.ndarray, y: np.ndarray, positions: np.ndarray, radii: np.ndarray, pupil: float,
                particles: np.ndarray, row0: np.ndarray, row1: np.ndarray, col0: np.ndarray,
                col1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (node, particle) pairs whose beam and particle discs overlap, particle by particle, each box row-major.

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
        The particles to pair, in order.
    row0, row1, col0, col1 : ndarray, shape (k,), int64
        Each particle's box of nodes (end exclusive; empty when end <= start).

    Returns
    -------
    node : ndarray, int64
        Flat node index of each overlapping pair.
    radius : ndarray
        The pair's particle radius (m).
    separation : ndarray
        Distance between the beam centre and the particle centre (m).
    """
    total = 0
    for index in range(particles.size):
        total += max(row1[index] - row0[index], 0) * max(col1[index] - col0[index], 0)
    node = np.empty(total, dtype=np.int64)
    radius = np.empty(total)
    separation = np.empty(total)
    count = 0
    width = x.shape[1]
    for index in range(particles.size):
        particle = particles[index]
        centre_x, centre_y, particle_radius = positions[particle, 0], positions[particle, 1], radii[particle]
        reach = pupil + particle_radius
        for row in range(row0[index], row1[index]):
            for col in range(col0[index], col1[index]):
                distance = np.hypot(x[row, col] - centre_x, y[row, col] - centre_y)
                if distance < reach:
                    node[count] = row * width + col
                    radius[count] = particle_radius
                    separation[count] = distance
                    count += 1
    return node[:count], radius[:count], separation[:count]
