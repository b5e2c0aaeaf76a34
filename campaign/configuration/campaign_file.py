"""Campaign configuration: a site TOML plus campaign tables, validated into typed objects.

A campaign file (e.g. ``sitedata/gusev.toml``) has these top-level tables, and optionally ``base = "gusev"`` (or
a path): the file it builds on, whose tables it overrides key by key (:mod:`campaign.configuration.base_files`):

``[site]``       site, camera, trajectory set, sun, appearance classes (read by :mod:`sitedata.sites`)
``[campaign]``   ``seed`` (int), ``output_dir`` (relative to the working directory; default
                 ``runs/<site>``), ``cases`` (optional
                 table class -> count overriding the site's counts), ``cases_scale`` (optional factor
                 applied to every class, e.g. 0.1 for a quick look; at least 1 case per class with a count),
                 ``max_outside_terrain_fraction`` (0..1, default 0: a case any of whose images sees more
                 of its pixels on ground outside the terrain is recorded invalid, reason ``outside_terrain``)
                 ``false_valid_mps`` (default 5: a valid case with a larger horizontal error counts as
                 false-valid in the tables; a reporting threshold, not part of the configuration hash)
``[execution]``  ``scheduler`` ("" = embedded LocalCluster, or "tcp://host:port"), ``workers`` (0 = one
                 per core), ``retries`` (attempts after the first for a case that raises), ``memory_limit``
                 (:mod:`campaign.configuration.execution`)
``[sensors]``    sensor noise (:mod:`simulator.sensors`)
``[estimator]``  calibration products (``flat_field``, ``flat_field_frames``) and the reference
                 estimator's parameters (:mod:`campaign.configuration.estimators`, :mod:`dimes_velocity.config`)
``[[estimators]]`` the estimators to compare on every case (:mod:`estimators.entries`); default: the
                 reference estimator alone, named ``dimes``
``[scene]``      scene parameters, ``[scene.effects]`` and ``[scene.camera_effects]`` switches
                 (:mod:`simulator.scene_config`); ``sun_distance_au`` defaults to the site's

Each table is declared once, as a pydantic model (:class:`CampaignFile` gathers them; ``campaign schema``
prints the JSON Schema). Errors are one line naming the file, the field and the allowed values. The configuration hash
identifies the campaign's *results*: it is computed from content, never from paths or from which
defaults were written out (:func:`hashed_content`): every resolved table except ``[execution]``,
``output_dir``, ``false_valid_mps`` and the case counts; the bytes of the camera, trajectory and terrain
files; a digest of the code that computes results (:func:`~campaign.configuration.code_identity.code_digest`:
the import closure of the case computation and the plug-ins' files). So a campaign can be resumed on
another cluster, from another directory, or with more cases (case identity is (class, index within
class)), but not with another camera or another version of the simulator or estimator.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, ConfigDict, Field, SkipValidation, ValidationInfo, model_validator

from campaign.configuration.base_files import layered_data, shipped_sites
from campaign.configuration.code_identity import code_digest, plugin_modules
from campaign.configuration.differences import HASH_EXCLUDED_CAMPAIGN_KEYS
from campaign.configuration.estimators import (
    CalibrationConfig,
    EstimatorTable,
    estimator_code_digests,
    estimator_tables,
)
from campaign.configuration.execution import ExecutionConfig
from campaign.configuration.paths import check_input_file
from config_tables.errors import ConfigError, FieldProblem
from config_tables.models import ConfigModel, parse, parse_field
from config_tables.toml_file import load_toml
from dimes_velocity.config import EstimatorConfig
from estimators.entries import EstimatorEntry, EstimatorSpec, unique_names
from simulator.scene_config import SceneConfig
from simulator.sensors import SensorConfig
from sitedata.sites import MAX_CASES, Site

COMMAND_LINE = "command line"
#: A class's number of cases.
CaseCount = Annotated[int, Field(ge=0, le=MAX_CASES)]
#: Factor on every class's case count.
CasesScale = Annotated[float, Field(gt=0.0, le=100.0)]


class CampaignTable(ConfigModel):
    """``[campaign]``: what to run and where the results go."""

    seed: int = Field(1, ge=0, le=2**63 - 1)
    """Campaign seed: the case with id c (class_index * 1_000_000 + index within class) draws from
    SeedSequence([seed, c])."""
    output_dir: str | None = None
    """Store directory, relative to the working directory (default runs/<site name in lower case>)."""
    cases: dict[str, CaseCount] = {}
    """Class name -> number of cases, overriding the site's counts."""
    cases_scale: CasesScale = 1.0
    """Multiplies every class's case count (at least 1 case per class with a count), e.g. 0.1 for a quick look."""
    max_outside_terrain_fraction: float = Field(0.0, ge=0.0, le=1.0)
    """A case any of whose images sees more of its pixels on ground outside the terrain is recorded invalid
    (reason outside_terrain)."""
    false_valid_mps: float = Field(5.0, gt=0.0, le=1000.0)
    """A valid case with a larger horizontal error (m/s) counts as false-valid in the tables (a reporting
    threshold, not part of the configuration hash)."""


def _site_may_come_from_the_base(schema: dict) -> None:
    """JSON Schema of a campaign file: ``site`` is required only of a file without ``base`` (the loader checks
    the merged tables)."""
    schema["required"] = [name for name in schema.get("required", []) if name != "site"]
    schema["anyOf"] = [{"required": ["site"]}, {"required": ["base"]}]


class CampaignFile(ConfigModel):
    """A campaign TOML file: a site file plus the campaign's optional tables."""

    model_config = ConfigDict(json_schema_extra=_site_may_come_from_the_base)

    base: str | None = None
    """The file this one builds on: a shipped site ("gusev", "meridiani") or a TOML file relative to this one;
    tables merge key by key, arrays and values are replaced (campaign.configuration.base_files). Resolved by
    the loader; not part of the results' configuration."""
    site: Site
    campaign: CampaignTable = CampaignTable()
    execution: ExecutionConfig = ExecutionConfig()
    sensors: SensorConfig = SensorConfig()
    estimator: EstimatorTable = EstimatorTable()
    estimators: Annotated[list[EstimatorEntry], Field(min_length=1), AfterValidator(unique_names)] | None = None
    """The estimators to run on every case ([[estimators]]); default: the reference estimator alone, "dimes"."""
    scene: SceneConfig = SceneConfig()

    @model_validator(mode="after")
    def _tables_agree(self, info: ValidationInfo):
        names = [entry.name for entry in self.site.classes]
        for key in self.campaign.cases:
            if key not in names:
                raise FieldProblem(f"campaign.cases.{key}", f"is not a class of site {self.site.name}; allowed: "
                                   f"{', '.join(names)}")
        return self


class CampaignConfig(ConfigModel):
    """A campaign as the runtime uses it: the validated tables of one campaign file, the file they were
    read from, and where its store is.

    Built only by validation (:func:`campaign_config_from_data`, :meth:`with_output_dir`), never by hand
    and never changed afterwards: the validator derives ``scene``, ``estimators`` and ``config_hash``
    from the other fields (whatever a caller passes for them is replaced); every other derived value is
    a property of the tables.
    """

    source: Path
    """The campaign file (relative paths in its ``[site]`` resolved against it)."""
    tables: CampaignFile
    """Every table of the file as written (validated; the manifest records them with defaults filled in)."""
    output_dir: Path
    """The campaign's store: ``--output``, else ``[campaign] output_dir``, else ``runs/<site>``."""
    cases_scale: CasesScale
    """Factor on every class's case count: ``--cases-scale``, else ``[campaign] cases_scale``."""
    scene: SceneConfig
    """``[scene]`` with ``sun_distance_au`` taken from the site when the file does not give it (derived)."""
    estimators: SkipValidation[tuple[EstimatorSpec, ...]] = ()
    """The estimators of ``[[estimators]]`` in file order, default the reference alone (derived)."""
    config_hash: str = ""
    """sha256 identifying the campaign's results (derived; see :func:`hashed_content`)."""
    hash_inputs: dict = {}
    """What the hash covers besides the tables (derived; the manifest records it, so a refused change can
    name a changed file or code): ``files`` (dotted field -> sha256 of the file's bytes), ``code_digest``,
    ``estimator_code_digests``."""

    @model_validator(mode="before")
    @classmethod
    def _derived_values(cls, data, info: ValidationInfo):
        if not isinstance(data, dict) or not isinstance(data.get("tables"), CampaignFile):
            return data
        tables = data["tables"]
        label = (info.context or {}).get("source") or str(data.get("source"))
        scene = tables.scene
        if "sun_distance_au" not in scene.model_fields_set:
            scene = SceneConfig.model_validate({**scene.model_dump(exclude_unset=True),
                                                "sun_distance_au": tables.site.heliocentric_distance_au})
        _, _, estimators = estimator_tables(tables.estimator, tables.estimators, label)
        hashed = hashed_content(resolved_tables(tables, scene), tables.site)
        hashed["code_digest"] = code_digest(plugin_modules(estimators))
        hashed["estimator_code_digests"] = estimator_code_digests(estimators)
        config_hash = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()
        inputs = {"files": input_file_digests(hashed["site"]), "code_digest": hashed["code_digest"],
                  "estimator_code_digests": hashed["estimator_code_digests"]}
        return {**data, "scene": scene, "estimators": estimators, "config_hash": config_hash, "hash_inputs": inputs}

    def with_output_dir(self, output_dir: str | Path) -> CampaignConfig:
        """This campaign with its store at ``output_dir`` (a copy of this validated campaign: the output
        directory is not part of the hash, so nothing is validated or hashed again)."""
        return self.model_copy(update={"output_dir": Path(output_dir)})

    @property
    def site(self) -> Site:
        return self.tables.site

    @property
    def seed(self) -> int:
        return self.tables.campaign.seed

    @property
    def execution(self) -> ExecutionConfig:
        return self.tables.execution

    @property
    def sensors(self) -> SensorConfig:
        return self.tables.sensors

    @property
    def estimator(self) -> EstimatorConfig:
        """The reference estimator's configuration (``[estimator]``, its defaults where the table gives none)."""
        return self.tables.estimator.reference()

    @property
    def calibration(self) -> CalibrationConfig:
        """How the calibration products are made (``[estimator] flat_field``, ``flat_field_frames``)."""
        return self.tables.estimator.calibration()

    @property
    def max_outside_terrain_fraction(self) -> float:
        return self.tables.campaign.max_outside_terrain_fraction

    @property
    def false_valid_mps(self) -> float:
        return self.tables.campaign.false_valid_mps

    @property
    def cases_per_class(self) -> dict[str, int]:
        """Class name -> number of cases: ``[campaign.cases]`` over the site's counts, times ``cases_scale``
        (rounded half up, at least 1 for a class with a count)."""
        cases = {}
        for entry in self.site.classes:
            count = self.tables.campaign.cases.get(entry.name, entry.cases)
            cases[entry.name] = 0 if count == 0 else max(1, int(math.floor(count * self.cases_scale + 0.5)))
        return cases

    @property
    def resolved(self) -> dict:
        """Every table with its defaults filled in, as JSON values (recorded in the manifest); ``scene`` as
        the cases use it (with the site's sun distance when the file leaves it out)."""
        return resolved_tables(self.tables, self.scene)

    @property
    def estimator_names(self) -> list[str]:
        return [spec.name for spec in self.estimators]


def resolved_tables(tables: CampaignFile, scene: SceneConfig) -> dict:
    """Every table of ``tables`` with its defaults filled in, as JSON values, and ``[scene]`` as the cases
    use it (``scene``: with the site's sun distance when the file leaves it out). So the hash and the
    manifest tell a sun distance left out from one written out at the scene default."""
    chosen = {name: scene if name == "scene" else getattr(tables, name) for name in CampaignFile.model_fields
              if name != "base"}
    return {name: json.loads(json.dumps(value, default=lambda item: item.model_dump(mode="json")))
            for name, value in chosen.items()}


def load_campaign_config(path: str | Path, *, output_dir: str | Path | None = None,
                         cases_scale: float | None = None) -> CampaignConfig:
    """Load and validate a campaign TOML.

    Parameters
    ----------
    path : str or Path
        The campaign file.
    output_dir : str or Path, optional
        ``--output``: the store, instead of ``[campaign] output_dir``.
    cases_scale : float, optional
        ``--cases-scale``: instead of ``[campaign] cases_scale`` (validated first, against the same
        declaration, errors naming the flag).

    Raises
    ------
    ConfigError
        One line naming the file (or flag), the field and the allowed values.
    """
    path = Path(path)
    check_input_file(path, "campaign file")
    if cases_scale is not None:
        parse_field(CampaignTable, "cases_scale", cases_scale, COMMAND_LINE, "--cases-scale")
    return campaign_config_from_data(load_toml(path), path, output_dir=output_dir, cases_scale=cases_scale)


def campaign_config_from_data(data: dict, path: str | Path, *, source: str | None = None,
                              output_dir: str | Path | None = None,
                              cases_scale: float | None = None) -> CampaignConfig:
    """Validate an already parsed campaign TOML ``data`` (e.g. a base campaign with sweep overrides).

    Parameters
    ----------
    data : dict
        Parsed TOML.
    path : str or Path
        The campaign file the data came from (relative paths in ``[site]`` resolve against it).
    source : str, optional
        Names the data in error messages (default: ``path``).
    output_dir, cases_scale
        Command-line overrides, as for :func:`load_campaign_config`.

    Returns
    -------
    CampaignConfig
        Same hash semantics as :func:`load_campaign_config`.
    """
    path = Path(path)
    label = source or str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: site is missing (a [site] table with the site, camera, sun and classes)")
    layered = layered_data(data, path, label)
    if "site" not in layered.data:
        raise ConfigError(f"{label}: site is missing (a [site] table with the site, camera, sun and classes, "
                          f"or base = \"{shipped_sites()[0]}\" to build on a shipped site)")
    try:
        tables = parse(CampaignFile, layered.data, label, context={"base_dir": path.parent, "source": label})
        check_site_paths(tables.site, label)
        campaign = tables.campaign
        store = Path(output_dir) if output_dir is not None else Path(campaign.output_dir or f"runs/{tables.site.name.lower()}")
        return parse(CampaignConfig, {"source": path, "tables": tables, "output_dir": store,
                                      "cases_scale": campaign.cases_scale if cases_scale is None else float(cases_scale)},
                     label, context={"source": label})
    except ConfigError as exc:
        error = layered.attribute(exc)
        if ": site.camera = " in str(error) and ": no such file " in str(error):
            error = ConfigError(f"{error}; relative paths resolve against the file that writes them: to build on a "
                                f"site file without copying it, write base = \"{shipped_sites()[0]}\" (a shipped site) "
                                "or base = \"path/to/site.toml\"")
        raise error from None


#: Largest synthetic terrain strip (rows x cols) a class may declare: 4x the presets' 5000 x 1000 pixels.
MAX_SYNTHETIC_TERRAIN_PIXELS = 20_000_000


def check_site_paths(site: Site, label: str) -> None:
    """The site's input files (camera, trajectory set, terrain images and side-cars) must not be FIFOs,
    devices, sockets or dangling links: refused by ``stat`` before anything opens them (reading a FIFO would
    block; ``/dev/zero`` never ends), also before the configuration hash reads their bytes. A synthetic
    terrain may declare at most :data:`MAX_SYNTHETIC_TERRAIN_PIXELS` (rows x cols)."""
    named = [("site.camera", site.camera_path), ("site.trajectory_set", site.trajectory_path)]
    for index, entry in enumerate(site.classes):
        for name in ("path", "sidecar"):
            value = getattr(entry.terrain, name, None)
            if value is not None:
                named.append((f"site.classes[{index}].terrain.{name}", Path(value)))
    for field, value in named:
        check_input_file(value, f"{label}: {field}")
    for index, entry in enumerate(site.classes):
        if entry.terrain.kind == "synthetic":
            params = entry.terrain.params()
            if params.rows * params.cols > MAX_SYNTHETIC_TERRAIN_PIXELS:
                raise ConfigError(f"{label}: site.classes[{index}].terrain.overrides: rows x cols = {params.rows} x "
                                  f"{params.cols} is too large; allowed: at most {MAX_SYNTHETIC_TERRAIN_PIXELS:,} pixels "
                                  "(the presets have 5000 x 1000)")




def hashed_content(resolved: dict, site: Site) -> dict:
    """What the configuration hash covers: the resolved tables (every default filled in, so writing a
    default out changes nothing) with input files replaced by the sha256 of their bytes (so the same
    campaign given by another path, or from another directory, has the same hash).

    Left out: ``[execution]`` (where cases run), the output directory, a python estimator's ``path`` (its
    module's bytes are hashed instead), the false-valid reporting threshold, and the case counts (``cases``,
    ``cases_scale``, each class's ``cases``): case identity is (class, index within class), so a scaled run is a
    prefix of the full one (see :mod:`campaign.plan.placement`).
    """
    content = json.loads(json.dumps({name: value for name, value in resolved.items() if name != "execution"}))
    if resolved.get("execution", {}).get("case_mode", "compute") != "compute":    # a no-op store is never results
        content["case_mode"] = resolved["execution"]["case_mode"]
    for key in HASH_EXCLUDED_CAMPAIGN_KEYS:
        content.get("campaign", {}).pop(key, None)
    for entry in content.get("estimators") or []:
        entry.pop("path", None)             # where a plug-in's module is: its bytes are hashed (estimator_code_digests)
    site_content = content["site"]
    site_content["camera"] = file_digest(site.camera_path)
    site_content["trajectory_set"] = file_digest(site.trajectory_path)
    for entry, class_content in zip(site.classes, site_content["classes"]):
        class_content.pop("cases", None)
        for name in ("path", "sidecar"):
            value = getattr(entry.terrain, name, None)
            if value is not None:
                class_content["terrain"][name] = file_digest(Path(value))
    return content


def input_file_digests(hashed_site: dict) -> dict[str, str]:
    """Dotted field (``site.camera``, ``site.classes[0].terrain.path``) -> sha256 of the file, read from the
    ``[site]`` of :func:`hashed_content` (where the digests replace the paths)."""
    digests = {f"site.{name}": hashed_site[name] for name in ("camera", "trajectory_set")}
    for index, entry in enumerate(hashed_site["classes"]):
        for name in ("path", "sidecar"):
            if isinstance(entry["terrain"].get(name), str):
                digests[f"site.classes[{index}].terrain.{name}"] = entry["terrain"][name]
    return digests


_DIGESTS: dict[tuple, str] = {}     # (path, device, inode, size, mtime) -> sha256: a sweep hashes its inputs once


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes ("missing" when it cannot be read: the loader reports that clearly). Kept
    per process while the file's stat (device, inode, size, mtime) is unchanged: the points of a sweep
    share their input files, which are hashed once."""
    try:
        stat = os.stat(path)
        key = (os.path.abspath(path), stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)
        if key not in _DIGESTS:
            with open(path, "rb") as handle:
                _DIGESTS[key] = hashlib.file_digest(handle, "sha256").hexdigest()
        return _DIGESTS[key]
    except OSError:
        return "missing"
