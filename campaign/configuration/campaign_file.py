"""Campaign configuration: a site TOML plus campaign tables, validated into typed objects.

A campaign file (e.g. ``sitedata/gusev.toml``) has these top-level tables:

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
``[[estimators]]`` the estimators to compare on every case (:mod:`estimators.registry`); default: the
                 reference estimator alone, named ``dimes``
``[scene]``      scene parameters, ``[scene.effects]`` and ``[scene.camera_effects]`` switches
                 (:mod:`simulator.scene_config`); ``sun_distance_au`` defaults to the site's

Each table is declared once, as a pydantic model (:class:`CampaignFile` gathers them; ``campaign schema``
prints the JSON Schema). Errors are one line naming the file, the field and the allowed values. The configuration hash
identifies the campaign's *results*: it is computed from content, never from paths or from which
defaults were written out (:func:`hashed_content`): every resolved table except ``[execution]``,
``output_dir``, ``false_valid_mps`` and the case counts; the bytes of the camera, trajectory and terrain
files; a digest of the code that computes results (:func:`code_digest`). So a campaign can be resumed on
another cluster, from another directory, or with more cases (case identity is (class, index within
class)), but not with another camera or another version of the simulator or estimator.
"""
from __future__ import annotations

import functools
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, Field, ValidationInfo, model_validator

from dimes_velocity.config import EstimatorConfig
from estimators.registry import EstimatorEntry, EstimatorSpec, unique_names
from flight_interface.tomlfields import ConfigError, ConfigModel, FieldProblem, load_toml, parse, parse_field
from simulator.scene_config import SceneConfig
from simulator.sensors import SensorConfig
from sitedata.sites import MAX_CASES, Site

from campaign.configuration.estimators import CalibrationConfig, EstimatorTable, estimator_code_digests, estimator_tables
from campaign.configuration.execution import ExecutionConfig

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


class CampaignFile(ConfigModel):
    """A campaign TOML file: a site file plus the campaign's optional tables."""

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


@dataclass(frozen=True)
class CampaignConfig:
    """A validated campaign (see the module docstring for the tables)."""

    source: Path
    site: Site
    seed: int
    output_dir: Path
    cases_per_class: dict
    execution: ExecutionConfig
    sensors: SensorConfig
    estimator: EstimatorConfig    # the reference estimator's configuration ([estimator] defaults)
    scene: SceneConfig
    config_hash: str
    resolved: dict                # every table with its defaults filled in (for the manifest)
    max_outside_terrain_fraction: float = 0.0   # an image seeing more ground outside the terrain: invalid
    false_valid_mps: float = 5.0  # tables: valid with a larger error counts as false-valid
    calibration: CalibrationConfig = CalibrationConfig()
    estimators: tuple[EstimatorSpec, ...] = ()   # in [[estimators]] order

    @property
    def estimator_names(self) -> list[str]:
        return [spec.name for spec in self.estimators]


def load_campaign_config(path: str | Path, *, output_dir: str | Path | None = None,
                         cases_scale: float | None = None) -> CampaignConfig:
    """Load and validate a campaign TOML; ``output_dir`` and ``cases_scale`` override the file (and are
    validated first, against the same declarations, naming the command-line flag)."""
    path = Path(path)
    if cases_scale is not None:
        parse_field(CampaignTable, "cases_scale", cases_scale, COMMAND_LINE, "--cases-scale")
    return campaign_config_from_data(load_toml(path), path, output_dir=output_dir, cases_scale=cases_scale)


def campaign_config_from_data(data: dict, path: str | Path, *, source: str | None = None,
                              output_dir: str | Path | None = None,
                              cases_scale: float | None = None) -> CampaignConfig:
    """Validate an already parsed campaign TOML ``data`` (e.g. a base campaign with sweep overrides).

    ``path`` is the campaign file the data came from (relative paths in ``[site]`` resolve against it);
    ``source`` names the data in error messages (default: ``path``). Same hash semantics as
    :func:`load_campaign_config`.
    """
    path = Path(path)
    label = source or str(path)
    if not isinstance(data, dict) or "site" not in data:
        raise ConfigError(f"{label}: site is missing (a [site] table with the site, camera, sun and classes)")
    tables = parse(CampaignFile, data, label, context={"base_dir": path.parent, "source": label})
    site = tables.site
    site._source = path
    scene = tables.scene
    if "sun_distance_au" not in scene.model_fields_set:
        scene = scene.model_copy(update={"sun_distance_au": site.heliocentric_distance_au})
    campaign = tables.campaign
    out = Path(output_dir) if output_dir is not None else Path(campaign.output_dir or f"runs/{site.name.lower()}")
    scale = cases_scale if cases_scale is not None else campaign.cases_scale
    cases = {}
    for entry in site.classes:
        count = campaign.cases.get(entry.name, entry.cases)
        cases[entry.name] = 0 if count == 0 else max(1, int(math.floor(count * scale + 0.5)))

    calibration, estimator, estimators = estimator_tables(tables.estimator, tables.estimators, label)

    resolved = {name: json.loads(json.dumps(getattr(tables, name), default=lambda value: value.model_dump(mode="json")))
                for name in CampaignFile.model_fields}
    hashed = hashed_content(resolved, site)
    hashed["code_digest"] = code_digest()
    hashed["estimator_code_digests"] = estimator_code_digests(estimators)
    config_hash = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()
    return CampaignConfig(source=path, site=site, seed=campaign.seed, output_dir=out, cases_per_class=cases,
                          execution=tables.execution, sensors=tables.sensors, estimator=estimator,
                          scene=scene, config_hash=config_hash, resolved=resolved,
                          max_outside_terrain_fraction=campaign.max_outside_terrain_fraction,
                          false_valid_mps=campaign.false_valid_mps, calibration=calibration, estimators=estimators)


HASH_EXCLUDED_CAMPAIGN_KEYS = ("output_dir", "false_valid_mps", "cases", "cases_scale")


def hashed_content(resolved: dict, site: Site) -> dict:
    """What the configuration hash covers: the resolved tables (every default filled in, so writing a
    default out changes nothing) with input files replaced by the sha256 of their bytes (so the same
    campaign given by another path, or from another directory, has the same hash).

    Left out: ``[execution]`` (where cases run), the output directory, the false-valid reporting
    threshold, and the case counts (``cases``, ``cases_scale``, each class's ``cases``): case identity is
    (class, index within class), so a scaled run is a prefix of the full one (see :mod:`campaign.plan.placement`).
    """
    content = json.loads(json.dumps({name: value for name, value in resolved.items() if name != "execution"}))
    for key in HASH_EXCLUDED_CAMPAIGN_KEYS:
        content.get("campaign", {}).pop(key, None)
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


RESULT_CODE = ("flight_interface", "simulator", "dimes_velocity", "estimators", "sitedata", "campaign/run/case.py",
               "campaign/run/error_budget.py")


@functools.lru_cache(maxsize=4)
def code_digest(root: Path = Path(__file__).resolve().parents[2], parts: tuple[str, ...] = RESULT_CODE) -> str:
    """sha256 over the Python sources that compute a case's result (simulator, estimator, site data and
    terrain generators, the case task), by path relative to ``root`` and contents. Part of the
    configuration hash: results of different code are never mixed in one store, and a sweep point is
    reused only when the code that computed it is unchanged."""
    digest = hashlib.sha256()
    for part in parts:
        base = root / part
        files = sorted(base.rglob("*.py")) if base.is_dir() else [base]
        for file in files:
            digest.update(str(file.relative_to(root).as_posix()).encode())
            digest.update(file_digest(file).encode())
    return digest.hexdigest()


def file_digest(path: Path) -> str:
    """sha256 of a file's bytes ("missing" when it cannot be read: the loader reports that clearly)."""
    try:
        with open(path, "rb") as handle:
            return hashlib.file_digest(handle, "sha256").hexdigest()
    except OSError:
        return "missing"
