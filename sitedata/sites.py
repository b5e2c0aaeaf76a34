"""Landing-site files: appearance classes, ellipse fractions, sun at landing, camera, trajectory set.

A site TOML (``sitedata/gusev.toml``, ``sitedata/meridiani.toml``) holds one ``[site]`` table::

    [site]
    name = "Gusev"
    camera = "cameras/mer_a.toml"                  # relative to the TOML file
    trajectory_set = "trajectories/gusev.parquet"

    [site.sun]                                     # at landing
    azimuth_deg = 267.9                            # clockwise from north
    elevation_deg = 56.8
    heliocentric_distance_au = 1.478

    [[site.classes]]
    name = "gcp"
    ellipse_fraction = 0.59                        # fractions of all classes sum to 1
    cases = 186
    terrain = { kind = "synthetic", preset = "gcp", seed = 1 }          # or
    # terrain = { kind = "file", path = "x.img", sidecar = "x.toml" }  # sidecar optional

Optional in either terrain table: ``resample = "none" | "stretch" | "mosaic"`` (default "none"): what
the campaign does with a terrain too small for the descent images' footprints (refuse it, show the
same image at the coarser scale that holds them, or mirror-tile it; :mod:`campaign.plan.coverage`).

Optional in a synthetic terrain table: ``overrides = { haze_optical_depth = 0.3, ... }`` (numeric
fields of :class:`sitedata.terrain.synthetic_classes.ClassTerrainParams`), ``contrast_scale = 0.5`` (the
preset's relief and albedo contrasts times this, on top of the preset's own calibrated scale) and
``relief = true`` (the class's height field with the I/F of level ground, :mod:`sitedata.terrain.relief`).
Optional in ``[site]``: ``terrain_contrast_scale`` multiplies every synthetic class's ``contrast_scale``
(the axis of the terrain-contrast sweeps, ``sitedata/sweeps/terrain_contrast_*.toml``). The ``[site]`` table is declared
once, by :class:`Site` and its parts (:class:`Sun`, :class:`SiteClass`, :class:`SyntheticTerrain`,
:class:`FileTerrain`); ``campaign schema site`` prints it. Other top-level tables (``[campaign]``,
``[sensors]``, ...) belong to other readers and are ignored here; unknown keys inside ``[site]`` are
errors. Every error is one line naming the file, the field and what is allowed.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeAlias

import numpy as np
from pydantic import Field, PrivateAttr, ValidationInfo, create_model, model_validator

from config_tables.errors import ConfigError, FieldProblem
from config_tables.models import ConfigModel, ExistingFile, InputPath, fixed_vector, parse
from config_tables.toml_file import load_toml
from simulator.scene.height_field import ReliefTerrain
from simulator.scene.terrain import Terrain
from sitedata.terrain.real_terrain import load_terrain
from sitedata.terrain.relief import relief_terrain
from sitedata.terrain.synthetic_classes import CLASS_PRESETS, CONTRAST_SCALE_MAX, ClassTerrainParams
from sitedata.terrain.synthetic_terrain import synthetic_terrain

ASTRONOMICAL_UNIT_M = 1.495978707e11
FRACTION_TOLERANCE = 1e-6
MAX_CASES = 1_000_000
#: What the campaign does with a terrain too small for the footprints (:mod:`campaign.plan.coverage`).
Resample = Literal["none", "stretch", "mosaic"]
RESAMPLE_MODES = typing.get_args(Resample)


def sun_direction(azimuth_rad: float, elevation_rad: float) -> np.ndarray:
    """Unit vector toward the sun (east, north, up) from azimuth (clockwise from north) and elevation."""
    return np.array([math.cos(elevation_rad) * math.sin(azimuth_rad),
                     math.cos(elevation_rad) * math.cos(azimuth_rad),
                     math.sin(elevation_rad)])


class Sun(ConfigModel):
    """``[site.sun]``: the sun at landing."""

    azimuth_deg: float = Field(ge=0.0, lt=360.0)
    """Clockwise from north (deg)."""
    elevation_deg: float = Field(gt=0.0, le=90.0)
    """Above the horizon (deg)."""
    heliocentric_distance_au: float = Field(ge=1.38, le=1.67)
    """Mars-Sun distance (AU)."""


def _overrides_model() -> type[ConfigModel]:
    """``overrides``: any numeric field of :class:`ClassTerrainParams` (declared there, with its ranges in
    ``ClassTerrainParams.validate``), optional."""
    fields: dict[str, Any] = {}
    for field in dataclasses.fields(ClassTerrainParams):
        if field.name in ("name", "description", "contrast_scale"):     # contrast_scale: the terrain's own key
            continue
        default = field.default
        if isinstance(default, tuple):
            annotation = fixed_vector(len(default))
        elif isinstance(default, int):
            annotation = Annotated[int, Field(ge=1)]
        else:
            annotation = float
        fields[field.name] = (annotation | None, None)
    return create_model("TerrainOverrides", __base__=ConfigModel, __doc__=_overrides_model.__doc__, **fields)


if TYPE_CHECKING:
    # Built at run time from the dataclass's fields; statically what every such model is: a ConfigModel
    # whose model_dump() gives keyword arguments of dataclasses.replace(ClassTerrainParams, ...).
    TerrainOverrides: TypeAlias = ConfigModel
    #: A name of CLASS_PRESETS (its keys, checked at run time).
    PresetName: TypeAlias = str
else:
    TerrainOverrides = _overrides_model()
    PresetName = Literal[tuple(CLASS_PRESETS)]


class _TerrainSpec(ConfigModel):
    resample: Resample = "none"
    """A terrain too small for the descent images' footprints: "none" refuses it, "stretch" shows the
    same image at the coarser scale that holds them, "mosaic" mirror-tiles it (campaign.plan.coverage)."""
    _where: str = PrivateAttr("")

    @property
    def source(self) -> str:
        """``"file: site.classes[i].terrain"`` for error messages."""
        return self._where


class SyntheticTerrain(_TerrainSpec):
    """A synthetic appearance-class terrain: preset + seed (+ overrides), generated and cached."""

    kind: Literal["synthetic"]
    preset: PresetName
    """Appearance-class preset (sitedata.terrain.synthetic_classes)."""
    seed: int = Field(ge=0, le=2**63 - 1)
    """Seed of the terrain generator."""
    overrides: TerrainOverrides | None = None
    """Preset parameters changed for this class."""
    contrast_scale: float = Field(1.0, gt=0.0, le=CONTRAST_SCALE_MAX)
    """Multiplies the preset's relief and albedo contrasts (its own contrast_scale; sitedata.terrain.synthetic_terrain):
    1 = the preset; a site's terrain_contrast_scale multiplies it too."""
    relief: bool = False
    """Give the class its height field (craters, knobs, slopes of the preset), rendered with parallax,
    occlusion, slope shading and cast shadows (sitedata.terrain.relief, simulator.scene.relief)."""

    @model_validator(mode="after")
    def _overrides_are_valid(self):
        try:
            self.params().validate()
        except ValueError as exc:
            raise FieldProblem("overrides", f": {exc}") from None
        return self

    def params(self) -> ClassTerrainParams:
        """The preset's parameters with the overrides applied."""
        changes: dict[str, Any] = self.overrides.model_dump(exclude_none=True) if self.overrides is not None else {}
        params = CLASS_PRESETS[self.preset]
        if self.contrast_scale != 1.0:
            changes["contrast_scale"] = params.contrast_scale * self.contrast_scale
        return dataclasses.replace(params, **changes)


class FileTerrain(_TerrainSpec):
    """Terrain from an orbital image file, with an optional side-car TOML (file_formats.planetary)."""

    kind: Literal["file"]
    path: InputPath
    """The image, relative to the site file."""
    sidecar: InputPath | None = None
    """Side-car TOML, relative to the site file (default: none)."""


TerrainSpec = Annotated[SyntheticTerrain | FileTerrain, Field(discriminator="kind")]


class SiteClass(ConfigModel):
    """``[[site.classes]]``: one appearance class of the landing ellipse."""

    name: str = Field(min_length=1)
    """Class name (unique within the site)."""
    ellipse_fraction: float = Field(ge=0.0, le=1.0)
    """Fraction of the landing ellipse; the fractions of all classes sum to 1."""
    cases: int = Field(ge=0, le=MAX_CASES)
    """Monte Carlo cases of the class."""
    terrain: TerrainSpec
    """Where the class's terrain comes from."""


class Site(ConfigModel):
    """``[site]``: a landing site. Paths are resolved against the site file's directory; the sun is in
    degrees here, radians and a direction vector through the properties."""

    name: str = Field(min_length=1)
    """Site name."""
    camera: ExistingFile
    """Camera TOML, relative to the site file."""
    trajectory_set: InputPath
    """EDL trajectory set (.parquet / .csv), relative to the site file."""
    sun: Sun
    classes: list[SiteClass] = Field(min_length=1)
    """Appearance classes ([[site.classes]])."""
    terrain_contrast_scale: float = Field(1.0, gt=0.0, le=CONTRAST_SCALE_MAX)
    """Multiplies the contrast_scale of every synthetic class terrain (a sweep axis: site.terrain_contrast_scale)."""
    _source: Path = PrivateAttr(Path("."))

    @model_validator(mode="before")
    @classmethod
    def _site_contrast_scale_reaches_each_class(cls, data: Any) -> Any:
        # the scale is carried into each synthetic terrain table (its contrast_scale times this), so a
        # class's terrain spec alone names its terrain (caches, hashes); non-numbers are left to the
        # field checks
        scale = data.get("terrain_contrast_scale", 1.0) if isinstance(data, dict) else 1.0
        if (isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < scale <= CONTRAST_SCALE_MAX
                or scale == 1.0 or not isinstance(data.get("classes"), list)):
            return data
        classes = []
        for entry in data["classes"]:
            terrain = entry.get("terrain") if isinstance(entry, dict) else None
            if isinstance(terrain, dict) and terrain.get("kind") == "synthetic":
                own = terrain.get("contrast_scale", 1.0)
                if isinstance(own, (int, float)) and not isinstance(own, bool):
                    entry = {**entry, "terrain": {**terrain, "contrast_scale": float(own) * float(scale)}}
            classes.append(entry)
        return {**data, "classes": classes}

    @model_validator(mode="after")
    def _classes_are_consistent(self, info: ValidationInfo):
        # private attributes (where the site and each terrain came from, for messages) are set here,
        # while validating, from the validation context; nothing sets them after validation
        self._source = Path((info.context or {}).get("site_path", "."))
        seen: set[str] = set()
        for index, entry in enumerate(self.classes):
            if entry.name in seen:
                raise FieldProblem(f"classes[{index}].name", f"= {entry.name!r} is a duplicate; class names must be unique")
            seen.add(entry.name)
            entry.terrain._where = f"{(info.context or {}).get('source', '<site>')}: site.classes[{index}].terrain"
        total = sum(entry.ellipse_fraction for entry in self.classes)
        if abs(total - 1.0) > FRACTION_TOLERANCE:
            raise FieldProblem("classes", f"ellipse_fraction values sum to {total:.9g}; allowed: 1 within "
                               f"{FRACTION_TOLERANCE:g}")
        return self

    @property
    def source(self) -> Path:
        return self._source

    @property
    def camera_path(self) -> Path:
        return self.camera

    @property
    def trajectory_path(self) -> Path:
        return self.trajectory_set

    @property
    def sun_azimuth_rad(self) -> float:
        return math.radians(self.sun.azimuth_deg)

    @property
    def sun_elevation_rad(self) -> float:
        return math.radians(self.sun.elevation_deg)

    @property
    def sun_direction_world(self) -> np.ndarray:
        """Unit vector (3,) from the ground toward the sun in the world frame (x east, y north, z up)."""
        return sun_direction(self.sun_azimuth_rad, self.sun_elevation_rad)

    @property
    def heliocentric_distance_au(self) -> float:
        return self.sun.heliocentric_distance_au

    @property
    def heliocentric_distance_m(self) -> float:
        return self.sun.heliocentric_distance_au * ASTRONOMICAL_UNIT_M

    @property
    def sun_incidence_rad(self) -> float:
        """Solar incidence angle on level ground (rad)."""
        return 0.5 * math.pi - self.sun_elevation_rad

    def class_named(self, name: str) -> SiteClass:
        for site_class in self.classes:
            if site_class.name == name:
                return site_class
        raise KeyError(f"site {self.name}: no appearance class {name!r}; "
                       f"classes: {', '.join(c.name for c in self.classes)}")


def site_from_data(data: dict, path: str | Path, source: str | None = None) -> Site:
    """Validate the ``[site]`` table of parsed TOML ``data`` read from ``path`` (relative paths resolve
    against its directory; ``source`` names the data in errors, default ``path``)."""
    path = Path(path)
    label = source or str(path)
    if not isinstance(data, dict) or "site" not in data:
        raise ConfigError(f"{label}: site is missing (a [site] table with the site, camera, sun and classes)")
    return parse(Site, data["site"], label, "site",
                 context={"base_dir": path.parent, "source": label, "site_path": path})


def load_site(path: str | Path) -> Site:
    """Read and validate the ``[site]`` table of a site TOML file.

    Raises
    ------
    ConfigError
        One line naming the file, the field and what is allowed.
    """
    return site_from_data(load_toml(path), path)


def class_terrain_params(spec: TerrainSpec) -> ClassTerrainParams:
    """The synthetic parameters of a ``kind = "synthetic"`` spec (preset plus overrides)."""
    if spec.kind != "synthetic":
        raise ConfigError(f"{spec.source}.kind = {spec.kind!r} has no synthetic parameters")
    return spec.params()


def load_class_terrain(spec: TerrainSpec, cache: bool = True) -> Terrain:
    """Build (synthetic, cached on disk) or read (file) the terrain of one appearance class.

    With ``cache`` the last few terrains are also kept in memory (a worker builds or reads each
    terrain once, not once per case); their reflectance arrays are read-only.
    """
    if cache:
        return _memoised_class_terrain(spec)
    return _class_terrain(spec, cache=False)


@functools.lru_cache(maxsize=4)
def _memoised_class_terrain(spec: TerrainSpec) -> Terrain:
    terrain = _class_terrain(spec, cache=True)
    terrain.reflectance_if.setflags(write=False)
    if isinstance(terrain, ReliefTerrain):
        terrain.height_m.setflags(write=False)
    return terrain


def _class_terrain(spec: TerrainSpec, cache: bool) -> Terrain:
    if spec.kind == "synthetic" and spec.relief:
        return relief_terrain(class_terrain_params(spec), spec.seed, cache=cache)
    if spec.kind == "synthetic":
        return synthetic_terrain(class_terrain_params(spec), spec.seed, cache=cache)
    if not spec.path.is_file():
        raise ConfigError(f"{spec.source}.path: no such file {spec.path}")
    return load_terrain(spec.path, spec.sidecar)
