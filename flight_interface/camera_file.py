"""The camera file: the fixed geometric, radiometric and electrical characteristics (paper 2.1).

A camera is data: a TOML file under ``sitedata/cameras/`` is validated here. Its tables are declared
once, as the models below (:class:`CameraFile`:
``[camera]``, ``[detector]``, ``[geometry]``, ``[mounting]``, ``[timing]``, ``[radiometry]``,
``[electronics]``, optional ``[optics]``); unknown keys are refused and errors name the file, the
field and the allowed range.
``campaign schema camera`` prints the JSON Schema. :func:`flight_interface.camera.load_camera` turns a
validated file into the runtime :class:`~flight_interface.camera.Camera`.

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

from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import Field, model_validator

from config_tables.errors import FieldProblem
from config_tables.models import ConfigModel, FloatList, fixed_vector
from flight_interface import cahvor
from flight_interface.cahvor import Cahvor, field_of_view_deg

PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 2.99792458e8
ZERO_CELSIUS_K = 273.15
#: Largest full well / summing well (e-): keeps every Poisson mean far below numpy's limit (~9e18).
MAX_WELL_E = 1e10
#: Largest dark current at the CCD temperature (e-/s per pixel): such a pixel fills any well in
#: microseconds; the storage dark of a binned row (<= 64 x 1e13 x 100 s) stays a valid Poisson mean.
MAX_DARK_CURRENT_E_PER_S = 1e13
#: A unit vector's norm may differ from 1 by this much.
UNIT_NORM_TOLERANCE = 1e-6
#: Largest rms wavefront error (waves at the band's shortest wavelength) of the optics' aberration term:
#: the limit of the aberration transfer factor's validity (simulator.detector.psf).
MAX_WAVEFRONT_ERROR_WAVES = 0.18
#: Full fields of view allowed (deg, exclusive).
FOV_RANGE_DEG = (1.0, 170.0)

if TYPE_CHECKING:   # what the validators below produce, for the type checker
    Vector2 = tuple[float, float]
    Vector3 = tuple[float, float, float]
    Vector4 = tuple[float, float, float, float]
else:
    Vector2 = fixed_vector(2)
    Vector3 = fixed_vector(3)
    Vector4 = fixed_vector(4)


def _check_unit(model, *names: str) -> None:
    for name in names:
        norm = float(np.linalg.norm(getattr(model, name)))
        if abs(norm - 1.0) > UNIT_NORM_TOLERANCE:
            raise FieldProblem(name, f"must be a unit vector (norm 1 within {UNIT_NORM_TOLERANCE:g}); norm is {norm:.9g}")


class CameraName(ConfigModel):
    """``[camera]``: identification."""

    name: str = Field(min_length=1)
    """Human-readable camera name."""


class Detector(ConfigModel):
    """``[detector]``: the CCD array and its on-chip binning."""

    width_px: int = Field(ge=8, le=16384)
    """Columns of the array (px)."""
    height_px: int = Field(ge=8, le=16384)
    """Rows of the array (px)."""
    pixel_pitch_m: float = Field(gt=0.0, le=1e-3)
    """Pixel pitch (m)."""
    binning_rows: int = Field(ge=1, le=64)
    """Rows summed on chip; must divide height_px."""

    @model_validator(mode="after")
    def _binning_divides_height(self):
        if self.height_px % self.binning_rows:
            raise FieldProblem("binning_rows", f"= {self.binning_rows} must divide detector.height_px = {self.height_px}")
        return self


class CahvorVectors(ConfigModel):
    """``[geometry.cahvor]``: a calibrated CAHVOR model, six vectors in the camera frame."""

    C: Vector3
    """Centre of projection (m)."""
    A: Vector3
    """Axis (unit vector)."""
    H: Vector3
    """Horizontal vector (px)."""
    V: Vector3
    """Vertical vector (px)."""
    O: Vector3  # noqa: E741 - CAHVOR notation (C, A, H, V, O, R)
    """Optical axis (unit vector)."""
    R: Vector3
    """Radial distortion coefficients R0, R1, R2."""

    @model_validator(mode="after")
    def _valid_model(self):
        _check_unit(self, "A", "O")
        model = self.to_cahvor()
        if model.hs <= 0 or model.vs <= 0:
            raise FieldProblem("H", "and V must not be parallel to A (focal lengths hs, vs must be > 0)")
        return self

    def to_cahvor(self) -> cahvor.Cahvor:
        """The model as arrays.

        Returns
        -------
        Cahvor
            The six vectors as float arrays of shape (3,).
        """
        return cahvor.Cahvor(c=np.array(self.C), a=np.array(self.A), h=np.array(self.H), v=np.array(self.V),
                             o=np.array(self.O), r=np.array(self.R))


class Geometry(ConfigModel):
    """``[geometry]``: the camera model.

    Either intrinsics (focal length, principal point, radial distortion) or an explicit ``[geometry.cahvor]``
    model.
    """

    focal_length_m: float | None = Field(None, gt=0.0, le=10.0)
    """Focal length (m); required unless [geometry.cahvor] is given."""
    principal_point_px: Vector2 | None = None
    """(column, row) of the principal point (px, pixel centres at integers); default the array centre."""
    radial_distortion: Vector3 | None = None
    """CAHVOR R0, R1, R2 (default [0, 0, 0]); -0.5 < R0 < 0.5."""
    cahvor: CahvorVectors | None = None
    """An explicit calibrated CAHVOR model instead of the intrinsics."""

    @model_validator(mode="after")
    def _one_description(self):
        intrinsics = [name for name in ("focal_length_m", "principal_point_px", "radial_distortion")
                      if getattr(self, name) is not None]
        if self.cahvor is not None and intrinsics:
            raise FieldProblem(intrinsics[0], "and geometry.cahvor are both given; allowed: one of them")
        if self.cahvor is None and self.focal_length_m is None:
            raise FieldProblem("focal_length_m", "is missing (or give [geometry.cahvor])")
        if self.radial_distortion is not None and not -0.5 < self.radial_distortion[0] < 0.5:
            raise FieldProblem("radial_distortion", f"R0 = {self.radial_distortion[0]:g} is out of range; "
                               "allowed: -0.5 < R0 < 0.5")
        return self

    def to_cahvor(self, detector: Detector) -> Cahvor:
        """The CAHVOR model in the camera frame, from the explicit model or the intrinsics.

        Parameters
        ----------
        detector : Detector
            The array (pixel pitch; its centre is the default principal point).

        Returns
        -------
        Cahvor
            The camera model.
        """
        if self.cahvor is not None:
            return self.cahvor.to_cahvor()
        assert self.focal_length_m is not None     # the validator requires it when no CAHVOR model is given
        centre = self.principal_point_px or ((detector.width_px - 1) / 2.0, (detector.height_px - 1) / 2.0)
        return cahvor.cahvor_from_intrinsics(self.focal_length_m, detector.pixel_pitch_m, tuple(centre),  # type: ignore[arg-type]
                                             tuple(self.radial_distortion or (0.0, 0.0, 0.0)))  # type: ignore[arg-type]


class Mounting(ConfigModel):
    """``[mounting]``: where the camera sits on the lander."""

    camera_to_lander_quaternion: Vector4
    """Camera-to-lander rotation, unit quaternion (w, x, y, z)."""
    camera_position_in_lander_m: Vector3 = (0.0, 0.0, 0.0)
    """Camera position in the lander body frame (m)."""

    @model_validator(mode="after")
    def _unit(self):
        _check_unit(self, "camera_to_lander_quaternion")
        return self


class Timing(ConfigModel):
    """``[timing]``: frame-transfer CCD timing (s)."""

    fast_flush_s: float = Field(ge=0.0, le=10.0)
    """Fast flush before the exposure (s)."""
    exposure_s: float = Field(gt=0.0, le=10.0)
    """Exposure (s)."""
    frame_transfer_s: float = Field(ge=0.0, le=10.0)
    """Frame transfer to the storage area (s)."""
    readout_s: float = Field(0.0, ge=0.0, le=100.0)
    """Read-out of the storage area (s)."""
    transfer_direction: Literal["toward_last_row", "toward_first_row"] = "toward_last_row"
    """Which way charge moves during frame transfer."""

    @property
    def transfer_toward_last_row(self) -> bool:
        """Charge moves toward row height-1 (the storage side)."""
        return self.transfer_direction == "toward_last_row"

    def exposure_mid_time_s(self, exposure_start_s):
        """Mid-exposure time(s) of exposures starting at ``exposure_start_s``.

        The instant an image's pose, footprint and measured state refer to.

        Parameters
        ----------
        exposure_start_s : float or ndarray
            Start of each exposure (s).

        Returns
        -------
        float or ndarray
            Mid-exposure time(s) (s), the shape of ``exposure_start_s``.
        """
        return exposure_start_s + 0.5 * self.exposure_s


class Radiometry(ConfigModel):
    """``[radiometry]``: optics and CCD photo response."""

    f_number: float = Field(ge=0.5, le=100.0)
    """Focal ratio N."""
    optics_transmission: float = Field(gt=0.0, le=1.0)
    """Optics transmission T."""
    mean_quantum_efficiency: float = Field(gt=0.0, le=1.0)
    """Band-mean quantum efficiency."""
    band_min_um: float = Field(ge=0.1, le=20.0)
    """Short end of the band (um)."""
    band_max_um: float = Field(gt=0.1, le=20.0)
    """Long end of the band (um), > band_min_um."""
    effective_wavelength_um: float = Field(ge=0.1, le=20.0)
    """Effective photon wavelength (um)."""
    prnu_sigma: float = Field(ge=0.0, le=0.5)
    """Pixel response non-uniformity (rms, relative), a datasheet number."""
    prnu_seed: int = Field(ge=0, le=2**63 - 1)
    """Seed of the simulated detector's PRNU realisation (simulation only)."""

    @model_validator(mode="after")
    def _band(self):
        if not self.band_max_um > self.band_min_um:
            raise FieldProblem("band_max_um", f"= {self.band_max_um:g} is out of range; allowed: > band_min_um "
                               f"({self.band_min_um:g}) and <= 20")
        return self

    def responsivity_e_per_s(self, pixel_area_m2: float) -> float:
        """On-axis photo-electrons per second per unit spectral radiance (module docstring: ``k``).

        Parameters
        ----------
        pixel_area_m2 : float
            Area of one pixel (m^2).

        Returns
        -------
        float
            Electrons per second per (W m^-2 sr^-1 um^-1).
        """
        photon_energy_j = PLANCK_J_S * SPEED_OF_LIGHT_M_S / (self.effective_wavelength_um * 1e-6)
        irradiance_per_radiance = np.pi * self.optics_transmission / (4.0 * self.f_number**2)
        band_um = self.band_max_um - self.band_min_um
        return irradiance_per_radiance * pixel_area_m2 * band_um * self.mean_quantum_efficiency / photon_energy_j


class Optics(ConfigModel):
    """``[optics]``: the lens's image quality, the point-spread function (PSF) of the optics.

    The PSF is the diffraction pattern of the circular aperture (focal ratio ``radiometry.f_number``)
    averaged over the band with the weight optics transmission x quantum efficiency per wavelength,
    blurred by an optional Gaussian (defocus, residual aberrations) and an optional random wavefront
    error (:mod:`simulator.detector.psf`). Without the spectral tables the weight is flat over
    ``radiometry.band_min_um`` .. ``band_max_um``.
    """

    spectral_wavelengths_um: FloatList | None = None
    """Wavelengths (um) of the two spectral tables, increasing, inside the band [band_min_um, band_max_um]."""
    spectral_transmission: FloatList | None = None
    """Optics transmission at each wavelength, 0 .. 1."""
    spectral_quantum_efficiency: FloatList | None = None
    """Detector quantum efficiency at each wavelength, 0 .. 1."""
    blur_sigma_um: float = Field(0.0, ge=0.0, le=1000.0)
    """Standard deviation (um, in the focal plane) of a Gaussian blur: defocus and aberrations (0: none)."""
    wavefront_error_rms_um: float = Field(0.0, ge=0.0, le=20.0)
    """Random rms wavefront error (um); at most 0.18 waves at band_min_um (0: none)."""

    @model_validator(mode="after")
    def _tables(self):
        tables = {"spectral_wavelengths_um": self.spectral_wavelengths_um,
                  "spectral_transmission": self.spectral_transmission,
                  "spectral_quantum_efficiency": self.spectral_quantum_efficiency}
        given = [name for name, value in tables.items() if value is not None]
        if given and len(given) != 3:
            missing = next(name for name in tables if name not in given)
            raise FieldProblem(missing, f"is missing; allowed: all three spectral tables ({', '.join(tables)}) or none")
        if not given:
            return self
        wavelengths = np.asarray(self.spectral_wavelengths_um)
        if len(wavelengths) < 2 or not np.all(np.diff(wavelengths) > 0):
            raise FieldProblem("spectral_wavelengths_um", "must list at least 2 wavelengths (um), strictly increasing")
        for name in ("spectral_transmission", "spectral_quantum_efficiency"):
            values = np.asarray(tables[name])
            if len(values) != len(wavelengths):
                raise FieldProblem(name, f"has {len(values)} values; allowed: one per wavelength "
                                   f"({len(wavelengths)} in spectral_wavelengths_um)")
            if not (np.all(values >= 0.0) and np.all(values <= 1.0)):
                raise FieldProblem(name, "has a value outside 0 .. 1; allowed: 0 <= value <= 1")
        if not np.any(np.asarray(self.spectral_transmission) * np.asarray(self.spectral_quantum_efficiency) > 0):
            raise FieldProblem("spectral_quantum_efficiency", "x spectral_transmission is 0 at every wavelength; "
                               "allowed: a response > 0 somewhere in the band")
        return self

    def band_weights(self, band_min_um: float, band_max_um: float) -> tuple[np.ndarray, np.ndarray]:
        """Wavelengths and trapezoid-rule weights of the photo-electrons per wavelength, on a 5 nm grid.

        The weight is transmission x QE (a photon spectrum flat across the band); without the spectral
        tables it is flat over the band.

        Parameters
        ----------
        band_min_um, band_max_um : float
            The band (um).

        Returns
        -------
        wavelengths_m : ndarray, shape (n,)
            Wavelengths (m).
        weights : ndarray, shape (n,)
            Weight of each wavelength (sum 1).
        """
        count = max(int(np.ceil((band_max_um - band_min_um) / 0.005)) + 1, 2)
        wavelengths_um = np.linspace(band_min_um, band_max_um, count)
        if self.spectral_wavelengths_um is None:
            response = np.ones(count)
        else:
            table = np.asarray(self.spectral_wavelengths_um)
            response = (np.interp(wavelengths_um, table, np.asarray(self.spectral_transmission), left=0.0, right=0.0)
                        * np.interp(wavelengths_um, table, np.asarray(self.spectral_quantum_efficiency),
                                    left=0.0, right=0.0))
        trapezoid = np.full(count, wavelengths_um[1] - wavelengths_um[0])
        trapezoid[[0, -1]] *= 0.5
        weights = response * trapezoid
        return wavelengths_um * 1e-6, weights / weights.sum()


class Electronics(ConfigModel):
    """``[electronics]``: dark current, charge capacity and analogue-to-digital conversion.

    Temperatures in Celsius at this edge; ``*_k`` properties in kelvin.
    """

    full_well_e: float = Field(gt=0.0, le=MAX_WELL_E)
    """Full well per pixel (e-)."""
    binned_full_well_e: float = Field(gt=0.0, le=MAX_WELL_E)
    """Summing-well capacity of a binned pixel (e-)."""
    adc_gain_e_per_dn: float = Field(gt=0.0, le=1e6)
    """ADC gain (e- per DN)."""
    adc_offset_dn: float = Field(0.0, ge=0.0, le=65535.0)
    """ADC offset (DN)."""
    adc_bits: int = Field(ge=1, le=16)
    """ADC resolution (bits)."""
    read_noise_e: float = Field(ge=0.0, le=1e5)
    """Read noise (e- RMS)."""
    dark_current_ref_e_per_s: float = Field(ge=0.0, le=1e9)
    """Dark current per pixel at dark_reference_temperature_c (e-/s)."""
    dark_reference_temperature_c: float = Field(ge=-273.15, le=200.0)
    """Temperature of dark_current_ref_e_per_s (deg C)."""
    dark_doubling_temperature_k: float = Field(gt=0.0, le=100.0)
    """Dark current doubles every this many kelvin."""
    ccd_temperature_c: float = Field(ge=-273.15, le=200.0)
    """CCD temperature during the descent (deg C)."""

    @model_validator(mode="after")
    def _dark_current_bounded(self):
        dark = self.dark_current_e_per_s()
        if not dark <= MAX_DARK_CURRENT_E_PER_S:
            raise FieldProblem("ccd_temperature_c", f"= {self.ccd_temperature_c:g} gives a dark current of {dark:.3g} "
                               "e-/s per pixel (dark_current_ref_e_per_s, dark_reference_temperature_c, "
                               f"dark_doubling_temperature_k); allowed: <= {MAX_DARK_CURRENT_E_PER_S:g} e-/s")
        return self

    @property
    def dark_reference_temperature_k(self) -> float:
        """Temperature of ``dark_current_ref_e_per_s`` (K)."""
        return self.dark_reference_temperature_c + ZERO_CELSIUS_K

    @property
    def ccd_temperature_k(self) -> float:
        """CCD temperature during the descent (K)."""
        return self.ccd_temperature_c + ZERO_CELSIUS_K

    @property
    def max_dn(self) -> int:
        """Largest digital number of the ADC (DN)."""
        return 2**self.adc_bits - 1

    def dark_current_e_per_s(self, temperature_k: float | None = None) -> float:
        """Dark current per pixel (module docstring: ``D(T)``).

        Parameters
        ----------
        temperature_k : float or None, optional
            CCD temperature (K); default the configured ``ccd_temperature_c``.

        Returns
        -------
        float
            Dark current (e-/s per pixel); ``inf`` beyond float range.
        """
        temperature_k = self.ccd_temperature_k if temperature_k is None else temperature_k
        exponent = (temperature_k - self.dark_reference_temperature_k) / self.dark_doubling_temperature_k
        with np.errstate(over="ignore"):
            return float(self.dark_current_ref_e_per_s * np.exp2(exponent))   # inf, not OverflowError


class CameraFile(ConfigModel):
    """A camera TOML file (e.g. ``sitedata/cameras/mer_a.toml``)."""

    camera: CameraName
    """``[camera]``: identification."""
    detector: Detector
    """``[detector]``: the CCD array and its binning."""
    geometry: Geometry
    """``[geometry]``: intrinsics or a CAHVOR model."""
    mounting: Mounting
    """``[mounting]``: camera-to-lander rotation and position."""
    timing: Timing
    """``[timing]``: flush, exposure, frame transfer, read-out (s)."""
    radiometry: Radiometry
    """``[radiometry]``: optics and CCD photo response."""
    electronics: Electronics
    """``[electronics]``: dark current, wells, ADC."""
    optics: Optics = Optics()
    """``[optics]``: point-spread function (optional; default diffraction over a flat band)."""

    @model_validator(mode="after")
    def _geometry_is_usable(self):
        model = self.geometry.to_cahvor(self.detector)
        _check_distortion_increases_to_corners(model, self.detector.width_px, self.detector.height_px)
        return self

    @model_validator(mode="after")
    def _optics_in_band(self):
        band = (self.radiometry.band_min_um, self.radiometry.band_max_um)
        table = self.optics.spectral_wavelengths_um
        if table is not None and (table[0] > band[0] or table[-1] < band[1]):
            raise FieldProblem("optics.spectral_wavelengths_um", f"cover {table[0]:g} .. {table[-1]:g} um; allowed: "
                               f"from radiometry.band_min_um ({band[0]:g}) to band_max_um ({band[1]:g}) or wider")
        largest = MAX_WAVEFRONT_ERROR_WAVES * band[0]
        if self.optics.wavefront_error_rms_um > largest:
            raise FieldProblem("optics.wavefront_error_rms_um", f"= {self.optics.wavefront_error_rms_um:g} is out of "
                               f"range; allowed: <= {MAX_WAVEFRONT_ERROR_WAVES:g} waves at radiometry.band_min_um, "
                               f"i.e. <= {largest:.4g} um")
        return self


def _check_distortion_increases_to_corners(model: cahvor.Cahvor, width: int, height: int) -> None:
    """The radial distortion must keep increasing out to the frame corners.

    Otherwise rays fold back and several field angles share one pixel. The field of view must also lie in
    :data:`FOV_RANGE_DEG`.
    """
    turning = cahvor.distortion_turning_point(model.r)
    if np.isfinite(turning):
        r0, r1, r2 = model.r
        largest = turning * (1.0 + r0 + r1 * turning**2 + r2 * turning**4)          # distorted tangent
        corners = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5], [width - 0.5, height - 0.5]])
        corner = float(np.max(np.hypot((corners[:, 0] - model.hc) / model.hs, (corners[:, 1] - model.vc) / model.vs)))
        if corner >= largest:
            raise FieldProblem("geometry.radial_distortion",
                               f"= [{', '.join(f'{value:g}' for value in model.r)}] stops increasing "
                               f"{largest * model.hs:.0f} px from the principal point, inside the frame (corner at "
                               f"{corner * model.hs:.0f} px); allowed: a distortion that increases out to the frame corners")
    horizontal, vertical = field_of_view_deg(model, width, height)
    low, high = FOV_RANGE_DEG
    if not (low < horizontal < high and low < vertical < high):
        raise FieldProblem("geometry", f"gives a field of view of {horizontal:.1f} x {vertical:.1f} deg; allowed: "
                           f"{low:g} to {high:g} deg (check focal_length_m and pixel_pitch_m)")
