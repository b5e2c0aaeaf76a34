"""Photometry of the Martian surface: phase function, MOC -> DIMES reflectance ratio, solar irradiance.

Paper section 3.2, equations (1)-(3)::

    I/F = [mu0 / (mu + mu0)] f(alpha)                                        (1)
    f(alpha < 10 deg)        = 2.05 - 3.93e-2 a + 2.09e-3 a^2 - 4.86e-5 a^3
                               + 4.93e-7 a^4 - 1.72e-9 a^5                    (2)
    f(10 deg < alpha < 60 deg) = 1.82 - 1.03e-2 (a - 10)                     (3)

with ``a`` the phase angle in degrees (the paper prints the ranges of (3) as "10 > alpha > 60", an empty
range; we read them as 10 < alpha < 60, where (3) continues (2) at 10 deg). Equation (2) ends at f(10) = 1.8222 and (3) starts at
1.82: the 0.12 % step is the paper's own and is kept. **Beyond 60 deg** the paper gives nothing; we
continue (3) linearly (the same slope), which is continuous at 60 deg and stays positive up to 186 deg,
and clip f at ``PHASE_FUNCTION_FLOOR`` so no geometry ever yields a non-positive reflectance. DIMES
images see phase angles up to about 33 + 52 = 85 deg, so the extension is used only at image edges of
tilted views with a high sun.

The orbital image already contains the photometric term of *its* geometry (MOC incidence, emission,
phase, nearly constant over the narrow-angle strip). The DIMES reflectance of a ground point is the
MOC value times the ratio of equation (1) at the DIMES geometry to equation (1) at the MOC geometry
(:func:`photometric_ratio`). On a level ground plane the vector from a ground point to the camera is
minus the pixel's ray, so the ratio depends only on the ray direction and the sun vector.

Solar irradiance (documented number)
------------------------------------
I is the surface radiance and pi F the solar irradiance normal to the sun vector, so the radiance of a
ground point is ``L = (I/F) * E_band / pi`` with E_band the band-mean spectral irradiance at Mars.
We take the Sun as a 5772 K blackbody scaled to the total solar irradiance 1361 W m^-2 at 1 AU: the
DIMES band 0.4-1.1 um then holds 64.4 % of it, 876 W m^-2, a band mean of
``SOLAR_BAND_IRRADIANCE_1AU_W_M2_UM = 1251`` W m^-2 um^-1 at 1 AU, scaled by 1/r^2 (r in AU; Mars
mean 1.524 AU -> 539 W m^-2 um^-1, so I/F 0.25 gives L = 42.9 W m^-2 sr^-1 um^-1). The real solar
spectrum has a few per cent less blue light than the blackbody; the MOC->DIMES spectral ratio factor
absorbs band-shape differences.

Spectral ratio (documented number)
----------------------------------
MOC NA saw 0.5-0.9 um, DIMES 0.4-1.1 um. The ratio of the band-mean reflectances of an average bright
Martian soil (values read from the Pathfinder IMP spectra of Maki et al. 1999, table
``MARS_SOIL_REFLECTANCE`` below), weighted by the solar (blackbody) spectrum and a flat response in
each band, is :func:`mars_soil_spectral_ratio` = 0.91 (0.906). It is one configured factor applied to the
whole terrain radiance field (``SceneConfig.spectral_ratio``).
"""
from __future__ import annotations

import numpy as np

SOLAR_TEMPERATURE_K = 5772.0
DIMES_BAND_UM = (0.4, 1.1)
MOC_BAND_UM = (0.5, 0.9)
SOLAR_BAND_IRRADIANCE_1AU_W_M2_UM = 1251.0   # see module docstring; checked by tests against Planck
SOLAR_RADIUS_M = 6.957e8
ASTRONOMICAL_UNIT_M = 1.495978707e11
MARS_MEAN_SUN_DISTANCE_AU = 1.524
PHASE_FUNCTION_FLOOR = 0.05

# (wavelength um, reflectance) of average bright Martian soil, Pathfinder IMP (Maki et al. 1999), read
# off the published spectra to about +-0.01; used only for the documented spectral ratio.
MARS_SOIL_REFLECTANCE = np.array([
    [0.40, 0.070], [0.44, 0.080], [0.48, 0.100], [0.53, 0.140], [0.60, 0.220], [0.67, 0.270],
    [0.75, 0.290], [0.80, 0.290], [0.86, 0.280], [0.90, 0.270], [0.93, 0.270], [1.00, 0.280],
    [1.10, 0.290],
])

_POLY_LOW_PHASE = (2.05, -3.93e-2, 2.09e-3, -4.86e-5, 4.93e-7, -1.72e-9)  # eq. (2), alpha in deg
_DEGREES_PER_RADIAN_F32 = np.degrees(np.float32(1.0))   # x * this == np.degrees(x) for float32 x, bit for bit


def phase_function(phase_rad: np.ndarray) -> np.ndarray:
    """The Mars phase function f(alpha) of equations (2)-(3), extended linearly beyond 60 deg.

    Parameters
    ----------
    phase_rad : array_like
        Phase angle (rad), any shape.

    Returns
    -------
    ndarray, float32 (float64 if the input is float64), same shape, >= ``PHASE_FUNCTION_FLOOR``.
    """
    phase_rad = np.asarray(phase_rad)
    dtype = np.float64 if phase_rad.dtype == np.float64 else np.float32
    alpha = np.degrees(phase_rad.astype(dtype))
    low = np.zeros_like(alpha)
    for coefficient in reversed(_POLY_LOW_PHASE):   # Horner
        low = low * alpha + dtype(coefficient)
    linear = dtype(1.82) - dtype(1.03e-2) * (alpha - dtype(10.0))
    result = np.where(alpha < 10.0, low, linear)
    return np.maximum(result, dtype(PHASE_FUNCTION_FLOOR)).astype(dtype)


def lommel_seeliger(cos_incidence: np.ndarray, cos_emission: np.ndarray) -> np.ndarray:
    """``mu0 / (mu + mu0)`` with both cosines clipped at 0; never divides by zero.

    Parameters
    ----------
    cos_incidence, cos_emission : ndarray
        Cosines ``mu0`` and ``mu`` of the incidence and emission angles, broadcastable.

    Returns
    -------
    ndarray
        The Lommel-Seeliger factor, 0 where the sun or the viewer is below the local horizon.
    """
    mu0 = np.maximum(cos_incidence, 0.0)
    mu = np.maximum(cos_emission, 0.0)
    total = mu + mu0
    return np.where(total > 0, mu0 / np.where(total > 0, total, 1.0), 0.0)


def reflectance_model(cos_incidence, cos_emission, cos_phase) -> np.ndarray:
    """Equation (1) without the albedo: ``mu0/(mu+mu0) f(alpha)``.

    Parameters
    ----------
    cos_incidence, cos_emission, cos_phase : float or ndarray
        Cosines of the incidence, emission and phase angles, broadcastable.

    Returns
    -------
    ndarray
        The model value.
    """
    phase = np.arccos(np.clip(cos_phase, -1.0, 1.0))
    return lommel_seeliger(cos_incidence, cos_emission) * phase_function(phase)


def moc_reflectance_model(incidence_rad: float, emission_rad: float, phase_rad: float) -> float:
    """Equation (1) at the orbital image's own geometry.

    Parameters
    ----------
    incidence_rad, emission_rad, phase_rad : float
        MOC incidence, emission and phase angles (rad).

    Returns
    -------
    float
        The model value.
    """
    value = float(reflectance_model(np.cos(incidence_rad), np.cos(emission_rad), np.cos(np.float64(phase_rad))))
    if not value > 0:
        raise ValueError(f"terrain photometry: MOC incidence {np.degrees(incidence_rad):.1f} deg, emission "
                         f"{np.degrees(emission_rad):.1f} deg give zero reflectance; allowed: both < 90 deg")
    return value


def photometric_ratio(view_to_camera_world: np.ndarray, sun_world: np.ndarray, moc_model_value: float) -> np.ndarray:
    """DIMES / MOC photometric ratio for level ground seen along given directions.

    Parameters
    ----------
    view_to_camera_world : ndarray, shape (..., 3)
        Unit vectors from the ground point to the camera (world, z up); minus the pixel rays.
    sun_world : ndarray, shape (3,)
        Unit vector toward the sun (world).
    moc_model_value : float
        :func:`moc_reflectance_model` of the terrain.

    Returns
    -------
    ndarray, float32, shape (...): multiply the MOC I/F by this to get the DIMES I/F.
    """
    view = np.asarray(view_to_camera_world, dtype=np.float32)
    sun = np.asarray(sun_world, dtype=np.float32)
    cos_emission = view[..., 2]
    cos_phase = view @ sun
    value = reflectance_model(np.float32(sun[2]), cos_emission, cos_phase)
    return (value / np.float32(moc_model_value)).astype(np.float32)


def photometric_ratio_from_cosines(cos_emission: np.ndarray, cos_phase: np.ndarray, sun_z: float,
                                   moc_model_value: float) -> np.ndarray:
    """:func:`photometric_ratio` from the cosines of the emission and phase angles of every pixel.

    The same float32 operations in the same order (so the same bits for the same cosines), done in
    place on the two given arrays (both are overwritten; the result is one of them), with the low-phase
    polynomial of equation (2) evaluated only where the phase angle is below 10 deg, the degree
    conversion as np.degrees' own float32 product, and without the floor (phase angles from arccos lie
    in [0, 180] deg, where f >= f(180 deg) = 0.069 > ``PHASE_FUNCTION_FLOOR``).

    Parameters
    ----------
    cos_emission, cos_phase : ndarray, shape (H, W), float32
        Cosines of the emission and phase angles; overwritten.
    sun_z : float
        Cosine of the solar incidence on level ground (> 0: sun up).
    moc_model_value : float
        The MOC geometry's model value (:func:`moc_reflectance_model`), the ratio's denominator.

    Returns
    -------
    ndarray, shape (H, W), float32
        The DIMES / MOC ratio.
    """
    # mu = max(cos e, 0): np.clip with both bounds takes numpy's vectorised clip loop (~3x faster here than
    # np.maximum with a scalar), the same values (+inf never binds, NaN propagates as in np.maximum)
    ratio = np.clip(cos_emission, np.float32(0.0), np.float32(np.inf), out=cos_emission)
    mu0 = np.float32(max(sun_z, 0.0))
    if mu0 > 0:      # mu0 / (mu + mu0): the sum never vanishes while the sun is up
        ratio += mu0
        np.divide(mu0, ratio, out=ratio)
    else:
        ratio[:] = 0.0
    return _times_phase_function(ratio, cos_phase, moc_model_value)


def photometric_ratio_from_ray_dz(ray_dz: np.ndarray, cos_phase: np.ndarray, sun_z: float,
                                  moc_model_value: float, out: np.ndarray) -> np.ndarray:
    """:func:`photometric_ratio_from_cosines` of unit pixel rays: ``cos e = -d_z``, one pass fewer.

    ``mu0 / (max(-d_z, 0) + mu0)`` is computed as ``mu0 / (mu0 - min(d_z, 0))``: ``-min(d_z, 0)`` is
    ``max(-d_z, 0)`` exactly and ``a - b`` is ``a + (-b)`` in IEEE arithmetic, so the same float32 values
    (signed zeros vanish in the sum with mu0 > 0, NaN propagates) without negating into a new array first.

    Parameters
    ----------
    ray_dz : ndarray, shape (H, W), float32
        World z components of the unit pixel rays (unchanged).
    cos_phase : ndarray, shape (H, W), float32
        Cosines of the phase angles; overwritten.
    sun_z : float
        Cosine of the solar incidence on level ground (> 0: sun up).
    moc_model_value : float
        The MOC geometry's model value, the ratio's denominator.
    out : ndarray, shape (H, W), float32
        Where the ratio is written.

    Returns
    -------
    ndarray, shape (H, W), float32
        The DIMES / MOC ratio (``out``).
    """
    mu0 = np.float32(max(sun_z, 0.0))
    if not mu0 > 0:
        return photometric_ratio_from_cosines(np.negative(ray_dz, out=out), cos_phase, sun_z, moc_model_value)
    ratio = np.clip(ray_dz, np.float32(-np.inf), np.float32(0.0), out=out)    # -max(-d_z, 0)
    np.subtract(mu0, ratio, out=ratio)
    np.divide(mu0, ratio, out=ratio)
    return _times_phase_function(ratio, cos_phase, moc_model_value)


def _times_phase_function(ratio: np.ndarray, cos_phase: np.ndarray, moc_model_value: float) -> np.ndarray:
    """``ratio`` times f(alpha) of eq. (2)/(3), over the MOC model value, in place (``cos_phase`` overwritten)."""
    alpha = np.clip(cos_phase, -1.0, 1.0, out=cos_phase)
    np.arccos(alpha, out=alpha)
    alpha *= _DEGREES_PER_RADIAN_F32                                          # np.degrees, bit for bit
    low = np.flatnonzero(alpha < 10.0) if float(alpha.min()) < 10.0 else None
    low_phase = _low_phase_polynomial(alpha.ravel()[low]) if low is not None and low.size else None
    alpha -= np.float32(10.0)                                                 # eq. (3) and beyond, in place
    alpha *= np.float32(1.03e-2)
    np.subtract(np.float32(1.82), alpha, out=alpha)
    if low_phase is not None:
        alpha.ravel()[low] = low_phase
    # the floor never binds here: f(180 deg) = 0.069 > PHASE_FUNCTION_FLOOR and eq. (2) stays above 1.8
    ratio *= alpha
    ratio /= np.float32(moc_model_value)
    return ratio


def _low_phase_polynomial(alpha_deg: np.ndarray) -> np.ndarray:
    """Equation (2) by Horner's rule in the dtype of ``alpha_deg`` (as :func:`phase_function`)."""
    dtype = alpha_deg.dtype.type
    low = np.zeros_like(alpha_deg)
    for coefficient in reversed(_POLY_LOW_PHASE):
        low = low * alpha_deg + dtype(coefficient)
    return low


def solar_band_irradiance_w_m2_um(sun_distance_au: float) -> float:
    """Band-mean (0.4-1.1 um) solar spectral irradiance at a distance from the sun.

    Parameters
    ----------
    sun_distance_au : float
        Distance from the sun (AU).

    Returns
    -------
    float
        Irradiance (W m^-2 um^-1).
    """
    if not sun_distance_au > 0:
        raise ValueError(f"sun_distance_au = {sun_distance_au} must be > 0")
    return SOLAR_BAND_IRRADIANCE_1AU_W_M2_UM / sun_distance_au**2


def solar_angular_radius_rad(sun_distance_au: float) -> float:
    """Angular radius of the solar disc; 3.05e-3 rad at 1.524 AU.

    Parameters
    ----------
    sun_distance_au : float
        Distance from the sun (AU).

    Returns
    -------
    float
        Radius (rad).
    """
    return float(np.arcsin(SOLAR_RADIUS_M / (sun_distance_au * ASTRONOMICAL_UNIT_M)))


def planck_band_fraction(band_um: tuple[float, float], temperature_k: float = SOLAR_TEMPERATURE_K) -> float:
    """Fraction of a blackbody's total exitance between two wavelengths (numerical integral).

    Parameters
    ----------
    band_um : (float, float)
        Band edges (um).
    temperature_k : float, optional
        Blackbody temperature (K), default the Sun's.

    Returns
    -------
    float
        Fraction, 0 .. 1.
    """
    wavelength_m = np.linspace(band_um[0], band_um[1], 4001) * 1e-6
    return float(np.trapezoid(_planck(wavelength_m, temperature_k), wavelength_m)
                 / (5.670374419e-8 * temperature_k**4 / np.pi))


def mars_soil_spectral_ratio(dimes_band_um=DIMES_BAND_UM, moc_band_um=MOC_BAND_UM) -> float:
    """Band-mean Mars soil reflectance in the DIMES band over that in the MOC band (solar-weighted).

    Parameters
    ----------
    dimes_band_um, moc_band_um : (float, float), optional
        Band edges (um).

    Returns
    -------
    float
        The ratio (0.906 for the default bands).
    """
    def band_mean(band):
        wavelength_um = np.linspace(band[0], band[1], 701)
        weight = _planck(wavelength_um * 1e-6, SOLAR_TEMPERATURE_K)
        reflectance = np.interp(wavelength_um, MARS_SOIL_REFLECTANCE[:, 0], MARS_SOIL_REFLECTANCE[:, 1])
        return np.trapezoid(weight * reflectance, wavelength_um) / np.trapezoid(weight, wavelength_um)
    return float(band_mean(dimes_band_um) / band_mean(moc_band_um))


def _planck(wavelength_m: np.ndarray, temperature_k: float) -> np.ndarray:
    """Blackbody spectral radiance, W m^-2 sr^-1 m^-1."""
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    return 2 * h * c**2 / wavelength_m**5 / np.expm1(h * c / (wavelength_m * k * temperature_k))
