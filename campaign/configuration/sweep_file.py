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

    [tolerances]                        # for --baseline (campaign/report/baseline_gate.py has the rules)
    false_valid_increase = 0            # false-valid cases a class (or the site) may gain
    significance = 0.01                 # level of the one-sided Fisher exact test on a % valid drop and
                                        # of the permutation test on an error growth
    pct_valid_drop_points = 20.0        # a larger % valid drop counts whatever its p-value
    error_increase_mps = 0.5            # an error mean+3 sigma growth (m/s) must exceed this to count

Axis fields are any field of the ``[sensors]``, ``[estimator]`` and ``[scene]`` tables (including
sub-tables such as ``scene.camera_effects``), or ``campaign.seed``. Each point's configuration is the
base TOML with the point's values set, validated exactly like a campaign file; its campaign
configuration hash (``[execution]`` and ``output_dir`` excluded) is the point's key. A sweep has at most
:data:`MAX_POINTS` points. Up to :data:`EAGER_POINTS` points are validated before anything runs: all
of a smaller sweep; of a larger one the first point and, for every axis value, the first point that
has it (so a bad value is refused before anything is written). The other points of a large sweep are
validated when they are first used (:attr:`SweepPoint.config`, a few ms each): a point that fails
there (a combination of valid values that the campaign refuses, or two points of one configuration)
stops the sweep with one line naming the point, the points before it kept. Errors are one
line naming the sweep file, the field and the allowed values. The file's tables are declared once, by
:class:`SweepFile` (``campaign schema sweep``); axis values are validated by the campaign tables' own
declarations when each point is validated.
"""
from __future__ import annotations

import copy
import dataclasses
import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

from pydantic import Field

from campaign.configuration.campaign_file import (
    COMMAND_LINE,
    CampaignConfig,
    CampaignTable,
    CaseCount,
    CasesScale,
    campaign_config_from_data,
    load_campaign_config,
)
from config_tables.errors import ConfigError
from config_tables.models import ConfigModel, ExistingFile, parse, parse_field
from config_tables.toml_file import load_toml

AXIS_ROOTS = ("sensors", "estimator", "scene")
AXIS_FIELDS = ("campaign.seed", "site.terrain_contrast_scale")
MAX_POINTS = 10_000
EAGER_POINTS = 256      # points validated before a sweep runs (module docstring); the rest when first used


class SweepTable(ConfigModel):
    """``[sweep]``: the base campaign and how its points are formed."""

    base: ExistingFile
    """Base campaign TOML, relative to the sweep file."""
    output_dir: str | None = None
    """Relative to the working directory (default runs/sweeps/<sweep file stem>)."""
    mode: Literal["grid", "list"] = "grid"
    """"grid": every combination of the axis values; "list": the i-th value of every axis."""
    cases_scale: CasesScale | None = None
    """Replaces the base's [campaign] cases_scale."""
    cases: dict[str, CaseCount] = {}
    """Class -> case count, merged over the base's [campaign.cases]."""


class Tolerances(ConfigModel):
    """``[tolerances]``: when a metric counts as a regression against a baseline (the rules are in
    :mod:`campaign.report.baseline_gate`)."""

    false_valid_increase: int = Field(0, ge=0, le=1_000_000)
    """False-valid cases a class (or the site) may gain (0: any increase is a regression)."""
    significance: float = Field(0.01, gt=0.0, le=0.5)
    """Level of the one-sided tests: Fisher exact on a % valid drop, permutation on an error growth."""
    pct_valid_drop_points: float = Field(20.0, ge=0.0, le=100.0)
    """A larger drop of a class's (or the weighted) % valid is a regression whatever its p-value; the
    default lets one case among 5 or more flip without tripping it (the exact test judges that)."""
    error_increase_mps: float = Field(0.5, ge=0.0, le=1e3)
    """The error mean + 3 sigma (m/s) is judged only when it grows by more than this."""


class SweepFile(ConfigModel):
    """A sweep TOML file."""

    sweep: SweepTable
    axes: dict[str, Any] = Field(min_length=1)
    """Dotted config field -> non-empty list of values (TOML units): sensors.*, estimator.*, scene.*, campaign.seed,
    site.terrain_contrast_scale."""
    tolerances: Tolerances = Tolerances()


@dataclass(frozen=True)
class SweepPoint:
    """One point of a sweep: its id (``p000``...), axis values and validated campaign config."""

    point_id: str
    values: dict            # axis field -> value, in axis order
    build: Callable[[], CampaignConfig] = dataclasses.field(compare=False, repr=False)

    @cached_property
    def config(self) -> CampaignConfig:
        """The point's campaign, validated on first use (ConfigError, one line); output_dir is the point's
        store, OUT/points/<hash[:16]>."""
        return self.build()

    @property
    def config_hash(self) -> str:
        return self.config.config_hash


class _PointBuilder:
    """Validates the points of one sweep, each once, and refuses two points of one configuration."""

    def __init__(self, base_data: dict, base_path: Path, label: str, output_dir: Path):
        self.base_data, self.base_path, self.label, self.output_dir = base_data, base_path, label, output_dir
        self.seen: dict[str, int] = {}

    def __call__(self, index: int, values: dict) -> CampaignConfig:
        point_data = _with_overrides(self.base_data, values, self.label)
        config = campaign_config_from_data(point_data, self.base_path, output_dir=self.output_dir,
                                           source=f"{self.label}: axis values applied to {self.base_path}")
        first = self.seen.setdefault(config.config_hash, index)
        if first != index:
            raise ConfigError(f"{self.label}: axes: points p{first:03d} and p{index:03d} are the same "
                              f"configuration ({values}); allowed: distinct points")
        return config.with_output_dir(point_store_dir(self.output_dir, config.config_hash))


def eager_indices(combos: list[dict], limit: int = EAGER_POINTS) -> list[int]:
    """The points validated before a sweep runs: every point of a sweep of at most ``limit`` points, else
    the first point and the first point having each axis value, up to ``limit`` (in point order)."""
    if len(combos) <= limit:
        return list(range(len(combos)))
    chosen, covered = [0], {(name, repr(value)) for name, value in combos[0].items()}
    for index, values in enumerate(combos):
        pairs = {(name, repr(value)) for name, value in values.items()}
        if not pairs <= covered and len(chosen) < limit:
            chosen.append(index)
            covered |= pairs
    return sorted(chosen)


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


def load_sweep(path: str | Path, output_dir: str | Path | None = None, cases_scale: float | None = None) -> SweepSpec:
    """Read and validate a sweep file and every point's configuration (nothing is written).

    ``output_dir`` (``--output``) replaces ``[sweep] output_dir``; ``cases_scale`` (``--cases-scale``)
    replaces ``[sweep] cases_scale`` and the base's ``[campaign] cases_scale`` (case counts are not part of
    a point's configuration hash: a scaled run is a prefix of the full one and shares its stores).

    Raises
    ------
    ConfigError
        One line naming the sweep (or base) file, the field and the allowed values.
    """
    path = Path(path)
    data = load_toml(path)
    label = str(path)
    tables = parse(SweepFile, data, label, context={"base_dir": path.resolve().parent})
    sweep = tables.sweep
    base_path = sweep.base.resolve()     # absolute: point hashes do not depend on the working directory
    out = Path(output_dir) if output_dir is not None else Path(sweep.output_dir or f"runs/sweeps/{path.stem}")
    base_data = load_toml(base_path)
    base_config = load_campaign_config(base_path)          # base errors name the base file
    campaign_overrides = _campaign_overrides(sweep, base_config, label)
    if cases_scale is not None:
        parse_field(CampaignTable, "cases_scale", cases_scale, COMMAND_LINE, "--cases-scale")
        campaign_overrides["campaign.cases_scale"] = float(cases_scale)
    axes = _read_axes(tables.axes, label)

    combos = _combinations(axes, sweep.mode, label)
    base_overridden = _with_overrides(base_data, campaign_overrides, label)
    base = campaign_config_from_data(base_overridden, base_path, source=f"{label}: [sweep] applied to {base_path}",
                                     output_dir=out)
    builder = _PointBuilder(base_overridden, base_path, label, out)
    points = [SweepPoint(point_id=f"p{index:03d}", values=values, build=functools.partial(builder, index, values))
              for index, values in enumerate(combos)]
    for index in eager_indices(combos):
        points[index].config        # noqa: B018 - validates (ConfigError, one line) before anything runs
    return SweepSpec(source=path, base_path=base_path, output_dir=out, mode=sweep.mode, axes=axes,
                     tolerances=tables.tolerances, points=points, base=base)


def _campaign_overrides(sweep: SweepTable, base_config: CampaignConfig, label: str) -> dict:
    """[sweep] cases_scale and [sweep.cases] as dotted overrides of the base's [campaign] table."""
    overrides = {}
    if sweep.cases_scale is not None:
        overrides["campaign.cases_scale"] = sweep.cases_scale
    names = list(base_config.cases_per_class)
    for key, count in sweep.cases.items():
        if key not in names:
            raise ConfigError(f"{label}: sweep.cases.{key} is not a class of site {base_config.site.name}; "
                              f"allowed: {', '.join(names)}")
        overrides[f"campaign.cases.{key}"] = count
    return overrides


def _read_axes(raw: dict, label: str) -> dict:
    """Flatten [axes] (quoted or unquoted dotted keys) into field -> list of scalar values."""
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
