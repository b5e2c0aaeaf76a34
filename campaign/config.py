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
``[sensors]``    sensor noise (:mod:`simulator.sensors`)
``[estimator]``  calibration products (``flat_field``, ``flat_field_frames``) and the reference
                 estimator's parameters (:mod:`campaign.estimator_config`, :mod:`dimes_velocity.config`)
``[[estimators]]`` the estimators to compare on every case (:mod:`estimators.registry`); default: the
                 reference estimator alone, named ``dimes``
``[scene]``      scene parameters, ``[scene.effects]`` and ``[scene.camera_effects]`` switches
                 (:mod:`simulator.descent_image`); ``sun_distance_au`` defaults to the site's

Errors are one line naming the file, the field and the allowed values. The configuration hash
identifies the campaign's *results*: it covers everything that changes them (all tables except
``[execution]`` and ``output_dir``, the contents of the camera, trajectory and terrain files, and a
digest of the code that computes results, :func:`code_digest`), so a campaign can be resumed on
another cluster but not with another camera or another version of the simulator or estimator.
"""
from __future__ import annotations

import functools
import hashlib
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from flight_interface.tomlfields import ConfigError, Table, load_toml

from .estimator_config import estimator_code_digests, estimator_tables

TOP_LEVEL_TABLES = ("site", "campaign", "execution", "sensors", "estimator", "estimators", "scene")


@dataclass(frozen=True)
class ExecutionConfig:
    scheduler: str
    workers: int
    retries: int
    memory_limit: str


@dataclass(frozen=True)
class CampaignConfig:
    """A validated campaign (see the module docstring for the tables)."""

    source: Path
    site: Any                     # sitedata.sites.Site
    seed: int
    output_dir: Path
    cases_per_class: dict
    execution: ExecutionConfig
    sensors: Any                  # simulator.sensors.SensorConfig
    estimator: Any                # dimes_velocity.config.EstimatorConfig (the reference's defaults)
    scene: Any                    # simulator.descent_image.SceneConfig
    config_hash: str
    resolved: dict                # the parsed TOML (for the manifest)
    max_outside_terrain_fraction: float = 0.0   # an image seeing more ground outside the terrain: invalid
    false_valid_mps: float = 5.0  # tables: valid with a larger error counts as false-valid
    calibration: Any = None       # campaign.estimator_config.CalibrationConfig
    estimators: tuple = ()        # estimators.registry.EstimatorSpec, in [[estimators]] order

    @property
    def estimator_names(self) -> list[str]:
        return [spec.name for spec in self.estimators]


def load_campaign_config(path: str | Path, *, output_dir: str | Path | None = None,
                         cases_scale: float | None = None) -> CampaignConfig:
    """Load and validate a campaign TOML; ``output_dir`` and ``cases_scale`` override the file."""
    path = Path(path)
    return campaign_config_from_data(load_toml(path), path, output_dir=output_dir, cases_scale=cases_scale)


def campaign_config_from_data(data: dict, path: str | Path, *, source: str | None = None, site: Any = None,
                              output_dir: str | Path | None = None,
                              cases_scale: float | None = None) -> CampaignConfig:
    """Validate an already parsed campaign TOML ``data`` (e.g. a base campaign with sweep overrides).

    ``path`` is the campaign file the data came from (its ``[site]`` is read from there, relative paths
    resolve against it); ``source`` names the data in error messages (default: ``path``); ``site``
    may pass the already loaded site of ``path``. Same hash semantics as :func:`load_campaign_config`.
    """
    from simulator.scene_table import scene_config_from_table
    from simulator.sensors import sensor_config_from_table
    from sitedata.sites import load_site

    path = Path(path)
    label = source or str(path)
    root = Table(data, label)
    for key in data:
        if key not in TOP_LEVEL_TABLES:
            raise ConfigError(f"{label}: unknown table {key!r}; allowed: {', '.join(TOP_LEVEL_TABLES)}")
    if "site" not in data:
        raise ConfigError(f"{label}: site is missing (a [site] table with the site, camera, sun and classes)")
    site = load_site(path) if site is None else site

    campaign = root.table("campaign", required=False)
    seed = campaign.integer("seed", default=1, minimum=0, maximum=2**63 - 1)
    configured_output = Path(campaign.string("output_dir", default=f"runs/{site.name.lower()}"))
    out = Path(output_dir) if output_dir is not None else configured_output
    scale = cases_scale if cases_scale is not None else campaign.number("cases_scale", default=1.0,
                                                                        minimum=0.0, maximum=100.0,
                                                                        exclusive_minimum=True)
    max_outside = campaign.number("max_outside_terrain_fraction", default=0.0, minimum=0.0, maximum=1.0)
    false_valid_mps = campaign.number("false_valid_mps", default=5.0, minimum=0.0, maximum=1000.0,
                                      exclusive_minimum=True)
    class_names = [entry.name for entry in site.classes]
    overrides = campaign.table("cases", required=False)
    cases = {}
    for entry in site.classes:
        count = overrides.integer(entry.name, default=entry.cases, minimum=0, maximum=1_000_000)
        cases[entry.name] = 0 if count == 0 else max(1, int(math.floor(count * scale + 0.5)))
    for key in overrides.data:
        if key not in class_names:
            raise overrides.fail(key, f"is not a class of site {site.name}; allowed: {', '.join(class_names)}")

    execution_table = root.table("execution", required=False)
    execution = ExecutionConfig(
        scheduler=execution_table.string("scheduler", default=""),
        workers=execution_table.integer("workers", default=0, minimum=0, maximum=1024),
        retries=execution_table.integer("retries", default=1, minimum=0, maximum=10),
        memory_limit=execution_table.string("memory_limit", default="1.5GiB"),
    )
    if execution.scheduler and not execution.scheduler.startswith(("tcp://", "tls://", "inproc://")):
        raise execution_table.fail("scheduler", f"= {execution.scheduler!r} is not a scheduler address; "
                                   "allowed: \"\" (embedded) or tcp://host:port")
    execution_table.reject_unknown()
    campaign.reject_unknown()

    sensors = sensor_config_from_table(root.table("sensors", required=False))
    calibration, estimator, estimators = estimator_tables(root, path.parent)
    scene_table = root.table("scene", required=False)
    effects = scene_config_from_table(scene_table)
    if not scene_table.has("sun_distance_au"):
        effects = replace(effects, sun_distance_au=site.heliocentric_distance_au)

    resolved = json.loads(json.dumps(data, default=str))
    hashed = {key: value for key, value in resolved.items() if key != "execution"}
    hashed["campaign"] = {k: v for k, v in hashed.get("campaign", {}).items()
                          if k not in ("output_dir", "false_valid_mps")}
    hashed["cases_resolved"] = cases
    hashed["input_digests"] = {str(p): file_digest(p) for p in _input_files(site)}
    hashed["code_digest"] = code_digest()
    hashed["estimator_code_digests"] = estimator_code_digests(estimators)
    config_hash = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()
    return CampaignConfig(source=path, site=site, seed=seed, output_dir=out, cases_per_class=cases,
                          execution=execution, sensors=sensors, estimator=estimator, scene=effects,
                          config_hash=config_hash, resolved=resolved, max_outside_terrain_fraction=max_outside,
                          false_valid_mps=false_valid_mps, calibration=calibration, estimators=estimators)


def _input_files(site) -> list[Path]:
    files = [Path(site.camera_path), Path(site.trajectory_path)]
    for entry in site.classes:
        for value in (entry.terrain.path, entry.terrain.sidecar):
            if value is not None:
                files.append(Path(value))
    return files


RESULT_CODE = ("flight_interface", "simulator", "dimes_velocity", "estimators", "sitedata", "campaign/case.py")


@functools.lru_cache(maxsize=4)
def code_digest(root: Path = Path(__file__).resolve().parents[1], parts: tuple[str, ...] = RESULT_CODE) -> str:
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
    """sha256 of a file's bytes ("missing" when it does not exist: the loader reports that clearly)."""
    try:
        with open(path, "rb") as handle:
            return hashlib.file_digest(handle, "sha256").hexdigest()
    except FileNotFoundError:
        return "missing"
