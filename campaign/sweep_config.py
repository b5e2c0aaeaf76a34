"""Sweep files: a base campaign plus parameter axes, validated into one campaign config per point.

A sweep file (e.g. ``sitedata/sweeps/nightly.toml``)::

    [sweep]
    base = "../gusev.toml"              # base campaign TOML, relative to this file (required)
    output_dir = "runs/sweeps/nightly"  # relative to the working directory (default runs/sweeps/<file stem>)
    mode = "grid"                       # "grid": cartesian product of the axes; "list": i-th value of every axis
    cases_scale = 0.05                  # optional: replaces the base's [campaign] cases_scale
    [sweep.cases]                       # optional: class -> count, merged over the base's [campaign.cases]
    gkep = 0

    [axes]                              # dotted config field -> list of values (TOML units: degrees...)
    "scene.camera_effects.dark_current_scale" = [1.0, 30.0]
    sensors.attitude_random_sigma_deg = [0.05, 0.5]     # unquoted dotted keys work as well

    [tolerances]                        # for --baseline
    pct_valid_drop_points = 5.0         # a class's (or the weighted) % valid may fall this many points
    error_increase_mps = 0.5            # its error mean+3 sigma (m/s) may grow this much

Axis fields are any field of the ``[sensors]``, ``[estimator]`` and ``[scene]`` tables (including
sub-tables such as ``scene.camera_effects``), or ``campaign.seed``. Each point's configuration is the
base TOML with the point's values set, validated exactly like a campaign file; its campaign
configuration hash (``[execution]`` and ``output_dir`` excluded) is the point's key. Errors are one
line naming the sweep file, the field and the allowed values.
"""
from __future__ import annotations

import copy
import itertools
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from flight_interface.tomlfields import ConfigError, Table, load_toml

from .config import CampaignConfig, campaign_config_from_data, load_campaign_config

SWEEP_TABLES = ("sweep", "axes", "tolerances")
AXIS_ROOTS = ("sensors", "estimator", "scene")
AXIS_FIELDS = ("campaign.seed",)
MODES = ("grid", "list")
MAX_POINTS = 10_000


@dataclass(frozen=True)
class Tolerances:
    """How much a metric may degrade against a baseline before it counts as a regression."""

    pct_valid_drop_points: float
    error_increase_mps: float


@dataclass(frozen=True)
class SweepPoint:
    """One point of a sweep: its id (``p000``...), axis values and validated campaign config."""

    point_id: str
    values: dict            # axis field -> value, in axis order
    config: CampaignConfig  # output_dir is the point's store, OUT/points/<hash[:16]>

    @property
    def config_hash(self) -> str:
        return self.config.config_hash


@dataclass(frozen=True)
class SweepSpec:
    source: Path
    base_path: Path
    output_dir: Path
    mode: str
    axes: dict              # field -> list of values
    tolerances: Tolerances
    points: list            # list[SweepPoint]
    base: CampaignConfig    # the base campaign with the sweep's case counts, without axis values

    @property
    def axis_names(self) -> list[str]:
        return list(self.axes)


def point_store_dir(output_dir: Path, config_hash: str) -> Path:
    return Path(output_dir) / "points" / config_hash[:16]


def load_sweep(path: str | Path, output_dir: str | Path | None = None) -> SweepSpec:
    """Read and validate a sweep file and every point's configuration (nothing is written).

    Raises
    ------
    ConfigError
        One line naming the sweep (or base) file, the field and the allowed values.
    """
    path = Path(path)
    data = load_toml(path)
    label = str(path)
    for key in data:
        if key not in SWEEP_TABLES:
            raise ConfigError(f"{label}: unknown table {key!r}; allowed: {', '.join(SWEEP_TABLES)}")
    root = Table(data, label)
    sweep = root.table("sweep")
    base_path = sweep.path_value("base", path.resolve().parent)
    if not base_path.is_file():
        raise sweep.fail("base", f"= {sweep.data['base']!r}: no such file {base_path}; allowed: a campaign "
                         "TOML, relative to the sweep file")
    base_path = base_path.resolve()    # absolute: point hashes do not depend on the working directory
    configured_output = Path(sweep.string("output_dir", default=f"runs/sweeps/{path.stem}"))
    out = Path(output_dir) if output_dir is not None else configured_output
    mode = sweep.string("mode", default="grid", choices=MODES)
    base_data = load_toml(base_path)
    base_config = load_campaign_config(base_path)          # base errors name the base file
    campaign_overrides = _campaign_overrides(sweep, base_config)
    sweep.reject_unknown()

    axes = _read_axes(root, label)
    tolerance_table = root.table("tolerances", required=False)
    tolerances = Tolerances(
        pct_valid_drop_points=tolerance_table.number("pct_valid_drop_points", default=5.0, minimum=0.0, maximum=100.0),
        error_increase_mps=tolerance_table.number("error_increase_mps", default=0.5, minimum=0.0, maximum=1e3))
    tolerance_table.reject_unknown()

    combos = _combinations(axes, mode, label)
    point_label = f"{label}: axis values applied to {base_path}"
    base_overridden = _with_overrides(base_data, campaign_overrides, label)
    base = campaign_config_from_data(base_overridden, base_path, source=f"{label}: [sweep] applied to {base_path}",
                                     site=base_config.site, output_dir=out)
    points, seen = [], {}
    for index, values in enumerate(combos):
        point_data = _with_overrides(base_overridden, values, label)
        config = campaign_config_from_data(point_data, base_path, source=point_label, site=base_config.site,
                                           output_dir=out)
        if config.config_hash in seen:
            raise ConfigError(f"{label}: axes: points {seen[config.config_hash]} and p{index:03d} are the same "
                              f"configuration ({values}); allowed: distinct points")
        seen[config.config_hash] = f"p{index:03d}"
        config = replace(config, output_dir=point_store_dir(out, config.config_hash))
        points.append(SweepPoint(point_id=f"p{index:03d}", values=values, config=config))
    return SweepSpec(source=path, base_path=base_path, output_dir=out, mode=mode, axes=axes,
                     tolerances=tolerances, points=points, base=base)


def _campaign_overrides(sweep: Table, base_config: CampaignConfig) -> dict:
    """[sweep] cases_scale and [sweep.cases] as dotted overrides of the base's [campaign] table."""
    overrides = {}
    if sweep.has("cases_scale"):
        overrides["campaign.cases_scale"] = sweep.number("cases_scale", minimum=0.0, maximum=100.0,
                                                         exclusive_minimum=True)
    if sweep.has("cases"):
        cases = sweep.table("cases")
        names = list(base_config.cases_per_class)
        for key in cases.data:
            if key not in names:
                raise cases.fail(key, f"is not a class of site {base_config.site.name}; allowed: {', '.join(names)}")
            overrides[f"campaign.cases.{key}"] = cases.integer(key, minimum=0, maximum=1_000_000)
    return overrides


def _read_axes(root: Table, label: str) -> dict:
    """Flatten [axes] (quoted or unquoted dotted keys) into field -> list of scalar values."""
    if not root.has("axes"):
        raise ConfigError(f"{label}: axes is missing (an [axes] table: config field -> list of values)")
    raw = root.table("axes").data
    axes: dict[str, list] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            if not value:
                raise ConfigError(f"{label}: axes.{prefix} is an empty table; allowed: field = [values]")
            for key, item in value.items():
                walk(f"{prefix}.{key}" if prefix else key, item)
            return
        axes[prefix] = _axis_values(prefix, value, label)

    walk("", raw)
    if not axes:
        raise ConfigError(f"{label}: axes is empty; allowed: one or more config fields, e.g. "
                          "\"scene.camera_effects.dark_current_scale\" = [1.0, 10.0]")
    for field in axes:
        parts = field.split(".")
        if field not in AXIS_FIELDS and not (parts[0] in AXIS_ROOTS and len(parts) >= 2):
            raise ConfigError(f"{label}: axes.{field} is not a sweepable field; allowed: "
                              f"{', '.join(root + '.<field>' for root in AXIS_ROOTS)}, {', '.join(AXIS_FIELDS)}")
    return axes


def _axis_values(field: str, value: Any, label: str) -> list:
    name = f"{label}: axes.{field}"
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{name} must be a non-empty list of values; got {value!r}")
    kinds = {_kind(item) for item in value}
    if None in kinds:
        bad = next(item for item in value if _kind(item) is None)
        raise ConfigError(f"{name}: value {bad!r} is not allowed; allowed: numbers, booleans or strings")
    if len(kinds) > 1:
        raise ConfigError(f"{name}: values {value!r} mix types; allowed: all numbers, all booleans or all strings")
    if any(isinstance(item, float) and not math.isfinite(item) for item in value):
        raise ConfigError(f"{name}: values {value!r} must be finite")
    return list(value)


def _kind(item: Any) -> str | None:
    if isinstance(item, bool):
        return "bool"
    if isinstance(item, (int, float)):
        return "number"
    if isinstance(item, str):
        return "string"
    return None


def _combinations(axes: dict, mode: str, label: str) -> list[dict]:
    names = list(axes)
    if mode == "list":
        lengths = {name: len(values) for name, values in axes.items()}
        if len(set(lengths.values())) > 1:
            raise ConfigError(f"{label}: axes: mode \"list\" needs axes of equal length; got "
                              f"{', '.join(f'{n} {k}' for n, k in lengths.items())}; allowed: equal lengths "
                              "(or mode = \"grid\")")
        combos = [dict(zip(names, values)) for values in zip(*axes.values())]
    else:
        for name, values in axes.items():
            if len(set(values)) != len(values):
                raise ConfigError(f"{label}: axes.{name}: values {values!r} repeat; allowed: distinct values "
                                  "in a grid")
        combos = [dict(zip(names, values)) for values in itertools.product(*axes.values())]
    if len(combos) > MAX_POINTS:
        raise ConfigError(f"{label}: axes make {len(combos)} points; allowed: at most {MAX_POINTS}")
    return combos


def _with_overrides(data: dict, values: dict, label: str) -> dict:
    """A deep copy of ``data`` with each dotted field set (sub-tables are created as needed)."""
    result = copy.deepcopy(data)
    for field, value in values.items():
        node = result
        parts = field.split(".")
        for depth, key in enumerate(parts[:-1]):
            child = node.setdefault(key, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{label}: axes.{field}: {'.'.join(parts[:depth + 1])} is a value, not a table, "
                                  "in the base campaign; allowed: a field inside a table")
            node = child
        node[parts[-1]] = value
    return result
