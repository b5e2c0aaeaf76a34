"""Camera configuration: the fixed geometric, radiometric and electrical characteristics (paper 2.1).

A camera is data: a TOML file under ``sitedata/cameras/`` is validated here into a frozen
:class:`Camera`; errors name the file, the field and the allowed range.

Radiometric response (documented number)
----------------------------------------
On axis, a lens of focal ratio N images a scene of spectral radiance L (W m^-2 sr^-1 um^-1) onto
the focal plane with irradiance ``E = pi * T * L / (4 N^2)``. A pixel of area ``A_pix`` with mean
quantum efficiency ``QE`` over the band ``dlambda`` (um), and photons of effective wavelength
``lambda_eff`` (energy ``h c / lambda_eff``), collects::

    k = pi T A_pix dlambda QE lambda_eff / (4 N^2 h c)   electrons s^-1 per (W m^-2 sr^-1 um^-1)

For the MER DIMES camera (f/12, 12 um pixels, 400-1100 nm, T = 0.8, band-mean QE 0.12 for a
front-side illuminated CCD behind its window, lambda_eff = 0.70 um) ``k = 1.86e5`` e-/s per unit
radiance, i.e. ``949`` e- per unit radiance in the 5.1 ms exposure. A typical Mars scene
(I/F 0.25 at 1.52 AU, L ~ 40) gives about 3.8e4 e- per pixel in the exposure.

Dark current (documented model)
-------------------------------
``D(T) = D_ref * 2 ** ((T - T_ref) / T_double)`` electrons/s/pixel: the usual CCD rule of
doubling every ``T_double`` (6.5 K here) kelvin. The MER files give ``D_ref`` at ``T_ref = 0 C``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from flight_interface import cahvor
from flight_interface.frames import quat_normalize, quat_to_matrix
from flight_interface.tomlfields import ConfigError, Table, load_toml

PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 2.99792458e8
ZERO_CELSIUS_K = 273.15
#: Largest full well / summing well (e-): keeps every Poisson mean far below numpy's limit (~9e18).
MAX_WELL_E = 1e10
#: Largest dark current at the CCD temperature (e-/s per pixel): such a pixel fills any well in
#: microseconds; the storage dark of a binned row (<= 64 x 1e13 x 100 s) stays a valid Poisson mean.
MAX_DARK_CURRENT_E_PER_S = 1e13


@dataclass(frozen=True)
class Timing:
    """Frame-transfer CCD timing (s)."""

    fast_flush_s: float
    exposure_s: float
    frame_transfer_s: float
    readout_s: float
    transfer_toward_last_row: bool = True  # charge moves toward row height-1 (storage side)

    def exposure_mid_time_s(self, exposure_start_s):
        """Mid-exposure time(s) (s) of exposures starting at ``exposure_start_s`` (s, scalar or array):
        the instant an image's pose, footprint and measured state refer to."""
        return exposure_start_s + 0.5 * self.exposure_s


@dataclass(frozen=True)
class Radiometry:
    """Optics and CCD photo response."""

    f_number: float
    optics_transmission: float
    mean_quantum_efficiency: float
    band_min_um: float
    band_max_um: float
    effective_wavelength_um: float
    prnu_sigma: float     # pixel response non-uniformity (rms), a datasheet number
    prnu_seed: int        # seed of the simulated detector's PRNU realisation (simulation only)

    def responsivity_e_per_s(self, pixel_area_m2: float) -> float:
        """On-axis photo-electrons per second per unit spectral radiance (W m^-2 sr^-1 um^-1)."""
        photon_energy_j = PLANCK_J_S * SPEED_OF_LIGHT_M_S / (self.effective_wavelength_um * 1e-6)
        irradiance_per_radiance = np.pi * self.optics_transmission / (4.0 * self.f_number**2)
        band_um = self.band_max_um - self.band_min_um
        return irradiance_per_radiance * pixel_area_m2 * band_um * self.mean_quantum_efficiency / photon_energy_j


@dataclass(frozen=True)
class Electronics:
    """Dark current, charge capacity and analogue-to-digital conversion."""

    full_well_e: float
    binned_full_well_e: float
    adc_gain_e_per_dn: float
    adc_offset_dn: float
    adc_bits: int
    read_noise_e: float
    dark_current_ref_e_per_s: float
    dark_reference_temperature_k: float
    dark_doubling_temperature_k: float
    ccd_temperature_k: float

    @property
    def max_dn(self) -> int:
        return 2**self.adc_bits - 1

    def dark_current_e_per_s(self, temperature_k: float | None = None) -> float:
        """Dark current per pixel at ``temperature_k`` (default: the configured CCD temperature)."""
        temperature_k = self.ccd_temperature_k if temperature_k is None else temperature_k
        exponent = (temperature_k - self.dark_reference_temperature_k) / self.dark_doubling_temperature_k
        with np.errstate(over="ignore"):
            return float(self.dark_current_ref_e_per_s * np.exp2(exponent))   # inf, not OverflowError


@dataclass(frozen=True)
class Camera:
    """A descent camera. Geometry is a CAHVOR model in the camera frame plus the mounting on the lander."""

    name: str
    source: str
    width_px: int
    height_px: int
    pixel_pitch_m: float
    binning_rows: int
    model: cahvor.Cahvor
    camera_to_lander_quaternion: np.ndarray
    camera_position_in_lander_m: np.ndarray
    timing: Timing
    radiometry: Radiometry
    electronics: Electronics

    @property
    def binned_shape(self) -> tuple[int, int]:
        """(rows, columns) of the read-out image."""
        return self.height_px // self.binning_rows, self.width_px

    @property
    def camera_to_lander_matrix(self) -> np.ndarray:
        return quat_to_matrix(self.camera_to_lander_quaternion)

    @property
    def responsivity_e_per_s(self) -> float:
        """On-axis photo-electrons per second per unit spectral radiance (W m^-2 sr^-1 um^-1)."""
        return self.radiometry.responsivity_e_per_s(self.pixel_pitch_m**2)

    @cached_property
    def pixel_rays(self) -> np.ndarray:
        """Unit ray of every pixel centre in the camera frame, shape (height, width, 3), float64."""
        return cahvor.unproject(self.model, cahvor.pixel_grid(self.width_px, self.height_px))

    @cached_property
    def field_angle_rad(self) -> np.ndarray:
        """Angle of each pixel's ray from the optical axis O, shape (height, width)."""
        return np.arccos(np.clip(self.pixel_rays @ self.model.o, -1.0, 1.0))

    @cached_property
    def falloff_map(self) -> np.ndarray:
        """Design relative illumination: cos^4 of the field angle, shape (height, width), float32.

        A property of the optics as designed (an estimator may use it when it has no flat field); the
        pixel response non-uniformity is realised only by the simulator
        (:func:`simulator.detector.charge_generation.prnu_map`) and reaches an estimator only through a
        measured flat field (:mod:`flight_interface.calibration`)."""
        return (np.cos(self.field_angle_rad) ** 4).astype(np.float32)

    def fov_deg(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view between the outer pixel edges (deg)."""
        half_w, half_h = self.width_px / 2.0, self.height_px / 2.0
        centre = np.array([self.model.hc, self.model.vc])
        edges = np.array([[centre[0] - half_w, centre[1]], [centre[0] + half_w, centre[1]],
                          [centre[0], centre[1] - half_h], [centre[0], centre[1] + half_h]])
        rays = cahvor.unproject(self.model, edges)
        horizontal = np.degrees(np.arccos(np.clip(rays[0] @ rays[1], -1, 1)))
        vertical = np.degrees(np.arccos(np.clip(rays[2] @ rays[3], -1, 1)))
        return float(horizontal), float(vertical)


def load_camera(path: str | Path) -> Camera:
    """Load and validate a camera TOML file (see ``sitedata/cameras/mer_a.toml`` for the fields)."""
    path = Path(path)
    root = Table(load_toml(path), str(path))
    meta = root.table("camera")
    detector = root.table("detector")
    width = detector.integer("width_px", minimum=8, maximum=16384)
    height = detector.integer("height_px", minimum=8, maximum=16384)
    pitch = detector.number("pixel_pitch_m", minimum=0.0, maximum=1e-3, exclusive_minimum=True)
    binning = detector.integer("binning_rows", minimum=1, maximum=64)
    if height % binning:
        raise detector.fail("binning_rows", f"= {binning} must divide detector.height_px = {height}")

    geometry = root.table("geometry")
    if geometry.has("cahvor"):
        model = _explicit_cahvor(geometry.table("cahvor"))
    else:
        focal = geometry.number("focal_length_m", minimum=0.0, maximum=10.0, exclusive_minimum=True)
        centre = geometry.vector("principal_point_px", 2, default=[(width - 1) / 2.0, (height - 1) / 2.0])
        distortion = geometry.vector("radial_distortion", 3, default=[0.0, 0.0, 0.0])
        if not (-0.5 < distortion[0] < 0.5):
            raise geometry.fail("radial_distortion", f"R0 = {distortion[0]:g} is out of range; allowed: -0.5 < R0 < 0.5")
        model = cahvor.cahvor_from_intrinsics(focal, pitch, (centre[0], centre[1]), tuple(distortion))

    mounting = root.table("mounting")
    quaternion = mounting.vector("camera_to_lander_quaternion", 4, unit_norm=True)
    position = mounting.vector("camera_position_in_lander_m", 3, default=[0.0, 0.0, 0.0])

    timing_table = root.table("timing")
    timing = Timing(
        fast_flush_s=timing_table.number("fast_flush_s", minimum=0.0, maximum=10.0),
        exposure_s=timing_table.number("exposure_s", minimum=0.0, maximum=10.0, exclusive_minimum=True),
        frame_transfer_s=timing_table.number("frame_transfer_s", minimum=0.0, maximum=10.0),
        readout_s=timing_table.number("readout_s", default=0.0, minimum=0.0, maximum=100.0),
        transfer_toward_last_row=timing_table.string(
            "transfer_direction", default="toward_last_row", choices=("toward_last_row", "toward_first_row"),
        ) == "toward_last_row",
    )

    rad = root.table("radiometry")
    band_min = rad.number("band_min_um", minimum=0.1, maximum=20.0)
    radiometry = Radiometry(
        f_number=rad.number("f_number", minimum=0.5, maximum=100.0),
        optics_transmission=rad.number("optics_transmission", minimum=0.0, maximum=1.0, exclusive_minimum=True),
        mean_quantum_efficiency=rad.number("mean_quantum_efficiency", minimum=0.0, maximum=1.0, exclusive_minimum=True),
        band_min_um=band_min,
        band_max_um=rad.number("band_max_um", minimum=band_min, maximum=20.0, exclusive_minimum=True),
        effective_wavelength_um=rad.number("effective_wavelength_um", minimum=0.1, maximum=20.0),
        prnu_sigma=rad.number("prnu_sigma", minimum=0.0, maximum=0.5),
        prnu_seed=rad.integer("prnu_seed", minimum=0),
    )

    ele = root.table("electronics")
    electronics = Electronics(
        full_well_e=ele.number("full_well_e", minimum=0.0, maximum=MAX_WELL_E, exclusive_minimum=True),
        binned_full_well_e=ele.number("binned_full_well_e", minimum=0.0, maximum=MAX_WELL_E, exclusive_minimum=True),
        adc_gain_e_per_dn=ele.number("adc_gain_e_per_dn", minimum=0.0, maximum=1e6, exclusive_minimum=True),
        adc_offset_dn=ele.number("adc_offset_dn", default=0.0, minimum=0.0, maximum=65535.0),
        adc_bits=ele.integer("adc_bits", minimum=1, maximum=16),
        read_noise_e=ele.number("read_noise_e", minimum=0.0, maximum=1e5),
        dark_current_ref_e_per_s=ele.number("dark_current_ref_e_per_s", minimum=0.0, maximum=1e9),
        dark_reference_temperature_k=ele.number("dark_reference_temperature_c", minimum=-273.15, maximum=200.0) + ZERO_CELSIUS_K,
        dark_doubling_temperature_k=ele.number("dark_doubling_temperature_k", minimum=0.0, maximum=100.0, exclusive_minimum=True),
        ccd_temperature_k=ele.number("ccd_temperature_c", minimum=-273.15, maximum=200.0) + ZERO_CELSIUS_K,
    )

    dark = electronics.dark_current_e_per_s()
    if not dark <= MAX_DARK_CURRENT_E_PER_S:
        raise ConfigError(f"{path}: electronics: dark current at ccd_temperature_c = "
                          f"{electronics.ccd_temperature_k - ZERO_CELSIUS_K:g} is {dark:.3g} e-/s per pixel "
                          f"(dark_current_ref_e_per_s, dark_reference_temperature_c, dark_doubling_temperature_k); "
                          f"allowed: <= {MAX_DARK_CURRENT_E_PER_S:g} e-/s")
    _check_distortion_increases_to_corners(model, width, height, path)

    camera = Camera(
        name=meta.string("name"), source=str(path), width_px=width, height_px=height, pixel_pitch_m=pitch,
        binning_rows=binning, model=model, camera_to_lander_quaternion=quat_normalize(quaternion),
        camera_position_in_lander_m=position, timing=timing, radiometry=radiometry, electronics=electronics,
    )
    horizontal_fov, vertical_fov = camera.fov_deg()
    if not (1.0 < horizontal_fov < 170.0 and 1.0 < vertical_fov < 170.0):
        raise ConfigError(f"{path}: geometry gives a field of view of {horizontal_fov:.1f} x {vertical_fov:.1f} deg; "
                          "allowed: 1 to 170 deg (check focal_length_m and pixel_pitch_m)")
    return camera


def _check_distortion_increases_to_corners(model: cahvor.Cahvor, width: int, height: int, path: Path) -> None:
    """The radial distortion must keep increasing out to the frame corners (else rays fold back and
    several field angles share one pixel); raises ConfigError naming geometry.radial_distortion."""
    turning = cahvor.distortion_turning_point(model.r)
    if not np.isfinite(turning):
        return
    r0, r1, r2 = model.r
    largest = turning * (1.0 + r0 + r1 * turning**2 + r2 * turning**4)          # distorted tangent
    corners = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5], [width - 0.5, height - 0.5]])
    corner = float(np.max(np.hypot((corners[:, 0] - model.hc) / model.hs, (corners[:, 1] - model.vc) / model.vs)))
    if corner >= largest:
        raise ConfigError(f"{path}: geometry.radial_distortion = [{', '.join(f'{value:g}' for value in model.r)}] stops increasing "
                          f"{largest * model.hs:.0f} px from the principal point, inside the frame (corner at "
                          f"{corner * model.hs:.0f} px); allowed: a distortion that increases out to the frame corners")


def _explicit_cahvor(table: Table) -> cahvor.Cahvor:
    """A calibrated CAHVOR model given as its six vectors (camera frame)."""
    model = cahvor.Cahvor(
        c=table.vector("C", 3), a=table.vector("A", 3, unit_norm=True), h=table.vector("H", 3),
        v=table.vector("V", 3), o=table.vector("O", 3, unit_norm=True), r=table.vector("R", 3),
    )
    if model.hs <= 0 or model.vs <= 0:
        raise table.fail("H", "and V must not be parallel to A (focal lengths hs, vs must be > 0)")
    return model
