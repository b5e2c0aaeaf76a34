"""Appearance-class parameters of the synthetic MOC-like terrain (paper Figs. 7 and 9, section 5).

Every parameter is a physical quantity with a unit in its name (angles in degrees: this is the
configuration edge). The presets below give one class each; the numbers and their sources:

* Albedo: normal albedo (I/F at normal incidence, normal emission, zero phase) in the MOC band.
  Gusev plains are moderately bright and dusty (TES Lambert albedo ~0.22-0.26; dark dust devil
  tracked plains ~0.18-0.2), Meridiani hematite plains are dark (~0.13-0.16) with brighter smooth
  areas (Golombek et al. 2003, JGR 108(E12) 8072; Christensen et al. 2000). The relative spread is
  the RMS of the fractal albedo field over the strip (outer scale 1 km), chosen so that the class
  contrast follows the paper's description: gcp/hbsp "low contrast overall", gdcp/hdcp "lower
  albedo, cratered plains", heb ejecta apron, gkep knobs of positive relief.
* Relief: RMS bidirectional slope at the 3 m pixel baseline; MOC photoclinometry/stereo of the MER
  sites gives a few degrees for Gusev and ~1 deg for Meridiani, the smoothest site (Kirk et al. 2003,
  JGR 108(E12) 8088; Beyer et al. 2003). Hurst exponent 0.8 (self-affine Mars plains, Shepard 2001).
* Craters: cumulative density N(>20 m) per km^2 and the cumulative SFD exponent b (about 2 near the
  small-crater equilibrium reached on the Gusev plains, Golombek et al. 2006); "few craters" for
  gcp and hbsp, cratered plains for gdcp and hdcp. Depth/diameter log-uniform between degraded
  hollows (0.02-0.03) and fresh simple craters (0.15-0.2, Pike 1977); Meridiani craters are
  shallow, sand-filled. gcp has "bright crater rims" (paper Fig. 7).
* Dust devil tracks (gdcp): 8-30 m wide, up to kilometres long, the freshest ~16 % darker than the
  dusty plains (older ones fainter), preferred NW-SE orientation in the MOC images of the Gusev
  ellipse (Greeley et al. 2005, 2006).
* Knobs/mesas (gkep): 20-150 m across, 4-25 m high, 25 per km^2 (etched plains south-east of the
  Gusev ellipse).
* heb: a ~2 km crater every 6 km along the strip, centred just off alternate strip edges, with
  continuous hummocky ejecta to 3 radii (thickness ~ r^-3, McGetchin et al. 1973), albedo rays and
  secondaries (Melosh 1989).
* MOC observation: the selected MOC images had incidence and phase < 60 deg, emission < 30 deg
  (paper 2.3); lit from the left (west) as MOC images of both sites are. Haze: dust optical depth
  ~0.5 during the 1999-2003 MOC coverage (TES, Smith 2004); path I/F from single scattering (see
  :mod:`sitedata.terrain.synthetic_terrain`). Grain: MOC NA SNR ~60 at the strip mean.

**Calibration source of the default presets: MER-A flight, paper Table 3** (issue 30). The presets
``<class>_rough_moc`` below are the issue-15 terrain, each class calibrated to real MOC NA ground of its
kind (next paragraph); on them the reference estimator's templates have a median contrast/brightness of
2.8 % (gcp) and 3.7 % (gdcp), against 1.01 / 1.07 / 1.18 % for the three MER-A flight templates of Table 3
(contrast 47.5 / 41.7 / 55.6 DN over brightness 4710 / 3898 / 4693 DN, the DIMES flight software on the
Spirit descent images). The default presets ``<class>`` are the rough ones with ``contrast_scale``
(:data:`FLIGHT_CONTRAST_SCALE`): the whole height field and every albedo modulation times that factor
(:mod:`sitedata.terrain.synthetic_terrain`). Fitted with :mod:`campaign.studies.calibrate_contrast`
(``python -m campaign.studies.calibrate_contrast sitedata/gusev.toml --cases 16 --contrast-scale 0.25 0.3 0.35
--fit-classes gcp,gdcp,site`` on the rough presets): the factor at which the ellipse-weighted median
contrast/brightness of every template the estimator selects on Gusev cases (gcp 59 %, gdcp 41 %) equals the
flight median, 1.07 %, interpolated in log(scale): 0.26 (measured 2026-11-27, 16 cases per class: 1.04 %
at 0.25, 1.16 % at 0.30, 1.29 % at 0.35). One factor for both ellipse classes because the flight's three
templates come from one descent over ground not assigned to a class (MOC images of the landing area,
MOC2-596, show dust-devil streaks on bright plains), and the only evidence on the classes' relative
contrast is the issue-15 calibration, which the common factor keeps; at 0.26 gcp gives ~1.0 % and gdcp
~1.15 %, the span of the flight templates. gkep (ellipse fraction 0, no flight evidence) and the
Meridiani classes (no flight contrast evidence at all: MER-B's descent images are not in the paper)
take the same factor: the reference ground of issue 15 overstated Gusev's contrast ~3x, nothing says it
did less elsewhere, and a common factor keeps the paper's ordering ("tuned to Gusev where there is more
scene contrast"; hbsp lowest). How template contrast and validity vary with the factor, per class:
``sitedata/sweeps/terrain_contrast_gusev.toml`` and ``..._meridiani.toml`` (docs/realism.md).

The literature values are order-of-magnitude anchors (quoted from memory of the MER landing-site
papers, not re-derived here). Within them, the rough presets' albedo spreads and spectra, slopes and crater
densities and depths are calibrated to real MOC NA images (issue 15; :mod:`campaign.realism.terrain_reference`): each class's
RMS contrast in descent-footprint tiles at the MER camera's sample at 1 and 2 km, and its density of
>= 5 % dark features 30-120 m across, lie inside the range measured on real ground of its kind
(smooth plains: gcp, hbsp; textured/cratered plains: gdcp, hdcp, heb; knobby: gkep), and the 4-64 px
PSD slope inside that of the real MOC/CTX images (tests/campaign/realism/test_terrain_calibration.py). The paper's
ordering is kept (tests/sitedata/terrain/test_synthetic_terrain.py): RMS contrast hbsp < gcp < hdcp < {gdcp, heb} and
gcp < gkep, Gusev (ellipse-weighted) above Meridiani ("tuned to Gusev where there is more scene
contrast"), fewer dark features on gcp/hbsp than on the other classes.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TypedDict

#: Outer scale of the albedo and relief spectra (m): patches larger than this are not brighter.
OUTER_SCALE_M = 1000.0
#: Largest terrain contrast scale (a preset's, or a site file's on top of it).
CONTRAST_SCALE_MAX = 4.0


@dataclass(frozen=True)
class ClassTerrainParams:
    """Physical description of one appearance class (angles in degrees at this config edge)."""

    name: str
    description: str = ""
    # strip geometry
    rows: int = 5000
    cols: int = 1000
    metres_per_pixel: float = 3.0
    # normal albedo (I/F at i = e = alpha = 0)
    normal_albedo_mean: float = 0.25
    albedo_relative_spread: float = 0.04          # RMS / mean of the fractal albedo
    albedo_spectral_exponent: float = 2.6         # P(k) ~ k^-beta
    # background relief
    rms_slope_deg: float = 3.0                    # bidirectional, at the 1-pixel baseline
    hurst_exponent: float = 0.8
    # craters: N(>D) = density * (D / reference)^-exponent per km^2
    crater_density_per_km2: float = 50.0
    crater_reference_diameter_m: float = 20.0
    crater_sfd_exponent: float = 2.0              # cumulative; ~2 near equilibrium
    crater_min_diameter_m: float = 9.0
    crater_max_diameter_m: float = 500.0
    crater_depth_to_diameter: tuple[float, float] = (0.03, 0.15)   # degraded .. fresh
    crater_rim_albedo_contrast: float = 0.04      # fractional brightening at the rim crest
    # dust devil tracks
    track_length_per_km2: float = 0.0             # km of track per km^2
    track_width_m: tuple[float, float] = (10.0, 40.0)
    track_albedo_contrast: float = 0.10           # fractional darkening of the freshest track
    track_azimuth_deg: float = 135.0
    track_azimuth_spread_deg: float = 25.0
    track_mean_length_m: float = 2000.0
    # knobs / mesas
    knob_density_per_km2: float = 0.0
    knob_diameter_m: tuple[float, float] = (40.0, 250.0)
    knob_height_m: tuple[float, float] = (5.0, 40.0)
    knob_albedo_contrast: float = 0.05
    # large crater with ejecta apron
    ejecta_crater_diameter_m: float = 0.0         # 0: none
    ejecta_crater_spacing_m: float = 6000.0       # along the strip
    ejecta_extent_radii: float = 3.0              # continuous ejecta reaches this many radii
    ejecta_ray_albedo_contrast: float = 0.0
    ejecta_blanket_albedo_contrast: float = 0.0   # fractional albedo change near the rim
    ejecta_relief_rms_m: float = 0.0              # hummocky blanket relief at the rim
    secondary_density_per_km2: float = 0.0        # N(>D_ref) on the apron, extra to the plains
    # MOC observation
    moc_incidence_deg: float = 45.0
    moc_emission_deg: float = 0.0
    moc_sun_azimuth_deg: float = 260.0            # clockwise from north (MOC: lit from the left)
    moc_spacecraft_azimuth_deg: float = 90.0
    haze_optical_depth: float = 0.5
    haze_path_if: float = 0.04
    grain_snr: float = 60.0
    # calibration: the height field (background relief, craters, knobs, ejecta) and every albedo
    # modulation (albedo spread, rim, track, knob, ejecta contrasts) are multiplied by this
    contrast_scale: float = 1.0

    def validate(self) -> None:
        """Raise ValueError naming the preset, field and allowed range for nonsense values."""
        checks = [
            ("rows", self.rows >= 64, ">= 64"), ("cols", self.cols >= 64, ">= 64"),
            ("metres_per_pixel", self.metres_per_pixel > 0, "> 0"),
            ("normal_albedo_mean", 0.01 <= self.normal_albedo_mean <= 0.6, "0.01 .. 0.6"),
            ("albedo_relative_spread", 0 <= self.albedo_relative_spread <= 0.5, "0 .. 0.5"),
            ("albedo_spectral_exponent", 0 <= self.albedo_spectral_exponent <= 4, "0 .. 4"),
            ("rms_slope_deg", 0 <= self.rms_slope_deg <= 30, "0 .. 30"),
            ("hurst_exponent", 0 < self.hurst_exponent < 1, "0 < H < 1"),
            ("crater_density_per_km2", self.crater_density_per_km2 >= 0, ">= 0"),
            ("crater_min_diameter_m", 0 < self.crater_min_diameter_m < self.crater_max_diameter_m,
             "> 0 and < crater_max_diameter_m"),
            ("crater_depth_to_diameter", 0 < self.crater_depth_to_diameter[0] <= self.crater_depth_to_diameter[1] <= 0.3,
             "0 < min <= max <= 0.3"),
            ("track_albedo_contrast", 0 <= self.track_albedo_contrast < 1, "0 .. <1"),
            ("track_width_m", 0 < self.track_width_m[0] <= self.track_width_m[1], "0 < min <= max"),
            ("knob_diameter_m", 0 < self.knob_diameter_m[0] <= self.knob_diameter_m[1], "0 < min <= max"),
            ("knob_height_m", 0 <= self.knob_height_m[0] <= self.knob_height_m[1], "0 <= min <= max"),
            ("ejecta_crater_diameter_m", self.ejecta_crater_diameter_m >= 0, ">= 0 (0: none)"),
            ("ejecta_crater_spacing_m", self.ejecta_crater_spacing_m > 0, "> 0"),
            ("ejecta_extent_radii", 1.5 <= self.ejecta_extent_radii <= 6, "1.5 .. 6"),
            ("moc_incidence_deg", 0 <= self.moc_incidence_deg < 85, "0 .. 85"),
            ("moc_emission_deg", 0 <= self.moc_emission_deg <= 60, "0 .. 60"),
            ("haze_optical_depth", 0 <= self.haze_optical_depth <= 5, "0 .. 5"),
            ("haze_path_if", 0 <= self.haze_path_if <= 0.3, "0 .. 0.3"),
            ("grain_snr", self.grain_snr > 0, "> 0"),
            ("contrast_scale", 0 < self.contrast_scale <= CONTRAST_SCALE_MAX, f"0 < scale <= {CONTRAST_SCALE_MAX:g}"),
        ]
        for field, ok, allowed in checks:
            if not ok:
                raise ValueError(f"synthetic terrain preset {self.name!r}: {field} = {getattr(self, field)!r} "
                                 f"is out of range; allowed: {allowed}")

    @property
    def area_km2(self) -> float:
        return self.rows * self.cols * (self.metres_per_pixel / 1000.0) ** 2


class _MocObservation(TypedDict):
    """The MOC observation and haze fields a site's presets share."""

    moc_incidence_deg: float
    moc_sun_azimuth_deg: float
    haze_optical_depth: float
    haze_path_if: float


_GUSEV_MOC = _MocObservation(moc_incidence_deg=45.0, moc_sun_azimuth_deg=255.0, haze_optical_depth=0.5,
                             haze_path_if=0.045)
_MERIDIANI_MOC = _MocObservation(moc_incidence_deg=40.0, moc_sun_azimuth_deg=260.0, haze_optical_depth=0.5,
                                 haze_path_if=0.04)

# The rough MOC ground (presets "<class>_rough_moc").
# Calibrated (issue 15) so that each class's footprint-tile contrast at the descent camera's sample (1 and
# 2 km) and its dark-feature density fall inside the real MOC NA range of its kind of ground
# (campaign/realism/terrain_reference.py: RECORDED_RANGES, KIND_OF_CLASS); the previous presets were 1.6-5x blander
# than real MOC I/F and had almost no >= 5 % dark features. Albedo spectra at beta = 2.2-2.4 (was 2.6:
# real MOC plains have PSD slopes -1.4 .. -1.6, i.e. more small-scale texture); deeper fresh craters.
_ROUGH_MOC: dict[str, ClassTerrainParams] = {
    "gcp": ClassTerrainParams(
        name="gcp_rough_moc", description="Gusev cratered plains: bright, smooth, few craters, bright rims, low contrast",
        normal_albedo_mean=0.27, albedo_relative_spread=0.072, albedo_spectral_exponent=2.2, rms_slope_deg=3.0,
        crater_density_per_km2=40.0, crater_max_diameter_m=400.0, crater_depth_to_diameter=(0.03, 0.18),
        crater_rim_albedo_contrast=0.06, **_GUSEV_MOC),
    "gdcp": ClassTerrainParams(
        name="gdcp_rough_moc", description="Gusev dark cratered plains: lower albedo, dark dust devil tracks, craters",
        normal_albedo_mean=0.22, albedo_relative_spread=0.10, albedo_spectral_exponent=2.4, rms_slope_deg=4.0,
        crater_density_per_km2=70.0, crater_depth_to_diameter=(0.04, 0.2),
        track_length_per_km2=4.0, track_width_m=(8.0, 30.0), track_albedo_contrast=0.16,
        track_mean_length_m=1200.0, **_GUSEV_MOC),
    "gkep": ClassTerrainParams(
        name="gkep_rough_moc", description="Gusev knobby etched plains: knobs and mesas of positive relief",
        normal_albedo_mean=0.24, albedo_relative_spread=0.06, albedo_spectral_exponent=2.2, rms_slope_deg=4.0,
        crater_density_per_km2=100.0, knob_density_per_km2=50.0, knob_diameter_m=(20.0, 150.0),
        knob_height_m=(5.0, 40.0), knob_albedo_contrast=0.06, **_GUSEV_MOC),
    "hbsp": ClassTerrainParams(
        name="hbsp_rough_moc", description="Meridiani hematite bright smooth plains: few craters, low contrast",
        normal_albedo_mean=0.19, albedo_relative_spread=0.055, albedo_spectral_exponent=2.2, rms_slope_deg=1.0,
        crater_density_per_km2=80.0, crater_max_diameter_m=300.0, crater_depth_to_diameter=(0.04, 0.2),
        crater_rim_albedo_contrast=0.03, **_MERIDIANI_MOC),
    "hdcp": ClassTerrainParams(
        name="hdcp_rough_moc", description="Meridiani hematite dark cratered plains: lower albedo, cratered",
        normal_albedo_mean=0.14, albedo_relative_spread=0.09, albedo_spectral_exponent=2.2, rms_slope_deg=3.5,
        crater_density_per_km2=200.0, crater_depth_to_diameter=(0.05, 0.2), **_MERIDIANI_MOC),
    "heb": ClassTerrainParams(
        name="heb_rough_moc", description="Meridiani hematite ejecta blanket: apron around a large crater",
        normal_albedo_mean=0.16, albedo_relative_spread=0.10, albedo_spectral_exponent=2.2, rms_slope_deg=3.5,
        crater_density_per_km2=60.0, crater_depth_to_diameter=(0.05, 0.2),
        ejecta_crater_diameter_m=2000.0, ejecta_crater_spacing_m=6000.0, ejecta_extent_radii=3.0,
        ejecta_ray_albedo_contrast=0.1, ejecta_blanket_albedo_contrast=0.1, ejecta_relief_rms_m=3.0,
        secondary_density_per_km2=100.0,
        **_MERIDIANI_MOC),
}

#: Contrast scale of each default class (see the module docstring: MER-A flight, paper Table 3).
#: One factor for every class: fitted on the Gusev ellipse (gcp, gdcp), carried to gkep and to Meridiani.
GUSEV_FLIGHT_CONTRAST_SCALE = 0.26
FLIGHT_CONTRAST_SCALE: dict[str, float] = {name: GUSEV_FLIGHT_CONTRAST_SCALE
                                           for name in ("gcp", "gdcp", "gkep", "hbsp", "hdcp", "heb")}

#: The default presets (calibrated to MER-A flight) and the rough-MOC-ground variants ``<class>_rough_moc``.
CLASS_PRESETS: dict[str, ClassTerrainParams] = {
    **{name: dataclasses.replace(rough, name=name, contrast_scale=FLIGHT_CONTRAST_SCALE[name])
       for name, rough in _ROUGH_MOC.items()},
    **{rough.name: rough for rough in _ROUGH_MOC.values()},
}
