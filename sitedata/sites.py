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
same image at the coarser scale that holds them, or mirror-tile it; :mod:`campaign.coverage`).

Optional in a synthetic terrain table: ``overrides = { haze_optical_depth = 0.3, ... }`` (numeric
fields of :class:`sitedata.synthetic_classes.ClassTerrainParams`). Other top-level tables
(``[campaign]``, ``[sensors]``, ...) belong to other readers and are ignored here; unknown keys
inside ``[site]`` are errors. Every error is one line naming the file, the field and what is allowed.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simulator.scene.terrain import Terrain
from flight_interface.tomlfields import ConfigError, Table, load_toml

from .synthetic_classes import CLASS_PRESETS, ClassTerrainParams

ASTRONOMICAL_UNIT_M = 1.495978707e11
FRACTION_TOLERANCE = 1e-6

_SITE_KEYS = ("name", "camera", "trajectory_set", "sun", "classes")
_SUN_KEYS = ("azimuth_deg", "elevation_deg", "heliocentric_distance_au")
_CLASS_KEYS = ("name", "ellipse_fraction", "cases", "terrain")
_TERRAIN_KEYS = {"synthetic": ("kind", "preset", "seed", "overrides", "resample"),
                 "file": ("kind", "path", "sidecar", "resample")}
RESAMPLE_MODES = ("none", "stretch", "mosaic")
_OVERRIDABLE = tuple(f.name for f in dataclasses.fields(ClassTerrainParams)
                     if f.name not in ("name", "description"))


@dataclass(frozen=True)
class TerrainSpec:
    """Where a class's terrain comes from: a synthetic preset + seed, or an image file (+ side-car)."""

    kind: str                                   # "synthetic" or "file"
    source: str                                 # "file: dotted.path" for error messages
    preset: str | None = None
    seed: int | None = None
    overrides: tuple[tuple[str, object], ...] = ()
    path: Path | None = None
    sidecar: Path | None = None
    resample: str = "none"                      # "none" | "stretch" | "mosaic" (campaign.coverage)


@dataclass(frozen=True)
class SiteClass:
    """One appearance class of a site."""

    name: str
    ellipse_fraction: float
    cases: int
    terrain: TerrainSpec


@dataclass(frozen=True)
class Site:
    """A landing site (SI units, radians).

    Attributes
    ----------
    sun_direction_world : ndarray (3,)
        Unit vector from the ground toward the sun in the world frame (x east, y north, z up).
    """

    name: str
    source: Path
    camera_path: Path
    trajectory_path: Path
    sun_azimuth_rad: float
    sun_elevation_rad: float
    sun_direction_world: np.ndarray
    heliocentric_distance_m: float
    classes: tuple[SiteClass, ...]

    @property
    def heliocentric_distance_au(self) -> float:
        return self.heliocentric_distance_m / ASTRONOMICAL_UNIT_M

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


def sun_direction(azimuth_rad: float, elevation_rad: float) -> np.ndarray:
    """Unit vector toward the sun (east, north, up) from azimuth (clockwise from north) and elevation."""
    return np.array([math.cos(elevation_rad) * math.sin(azimuth_rad),
                     math.cos(elevation_rad) * math.cos(azimuth_rad),
                     math.sin(elevation_rad)])


def _reject_unknown(table: Table, allowed) -> None:
    for key in table.data:
        if key not in allowed:
            raise table.fail(key, f"is not a known field; allowed: {', '.join(allowed)}")


def _terrain_spec(table: Table, base_dir: Path) -> TerrainSpec:
    kind = table.string("kind", choices=tuple(_TERRAIN_KEYS))
    _reject_unknown(table, _TERRAIN_KEYS[kind])
    source = f"{table.source}: {table.path}"
    resample = table.string("resample", default="none", choices=RESAMPLE_MODES)
    if kind == "file":
        sidecar = table.path_value("sidecar", base_dir) if table.has("sidecar") else None
        return TerrainSpec(kind="file", source=source, path=table.path_value("path", base_dir), sidecar=sidecar,
                           resample=resample)
    preset = table.string("preset", choices=tuple(CLASS_PRESETS))
    seed = table.integer("seed", minimum=0, maximum=2**63 - 1)
    overrides = []
    if table.has("overrides"):
        extra = table.table("overrides")
        _reject_unknown(extra, _OVERRIDABLE)
        for key in sorted(extra.data):
            default = getattr(CLASS_PRESETS[preset], key)
            if isinstance(default, tuple):
                value = tuple(float(v) for v in extra.vector(key, len(default)))
            elif isinstance(default, int):
                value = extra.integer(key, minimum=1)
            else:
                value = extra.number(key)
            overrides.append((key, value))
        try:
            dataclasses.replace(CLASS_PRESETS[preset], **dict(overrides)).validate()
        except ValueError as exc:
            raise ConfigError(f"{source}.overrides: {exc}") from None
    return TerrainSpec(kind="synthetic", source=source, preset=preset, seed=seed, overrides=tuple(overrides),
                       resample=resample)


def load_site(path: str | Path) -> Site:
    """Read and validate the ``[site]`` table of a site TOML file.

    Raises
    ------
    ConfigError
        One line naming the file, the field and what is allowed.
    """
    path = Path(path)
    root = Table(load_toml(path), str(path))
    site = root.table("site")
    _reject_unknown(site, _SITE_KEYS)
    base_dir = path.parent
    name = site.string("name")
    camera_path = site.path_value("camera", base_dir)
    if not camera_path.is_file():
        raise site.fail("camera", f"= {site.data['camera']!r}: no such file {camera_path}")
    trajectory_path = site.path_value("trajectory_set", base_dir)

    sun = site.table("sun")
    _reject_unknown(sun, _SUN_KEYS)
    azimuth = math.radians(sun.number("azimuth_deg", minimum=0.0, maximum=360.0, exclusive_maximum=True))
    elevation = math.radians(sun.number("elevation_deg", minimum=0.0, maximum=90.0, exclusive_minimum=True))
    distance_au = sun.number("heliocentric_distance_au", minimum=1.38, maximum=1.67)

    raw_classes = site.data.get("classes")
    if not isinstance(raw_classes, list) or not raw_classes:
        raise site.fail("classes", "must be a non-empty array of tables ([[site.classes]])")
    classes = []
    for index, raw in enumerate(raw_classes):
        entry = Table(raw, site.source, f"site.classes[{index}]")
        _reject_unknown(entry, _CLASS_KEYS)
        class_name = entry.string("name")
        if any(c.name == class_name for c in classes):
            raise entry.fail("name", f"= {class_name!r} is a duplicate; class names must be unique")
        classes.append(SiteClass(
            name=class_name,
            ellipse_fraction=entry.number("ellipse_fraction", minimum=0.0, maximum=1.0),
            cases=entry.integer("cases", minimum=0),
            terrain=_terrain_spec(entry.table("terrain"), base_dir)))
    total = sum(c.ellipse_fraction for c in classes)
    if abs(total - 1.0) > FRACTION_TOLERANCE:
        raise site.fail("classes", f"ellipse_fraction values sum to {total:.9g}; allowed: 1 within {FRACTION_TOLERANCE:g}")

    return Site(name=name, source=path, camera_path=camera_path, trajectory_path=trajectory_path,
                sun_azimuth_rad=azimuth, sun_elevation_rad=elevation,
                sun_direction_world=sun_direction(azimuth, elevation),
                heliocentric_distance_m=distance_au * ASTRONOMICAL_UNIT_M, classes=tuple(classes))


def class_terrain_params(spec: TerrainSpec) -> ClassTerrainParams:
    """The synthetic parameters of a ``kind = "synthetic"`` spec (preset plus overrides)."""
    if spec.kind != "synthetic":
        raise ConfigError(f"{spec.source}.kind = {spec.kind!r} has no synthetic parameters")
    return dataclasses.replace(CLASS_PRESETS[spec.preset], **dict(spec.overrides))


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
    return terrain


def _class_terrain(spec: TerrainSpec, cache: bool) -> Terrain:
    if spec.kind == "synthetic":
        from .synthetic_terrain import synthetic_terrain
        return synthetic_terrain(class_terrain_params(spec), spec.seed, cache=cache)
    if not spec.path.is_file():
        raise ConfigError(f"{spec.source}.path: no such file {spec.path}")
    try:
        from .readers import load_terrain
    except ImportError as exc:
        raise ConfigError(f"{spec.source}.kind = 'file' needs sitedata.readers.load_terrain, "
                          f"which cannot be imported ({exc})") from None
    return load_terrain(spec.path, spec.sidecar)
