"""Dusty atmosphere: orbital I/F -> surface reflectance -> what the descent camera sees (paper section 6).

The paper explains its 3x contrast loss against flight: MOC saw the ground through the whole dusty
column, the descent camera through the ~2 km below it. This stage models both paths with a plane-parallel,
exponentially stratified dust layer in single scattering, Lambertian (isotropic) surface light, and undoes
the orbital one before applying the descent one.

Atmosphere
----------
Zenith optical depth ``tau`` (``orbital_optical_depth``), dust well mixed with the gas (density
``exp(-z / H)``, scale height ``H``, ~11.1 km at the MER sites), so the optical depth *below* altitude
``z`` and *above* it are::

    tau_b(z) = tau (1 - exp(-z / H)),      tau_a(z) = tau exp(-z / H)                           (A1)

Single-scattering albedo ``w`` and a double Henyey-Greenstein phase function of the scattering angle
``Theta`` (normalised to 1 over 4 pi; the form Wolff et al. 2009 and Chen-Chen et al. 2019, Icarus 330,
16 fit to Martian dust)::

    p(Theta) = f HG(g1, Theta) + (1 - f) HG(g2, Theta),
    HG(g, Theta) = (1 - g^2) / (1 + g^2 - 2 g cos Theta)^(3/2)                                  (A2)

Defaults (order-of-magnitude anchors for visible dust, not fitted here): ``w = 0.94`` (dust absorbs in
the blue half of the 0.4-1.1 um DIMES band, ~0.97 in the red), ``g1 = 0.70``, ``g2 = -0.30``, ``f = 0.90``.

Three single-scattering terms (I/F, i.e. pi I / E_sun; ``mu0`` cosine of the solar incidence, ``mu``
cosine of the viewing zenith angle of the line of sight at the ground, ``Theta`` between the sunlight and
the line of sight, ``cos Theta = -cos(phase)``):

* path reflectance of a layer of optical depth ``t`` under ``u`` of dust (the first-order term of the
  layer's reflectance: Chandrasekhar 1960, *Radiative Transfer*; Hansen & Travis 1974, Space Sci. Rev.
  16, 527), the sunlight dimmed by ``exp(-u/mu0)`` before it enters::

      P(u, t; mu0, mu, Theta) = exp(-u / mu0) (w p(Theta) / 4) mu0 / (mu + mu0) (1 - exp(-t (1/mu + 1/mu0)))   (A3)

* direct transmission of the surface light along the line of sight: ``exp(-t / mu)``;
* diffuse transmission: surface light scattered once into the line of sight. The surface seen through
  metres to kilometres of dust is blurred over kilometres, so this light carries the *mean* surface
  brightness, not its detail (adjacency effect). For a Lambertian (isotropic) upwelling field::

      t_d(t, mu) = (w / 2) int_0^1 pbar(mu, mu') mu' (exp(-t / mu') - exp(-t / mu)) / (mu' - mu) dmu'   (A4)

  with ``pbar`` the azimuthal mean of ``p`` between directions of cosines ``mu`` and ``mu'`` on the
  same side of the layer. By reciprocity the same ``t_d(tau, mu0)`` is the diffuse part of the solar
  flux reaching the ground, so the ground irradiance relative to the top of the atmosphere is
  ``E(mu0) = exp(-tau / mu0) + t_d(tau, mu0)``.

Orbital and descent I/F of a ground point of surface I/F ``r(x)`` (mean ``rbar``; geometry: MOC's
``mu0_o, mu_o, Theta_o``, the descent's ``mu0_d, mu_d(x), Theta_d(x)``, ``rho(x)`` the DIMES/MOC
photometric ratio of :mod:`simulator.scene.photometry`)::

    R_orb(x)  = E(mu0_o) [r(x) exp(-tau / mu_o) + rbar t_d(tau, mu_o)]
                + P(0, tau; mu0_o, mu_o, Theta_o)                                                         (A5)
    R_desc(x) = E(mu0_d) rho(x) [r(x) exp(-tau_b / mu_d) + rbar t_d(tau_b, mu_d)]
                + P(tau_a, tau_b; mu0_d, mu_d, Theta_d)                                                   (A6)

Inverting (A5) with the terrain's mean I/F ``Rbar`` for its mean gives, with ``S = E(mu0_o) rbar``::

    S = (Rbar - P_o) / (exp(-tau / mu_o) + t_d(tau, mu_o)),    C_o = S t_d(tau, mu_o) + P_o
    R_desc(x) = rho(x) kappa [max(R_orb(x) - C_o, 0) A(x) + S t_d(tau_b, mu_d)] + P_d(x)                         (A7)
    A(x) = exp(tau / mu_o - tau_b / mu_d),    kappa = E(mu0_d) / E(mu0_o)

(:func:`orbital_haze` computes ``C_o, S``; :func:`descent_factors` ``kappa A``, ``kappa S t_d`` and
``P_d`` on the photometry node grid: they vary slowly over the image). ``tau = 0`` gives ``C_o = 0``,
``A = kappa = 1`` and no added light: the scene without atmosphere, exactly.

What is left out (single scattering): multiple scattering (it brightens the path radiance at
``tau >~ 0.5``), light reflected by the surface and scattered back down by the dust, the sky seen above
the horizon (sky pixels stay 0), and the dust between the camera and the heat shield (a few hundred
metres; the heat shield is drawn unattenuated). Pixels whose orbital I/F is below ``C_o`` are clipped to a
black surface. Shadows darken the surface term only: the path and adjacency light are added after them.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED
from simulator.scene import ground_mapping, photometry

MARS_SCALE_HEIGHT_M = 11100.0       # ~ R T / (M g) at 210 K
MIN_COSINE = 0.02                   # lines of sight and sun cosines are clipped here (grazing, horizon)
_MU_TABLE_SIZE = 129                # mu nodes of the tabulated diffuse transmission (linear in mu)
_MU_PRIME_NODES = 48                # Gauss-Legendre nodes over mu' in (0, 1)
_AZIMUTH_NODES = 128                # trapezoid nodes over the azimuth difference (periodic: spectral accuracy)


def henyey_greenstein(cos_theta: np.ndarray, asymmetry: float) -> np.ndarray:
    """Henyey-Greenstein phase function (A2), normalised to 1 over 4 pi (mean 1 over the sphere).

    Parameters
    ----------
    cos_theta : ndarray
        Cosine of the scattering angle, any shape.
    asymmetry : float
        Asymmetry parameter g, -1 < g < 1.

    Returns
    -------
    ndarray, float64, shape of ``cos_theta``
        Phase function value.
    """
    g = float(asymmetry)
    return (1.0 - g * g) / (1.0 + g * g - 2.0 * g * np.asarray(cos_theta, dtype=float)) ** 1.5


def phase_function(cos_theta: np.ndarray, config) -> np.ndarray:
    """Double Henyey-Greenstein phase function (A2) of the atmosphere's dust.

    Parameters
    ----------
    cos_theta : ndarray
        Cosine of the scattering angle, any shape.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    ndarray, float64, shape of ``cos_theta``
        Phase function value (mean 1 over the sphere).
    """
    f = config.forward_fraction
    return (f * henyey_greenstein(cos_theta, config.forward_asymmetry)
            + (1.0 - f) * henyey_greenstein(cos_theta, config.backward_asymmetry))


def optical_depths(altitude_m: float, config) -> tuple[float, float]:
    """Dust optical depths above and below a camera, (A1).

    The layer below is empty when ``config.descent_path`` is off (the descent camera then sees the ground clear).

    Parameters
    ----------
    altitude_m : float
        Camera height above the ground (m).
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    tau_above, tau_below : float
        Optical depths.
    """
    tau = config.orbital_optical_depth
    if not config.descent_path:
        return tau, 0.0
    above = tau * float(np.exp(-max(float(altitude_m), 0.0) / config.scale_height_m))
    return above, tau - above


def path_reflectance(tau_above: float, tau_layer: float, mu0, mu, cos_scatter, config) -> np.ndarray:
    """Single-scattered path I/F (A3) of a dust layer lying under more dust, seen from above.

    Parameters
    ----------
    tau_above : float
        Optical depth above the layer.
    tau_layer : float
        Optical depth of the layer.
    mu0 : float or ndarray
        Cosine of the solar incidence.
    mu : float or ndarray
        Cosine of the view direction against the vertical, any shape.
    cos_scatter : float or ndarray
        Cosine of the scattering angle.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    ndarray
        Path I/F, the broadcast shape.
    """
    mu0 = np.maximum(np.asarray(mu0, dtype=float), MIN_COSINE)
    mu = np.maximum(np.asarray(mu, dtype=float), MIN_COSINE)
    layer = -np.expm1(-tau_layer * (1.0 / mu + 1.0 / mu0))
    return (np.exp(-tau_above / mu0) * 0.25 * config.single_scattering_albedo
            * phase_function(cos_scatter, config) * mu0 / (mu + mu0) * layer)


@lru_cache(maxsize=16)
def _azimuthal_phase_table(forward_asymmetry: float, backward_asymmetry: float, forward_fraction: float):
    """``pbar(mu_i, mu'_j)``: the phase function averaged over the azimuth difference.

    For the table's ``mu_i`` (linear in (0, 1]) and Gauss-Legendre ``mu'_j`` on (0, 1) with weights ``w_j``.
    """
    mu = np.linspace(MIN_COSINE, 1.0, _MU_TABLE_SIZE)
    nodes, weights = np.polynomial.legendre.leggauss(_MU_PRIME_NODES)
    mu_prime, weights = 0.5 * (nodes + 1.0), 0.5 * weights
    phi = np.linspace(0.0, 2.0 * np.pi, _AZIMUTH_NODES, endpoint=False)
    sin_mu = np.sqrt(1.0 - mu * mu)[:, None, None]
    sin_mu_prime = np.sqrt(1.0 - mu_prime * mu_prime)[None, :, None]
    cos_theta = mu[:, None, None] * mu_prime[None, :, None] + sin_mu * sin_mu_prime * np.cos(phi)[None, None, :]
    f = forward_fraction
    phase = (f * henyey_greenstein(cos_theta, forward_asymmetry)
             + (1.0 - f) * henyey_greenstein(cos_theta, backward_asymmetry))
    return mu, mu_prime, weights, phase.mean(axis=-1)


def _diffuse_table(optical_depth: float, config) -> tuple[np.ndarray, np.ndarray]:
    """(mu nodes, t_d(optical_depth, mu nodes)) of (A4).

    The divided difference is written stably:
    ``mu' (e^{-t/mu'} - e^{-t/mu}) / (mu' - mu) = (t / mu) e^{-t/mu} expm1(x) / x``, ``x = t (mu' - mu) / (mu mu')``.
    """
    mu, mu_prime, weights, pbar = _azimuthal_phase_table(config.forward_asymmetry, config.backward_asymmetry,
                                                         config.forward_fraction)
    t = float(optical_depth)
    if t <= 0.0:
        return mu, np.zeros_like(mu)
    x = t * (mu_prime[None, :] - mu[:, None]) / (mu[:, None] * mu_prime[None, :])
    small = np.abs(x) < 1e-8
    ratio = np.where(small, 1.0 + 0.5 * x, np.expm1(x) / np.where(small, 1.0, x))
    kernel = (t / mu)[:, None] * np.exp(-t / mu)[:, None] * ratio
    return mu, 0.5 * config.single_scattering_albedo * (pbar * kernel) @ weights


def diffuse_transmission(optical_depth: float, mu, config) -> np.ndarray:
    """Diffuse transmission (A4) of an isotropic upwelling field into a direction.

    Equally the diffuse fraction of a solar beam at ``mu`` reaching the ground. Tabulated in mu and
    interpolated linearly.

    Parameters
    ----------
    optical_depth : float
        Optical depth of the dust.
    mu : float or ndarray
        Cosine of the direction against the vertical, any shape.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    ndarray, shape of ``mu``
        Diffuse transmission; 0 when ``config.diffuse_transmission`` is off.
    """
    mu = np.asarray(mu, dtype=float)
    if not config.diffuse_transmission or optical_depth <= 0.0:
        return np.zeros_like(mu)
    nodes, values = _diffuse_table(optical_depth, config)
    return np.interp(np.maximum(mu, MIN_COSINE), nodes, values)


def illumination(optical_depth: float, mu0: float, config) -> float:
    """Ground irradiance from the sun relative to no atmosphere: ``exp(-tau/mu0) + t_d(tau, mu0)``.

    Parameters
    ----------
    optical_depth : float
        Optical depth of the dust.
    mu0 : float
        Cosine of the solar incidence.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    float
        Relative irradiance.
    """
    mu0 = max(float(mu0), MIN_COSINE)
    return float(np.exp(-optical_depth / mu0) + diffuse_transmission(optical_depth, mu0, config))


@dataclass(frozen=True)
class OrbitalHaze:
    """The orbital atmosphere of one terrain image (I/F units; see (A7)).

    Attributes
    ----------
    offset_if : float
        ``C_o`` = adjacency light + path I/F, removed from the orbital I/F.
    surface_mean_if : float
        ``S`` = mean surface I/F under the atmosphere's illumination at MOC's sun.
    path_if : float
        ``P_o``, the orbital path I/F.
    transmission : float
        ``exp(-tau / mu_o)``.
    illumination : float
        ``E(mu0_o)``.
    terrain_mean_if : float
        The terrain image's mean I/F ``Rbar``.
    """

    offset_if: float
    surface_mean_if: float
    path_if: float
    transmission: float
    illumination: float
    terrain_mean_if: float


def orbital_haze(terrain, config) -> OrbitalHaze:
    """The orbital haze of a terrain for an atmosphere; cached on the terrain per configuration.

    Parameters
    ----------
    terrain : simulator.scene.terrain.Terrain
        The orbital image with its MOC geometry.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    OrbitalHaze
        The orbital atmosphere's terms.

    Raises
    ------
    ValueError
        When the orbital path I/F is not below the terrain's mean I/F (the inversion would need a
        negative surface): the optical depth is too large for this terrain.
    """
    cache = DERIVED.of(terrain, "scene")
    key = ("orbital_haze", config)
    if key in cache:
        return cache[key]
    if "mean_if" not in cache:
        cache["mean_if"] = float(np.mean(terrain.reflectance_if, dtype=np.float64))
    mean_if = cache["mean_if"]
    tau = config.orbital_optical_depth
    mu0 = float(np.cos(terrain.moc_incidence_rad))
    mu = max(float(np.cos(terrain.moc_emission_rad)), MIN_COSINE)
    path = float(path_reflectance(0.0, tau, mu0, mu, -np.cos(terrain.moc_phase_rad), config))
    transmission = float(np.exp(-tau / mu))
    adjacency = float(diffuse_transmission(tau, mu, config))
    surface = (mean_if - path) / (transmission + adjacency)
    if not surface > 0.0:
        raise ValueError(f"scene.atmosphere: orbital path I/F {path:.4f} at orbital_optical_depth {tau:g} is not below "
                         f"terrain {terrain.name}'s mean I/F {mean_if:.4f}; allowed: a smaller optical depth")
    haze = OrbitalHaze(offset_if=surface * adjacency + path, surface_mean_if=surface, path_if=path,
                       transmission=transmission, illumination=illumination(tau, mu0, config), terrain_mean_if=mean_if)
    cache[key] = haze
    return haze


def remove_orbital_haze(orbital_if: np.ndarray, haze: OrbitalHaze) -> np.ndarray:
    """``max(R_orb - C_o, 0)`` in place; the caller's sky pixels (0) stay 0.

    Parameters
    ----------
    orbital_if : ndarray, shape (H, W), float32
        Orbital I/F resampled to the image; changed in place.
    haze : OrbitalHaze
        The orbital atmosphere.

    Returns
    -------
    ndarray, shape (H, W), float32
        ``orbital_if``.
    """
    cv2.subtract(orbital_if, float(haze.offset_if), dst=orbital_if)  # type: ignore[call-overload]  # cv2 stubs: no scalar
    cv2.threshold(orbital_if, 0.0, 0.0, cv2.THRESH_TOZERO, dst=orbital_if)   # one pass each (numpy: 2x slower)
    return orbital_if


def descent_factors(view_to_camera: np.ndarray, sun_world: np.ndarray, altitude_m: float, haze: OrbitalHaze,
                    config) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The descent terms of (A7) along unit ground-to-camera directions.

    ``R_desc = rho (max(R_orb - C_o, 0) gain + adjacency_if) + path_if``.

    Parameters
    ----------
    view_to_camera : ndarray, shape (..., 3)
        Unit ground-to-camera directions.
    sun_world : ndarray, shape (3,)
        World unit vector toward the sun.
    altitude_m : float
        Camera height above the ground (m).
    haze : OrbitalHaze
        The orbital atmosphere.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.

    Returns
    -------
    gain : ndarray, shape (...), float32
        ``kappa A``.
    adjacency_if : ndarray, shape (...), float32
        ``kappa S t_d(tau_b, mu_d)``.
    path_if : ndarray, shape (...), float32
        ``P_d``.
    """
    view = np.asarray(view_to_camera, dtype=float)
    sun = np.asarray(sun_world, dtype=float)
    tau = config.orbital_optical_depth
    tau_above, tau_below = optical_depths(altitude_m, config)
    mu = np.maximum(view[..., 2], MIN_COSINE)
    mu0 = float(sun[2])
    kappa = illumination(tau, mu0, config) / haze.illumination
    gain = kappa * np.exp(-tau_below / mu) / haze.transmission
    adjacency = kappa * haze.surface_mean_if * diffuse_transmission(tau_below, mu, config)
    path = path_reflectance(tau_above, tau_below, mu0, mu, -(view @ sun), config)
    return gain.astype(np.float32), adjacency.astype(np.float32), path.astype(np.float32)


def descent_fields(camera: Camera, pose: ground_mapping.CameraPose, ground_map: ground_mapping.GroundMap,
                      sun: np.ndarray, moc_value: float | None, scale: float, haze: OrbitalHaze,
                      config, grid_step_px: int) -> tuple[np.ndarray, np.ndarray]:
    """The descent side of the atmosphere, (A7), as two fields.

    ``rho`` is the photometric ratio (1 when ``moc_value`` is None: no photometric correction). On the
    node grid when ``grid_step_px > 0`` (the terms vary slowly), else per pixel.

    Parameters
    ----------
    camera : Camera
        The camera.
    pose : CameraPose
        The camera's world pose.
    ground_map : GroundMap
        The pose's ground map.
    sun : ndarray, shape (3,)
        World unit vector toward the sun.
    moc_value : float or None
        The MOC geometry's reflectance model value, None without photometric correction.
    scale : float
        Radiometric scale: I/F -> radiance (W m^-2 sr^-1 um^-1).
    haze : OrbitalHaze
        The orbital atmosphere.
    config : simulator.scene_config.AtmosphereConfig
        The atmosphere.
    grid_step_px : int
        Node spacing (px), 0 for per pixel.

    Returns
    -------
    gain : ndarray, shape (H, W), float32
        ``scale rho kappa A``: multiplies the haze-free orbital I/F.
    added : ndarray, shape (H, W), float32
        ``scale (rho kappa S t_d + P_d)``: adjacency and path radiance (W m^-2 sr^-1 um^-1) added after shadows.
    """
    view = ground_mapping.view_directions(camera, pose, ground_map, grid_step_px)
    gain, adjacency, path = descent_factors(view, sun, pose.altitude_m, haze, config)
    ratio = np.float32(1.0) if moc_value is None else photometry.photometric_ratio(view, sun, moc_value)
    gain = gain * ratio * np.float32(scale)
    added = (adjacency * ratio + path) * np.float32(scale)
    return (ground_mapping.field_at_pixels(gain, camera, grid_step_px),
            ground_mapping.field_at_pixels(added, camera, grid_step_px))
