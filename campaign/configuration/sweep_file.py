"""Sweep files: a base campaign plus parameter axes, validated into one campaign config per point.

A sweep file (e.g. ``sitedata/sweeps/nightly.toml``)::

    [sweep]
    base = ["../gusev.toml", "../meridiani.toml"]   # base campaign TOML(s), relative to this file (required):
                                        # one file, or a list of files of distinct sites (each point is
                                        # swept on every base: a "site" axis, first, whose values are the
                                        # sites' names)
    output_dir = "runs/sweeps/nightly"  # relative to the working directory (default runs/sweeps/<file stem>)
    mode = "grid"                       # how the axes make points (:data:`POINT_GENERATORS`): "grid":
                                        # cartesian product of the axes; "list": i-th value of every axis;
                                        # "sobol" / "morris": a design sampled from each axis's range
                                        # [low, high] (campaign/configuration/sweep_designs.py)
    samples = 8                         # designed sweeps only: Sobol base samples (power of two) or Morris
                                        # trajectories; design_seed = 0 the sampling's seed
    cases_scale = 0.05                  # optional: replaces the base's [campaign] cases_scale
    [sweep.cases]                       # optional: class -> count, merged over the [campaign.cases] of the
    gkep = 0                            # base(s) having that class

    [axes]                              # dotted config field -> list of values (TOML units: degrees...)
    "scene.camera_effects.dark_current_scale" = [1.0, 30.0]
    sensors.attitude_random_sigma_deg = [0.05, 0.5]     # unquoted dotted keys work as well
    "estimators.probe.parameters.bias" = [[0.0, 0.0], [6.0, 0.0]]   # a plug-in's parameter (by its name)

    [tolerances]                        # for --baseline (campaign/report/baseline_gate.py has the rules)
    false_valid_increase = 0            # false-valid cases a class (or the site) may gain
    significance = 0.01                 # level of the one-sided Fisher exact test on a % valid drop and
                                        # of the permutation test on an error growth
    pct_valid_drop_points = 20.0        # a larger % valid drop counts whatever its p-value
    error_increase_mps = 0.5            # an error mean+3 sigma growth (m/s) must exceed this to count

Axis fields are any field of the ``[sensors]``, ``[estimator]`` and ``[scene]`` tables (including
sub-tables such as ``scene.camera_effects``), ``campaign.seed``, ``site.terrain_contrast_scale``, or a
field of one ``[[estimators]]`` entry named by its ``name``: ``estimators.<name>.parameters.<key>`` (a
plug-in's or a reference entry's parameter; every base must have an estimator of that name) or
``estimators.<name>.<field>`` (e.g. ``timeout_s``; ``name`` and ``kind`` are not swept). Axis values are
numbers, booleans, strings, or lists of numbers (a vector parameter such as a bias ``[east, north]``).
Each point's configuration is the
base TOML with the point's values set, validated exactly like a campaign file; its campaign
configuration hash (``[execution]`` and ``output_dir`` excluded) is the point's key. With several bases,
every point of the axes is made on each base in turn (p000... on the first base's site, then the
next's), the point's values start with ``site`` (the base's site name), ``[execution]`` is the first
base's, and each site's table, plots and gate use its own classes and ellipse fractions. A sweep has at most
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
from typing import Annotated, Any, Literal

from pydantic import Field

from campaign.configuration.base_files import layered_data, resolve_base, shipped_sites
from campaign.configuration.campaign_file import (
    COMMAND_LINE,
    CampaignConfig,
    CampaignTable,
    CaseCount,
    CasesScale,
    campaign_config_from_data,
    load_campaign_config,
)
from campaign.configuration.sweep_axes import SITE_AXIS
from campaign.configuration.sweep_designs import DESIGN_MODES, design_points
from config_tables.errors import ConfigError
from config_tables.models import ConfigModel, ExistingFile, parse, parse_field
from config_tables.toml_file import load_toml

AXIS_ROOTS = ("sensors", "estimator", "scene")
AXIS_FIELDS = ("campaign.seed", "site.terrain_contrast_scale")
ESTIMATOR_ENTRY_ROOT = "estimators"     # estimators.<name>.<field...>: a field of the [[estimators]] entry <name>
ESTIMATOR_ENTRY_FIXED = ("name", "kind")    # fields of an entry that are not swept
MAX_POINTS = 10_000
EAGER_POINTS = 256      # points validated before a sweep runs (module docstring); the rest when first used


class SweepTable(ConfigModel):
    """``[sweep]``: the base campaign and how its points are formed."""

    base: ExistingFile | Annotated[list[ExistingFile], Field(min_length=1, max_length=64)]
    """Base campaign TOML, relative to the sweep file, or a shipped site by name (``"gusev"``; resolved before
    validation by :func:`_resolve_bases`); or a list of them, of distinct sites (a ``site`` axis)."""
    output_dir: str | None = None
    """Relative to the working directory (default runs/sweeps/<sweep file stem>)."""
    mode: Literal["grid", "list", "sobol", "morris"] = "grid"
    """"grid": every combination of the axis values; "list": the i-th value of every axis (:data:`POINT_GENERATORS`);
    "sobol", "morris": a design sampled from each axis's range [low, high] (campaign.configuration.sweep_designs)."""
    samples: int | None = Field(None, ge=2, le=4096)
    """Designed sweeps only (required there): Sobol base samples N (a power of two; N x (axes + 2) points) or
    Morris trajectories (N x (axes + 1) points)."""
    design_seed: int = Field(0, ge=0, le=2**31 - 1)
    """Designed sweeps: the seed of the sampling (same seed, same points)."""
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
    site.terrain_contrast_scale, estimators.<name>.parameters.<key> (a [[estimators]] entry's parameter)."""
    tolerances: Tolerances = Tolerances()


@dataclass(frozen=True)
class SweepPoint:
    """One point of a sweep: its id (``p000``...), axis values and validated campaign config."""

    point_id: str
    values: dict            # axis field -> value, in axis order (``site`` first in a sweep of several bases)
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

    def __init__(self, base_data: dict, base_path: Path, label: str, output_dir: Path, seen: dict[str, int],
                 repeats: bool = False):
        self.base_data, self.base_path, self.label, self.output_dir = base_data, base_path, label, output_dir
        self.seen = seen        # config hash -> first point index, shared by the builders of every base
        self.repeats = repeats  # a design's rows may repeat a configuration: they share its store

    def __call__(self, index: int, values: dict) -> CampaignConfig:
        overrides = {field: value for field, value in values.items() if field != SITE_AXIS}
        point_data = _with_overrides(self.base_data, overrides, self.label)
        config = campaign_config_from_data(point_data, self.base_path, output_dir=self.output_dir,
                                           source=f"{self.label}: axis values applied to {self.base_path}")
        first = self.seen.setdefault(config.config_hash, index)
        if first != index and not self.repeats:
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
    base_path: Path         # the first base
    output_dir: Path
    mode: str
    axes: dict              # field -> list of values (``site`` first with several bases)
    tolerances: Tolerances
    points: list            # list[SweepPoint]
    base: CampaignConfig    # the first base campaign with the sweep's case counts, without axis values
    bases: tuple = ()       # every base campaign (CampaignConfig), in file order; (base,) for one base
    design_samples: int | None = None   # designed sweeps ([sweep] samples)
    design_seed: int = 0                # designed sweeps ([sweep] design_seed)

    @property
    def axis_names(self) -> list[str]:
        return list(self.axes)

    @property
    def all_bases(self) -> tuple:
        return self.bases or (self.base,)

    def base_of(self, point: SweepPoint) -> CampaignConfig:
        """The base campaign a point was made from (its site's)."""
        site = point.values.get(SITE_AXIS) if SITE_AXIS in self.axes else None
        return next((base for base in self.all_bases if base.site.name == site), self.base)

    def site_views(self) -> list[SweepSpec]:
        """One sweep per site: its base, its points, the axes without ``site`` ([self] for one base). The
        tables and plots of a site use its classes."""
        if SITE_AXIS not in self.axes:
            return [self]
        axes = {name: values for name, values in self.axes.items() if name != SITE_AXIS}
        return [dataclasses.replace(self, base=base, base_path=Path(base.source), axes=axes, bases=(base,),
                                    points=[p for p in self.points if p.values[SITE_AXIS] == base.site.name])
                for base in self.all_bases]

    @property
    def estimators(self) -> list:
        """The estimators of every base (each python callable and command once), for the cluster's plug-ins."""
        seen, specs = set(), []
        for base in self.all_bases:
            for spec in base.estimators:
                key = (spec.kind, spec.callable, tuple(spec.argv))
                if key not in seen:
                    seen.add(key)
                    specs.append(spec)
        return specs


def point_store_dir(output_dir: Path, config_hash: str) -> Path:
    return Path(output_dir) / "points" / config_hash[:16]


def grid_points(axes: dict, label: str) -> list[dict]:
    """``mode = "grid"``: every combination of the axis values (the last axis varies fastest)."""
    for name, values in axes.items():
        if len({_value_key(value) for value in values}) != len(values):
            raise ConfigError(f"{label}: axes.{name}: values {values!r} repeat; allowed: distinct values "
                              "in a grid")
    return [dict(zip(axes, values)) for values in itertools.product(*axes.values())]


def list_points(axes: dict, label: str) -> list[dict]:
    """``mode = "list"``: point i takes the i-th value of every axis (axes of equal length)."""
    lengths = {name: len(values) for name, values in axes.items()}
    if len(set(lengths.values())) > 1:
        raise ConfigError(f"{label}: axes: mode \"list\" needs axes of equal length; got "
                          f"{', '.join(f'{n} {k}' for n, k in lengths.items())}; allowed: equal lengths "
                          "(or mode = \"grid\")")
    return [dict(zip(axes, values)) for values in zip(*axes.values())]


#: ``[sweep] mode`` -> the function making a sweep's points from its axes (``(axes, label) -> [values]``,
#: each point's values a dict field -> value in axis order; ConfigError, one line, naming ``label``). Another
#: generator (e.g. a sampling design) is one more entry here and one more value of ``SweepTable.mode``.
POINT_GENERATORS: dict[str, Callable[[dict, str], list[dict]]] = {"grid": grid_points, "list": list_points}


def _resolve_bases(data: dict, path: Path, label: str) -> None:
    """Resolve ``[sweep] base`` (one value or a list) in place, as a campaign file's ``base`` is resolved.

    Each string is a shipped site's name (``"gusev"``: ``sitedata/gusev.toml`` of the installed package) or a
    TOML file relative to the sweep file (:func:`campaign.configuration.base_files.resolve_base`); it is
    replaced by the absolute path of the file it names. A name or file that does not exist is one line
    naming ``sweep.base`` (other wrong values are left to the model's validation).

    Raises
    ------
    ConfigError
        ``sweep.base`` names neither a shipped site nor an existing file.
    """
    sweep = data.get("sweep")
    if not isinstance(sweep, dict) or not isinstance(sweep.get("base"), (str, list)):
        return
    if sweep["base"] == []:
        raise ConfigError(f"{label}: sweep.base = [] names no campaign; allowed: a shipped site "
                          f"({', '.join(shipped_sites())}), a TOML file relative to the sweep file, or a list of "
                          "1 to 64 of them")
    writer = path.resolve()
    resolved = []
    for item in sweep["base"] if isinstance(sweep["base"], list) else [sweep["base"]]:
        try:
            resolved.append(str(resolve_base(item, writer, label)))
        except ConfigError as error:        # "<label>: base = ..." -> "<label>: sweep.base = ..."
            raise ConfigError(f"{label}: sweep.{str(error)[len(label) + 2:]}") from None
    sweep["base"] = resolved if isinstance(sweep["base"], list) else resolved[0]


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
    _resolve_bases(data, path, label)
    tables = parse(SweepFile, data, label, context={"base_dir": path.resolve().parent})
    sweep = tables.sweep
    base_paths = [item.resolve() for item in (sweep.base if isinstance(sweep.base, list) else [sweep.base])]
    out = Path(output_dir) if output_dir is not None else Path(sweep.output_dir or f"runs/sweeps/{path.stem}")
    if cases_scale is not None:
        parse_field(CampaignTable, "cases_scale", cases_scale, COMMAND_LINE, "--cases-scale")
    base_configs = [load_campaign_config(base_path) for base_path in base_paths]   # base errors name the base file
    _check_sites(base_paths, base_configs, label)
    class_names = {name for config in base_configs for name in config.cases_per_class}
    axes = _read_axes(tables.axes, label)
    designed = sweep.mode in DESIGN_MODES
    if designed != (sweep.samples is not None):
        raise ConfigError(f"{label}: sweep.samples = {sweep.samples}; allowed: an integer >= 2 with mode "
                          f"\"sobol\" or \"morris\" (required there), none with mode \"{sweep.mode}\"")
    combos = (design_points(sweep.mode, axes, int(sweep.samples or 0), sweep.design_seed, label) if designed
              else POINT_GENERATORS[sweep.mode](axes, label))
    multi_site = len(base_paths) > 1
    if multi_site:
        axes = {SITE_AXIS: [config.site.name for config in base_configs], **axes}
    if len(combos) * len(base_paths) > MAX_POINTS:
        raise ConfigError(f"{label}: axes make {len(combos) * len(base_paths)} points; allowed: at most {MAX_POINTS}")

    seen: dict[str, int] = {}
    bases: list[CampaignConfig] = []
    points: list[SweepPoint] = []
    all_values: list[dict] = []
    for base_path, base_config in zip(base_paths, base_configs):
        overrides = _campaign_overrides(sweep, base_config, class_names, label)
        if cases_scale is not None:
            overrides["campaign.cases_scale"] = float(cases_scale)
        # the base file with its own bases laid under it (campaign.configuration.base_files), then the overrides
        base_data = _with_overrides(layered_data(load_toml(base_path), base_path, label).data, overrides, label)
        _check_estimator_axes(axes, base_data, base_path, label)
        bases.append(campaign_config_from_data(base_data, base_path, source=f"{label}: [sweep] applied to {base_path}",
                                               output_dir=out))
        builder = _PointBuilder(base_data, base_path, label, out, seen, repeats=designed)
        for combo in combos:
            index = len(points)
            values = {SITE_AXIS: base_config.site.name, **combo} if multi_site else combo
            points.append(SweepPoint(point_id=f"p{index:03d}", values=values,
                                     build=functools.partial(builder, index, values)))
            all_values.append(values)
    for index in eager_indices(all_values):
        points[index].config        # noqa: B018 - validates (ConfigError, one line) before anything runs
    return SweepSpec(source=path, base_path=base_paths[0], output_dir=out, mode=sweep.mode, axes=axes,
                     tolerances=tables.tolerances, points=points, base=bases[0], bases=tuple(bases),
                     design_samples=sweep.samples, design_seed=sweep.design_seed)


def _check_sites(base_paths: list[Path], configs: list[CampaignConfig], label: str) -> None:
    """Several bases must be of distinct sites (the ``site`` axis names a point's base)."""
    first: dict[str, Path] = {}
    for base_path, config in zip(base_paths, configs):
        other = first.setdefault(config.site.name, base_path)
        if other is not base_path:
            raise ConfigError(f"{label}: sweep.base: {other} and {base_path} are both of site {config.site.name}; "
                              "allowed: one base per site (sweep a field to compare two variants of a site)")


def _campaign_overrides(sweep: SweepTable, base_config: CampaignConfig, class_names: set[str], label: str) -> dict:
    """[sweep] cases_scale and [sweep.cases] as dotted overrides of a base's [campaign] table ([sweep.cases]
    keys that are classes of another base are left out)."""
    overrides: dict[str, Any] = {}
    if sweep.cases_scale is not None:
        overrides["campaign.cases_scale"] = sweep.cases_scale
    names = list(base_config.cases_per_class)
    for key, count in sweep.cases.items():
        if key not in class_names:
            sites = "" if len(class_names) == len(names) else " of any base"
            raise ConfigError(f"{label}: sweep.cases.{key} is not a class of site {base_config.site.name}{sites}; "
                              f"allowed: {', '.join(sorted(class_names) if sites else names)}")
        if key in names:
            overrides[f"campaign.cases.{key}"] = count
    return overrides


def _read_axes(raw: dict, label: str) -> dict:
    """Flatten [axes] (quoted or unquoted dotted keys) into field -> list of values."""
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
        if parts[0] == ESTIMATOR_ENTRY_ROOT and len(parts) >= 3 and parts[2] not in ESTIMATOR_ENTRY_FIXED:
            continue
        if field not in AXIS_FIELDS and not (parts[0] in AXIS_ROOTS and len(parts) >= 2):
            raise ConfigError(f"{label}: axes.{field} is not a sweepable field; allowed: "
                              f"{', '.join(root + '.<field>' for root in AXIS_ROOTS)}, {', '.join(AXIS_FIELDS)}, "
                              f"{ESTIMATOR_ENTRY_ROOT}.<estimator name>.parameters.<key>")
    return axes


def _check_estimator_axes(axes: dict, base_data: dict, base_path: Path, label: str) -> None:
    """Every ``estimators.<name>...`` axis names an entry of the base's [[estimators]]."""
    entries = base_data.get("estimators")
    names = [entry.get("name") for entry in entries if isinstance(entry, dict)] if isinstance(entries, list) else []
    for field in axes:
        parts = field.split(".")
        if parts[0] == ESTIMATOR_ENTRY_ROOT and parts[1] not in names:
            have = f"its estimators are {', '.join(map(str, names))}" if names else "it has no [[estimators]]"
            raise ConfigError(f"{label}: axes.{field}: the base {base_path} has no estimator named {parts[1]!r} "
                              f"({have}); allowed: estimators.<name of one of its [[estimators]]>.parameters.<key> "
                              "(the reference's defaults are swept as estimator.<field>)")


def _axis_values(field: str, value: Any, label: str) -> list:
    name = f"{label}: axes.{field}"
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{name} must be a non-empty list of values; got {value!r}")
    kinds = {_kind(item) for item in value}
    if None in kinds:
        bad = next(item for item in value if _kind(item) is None)
        raise ConfigError(f"{name}: value {bad!r} is not allowed; allowed: numbers, booleans, strings or lists of "
                          "numbers")
    if len(kinds) > 1:
        raise ConfigError(f"{name}: values {value!r} mix types; allowed: all numbers, all booleans, all strings "
                          "or all lists of numbers")
    numbers = [number for item in value for number in (item if isinstance(item, list) else [item])]
    if any(isinstance(number, float) and not math.isfinite(number) for number in numbers):
        raise ConfigError(f"{name}: values {value!r} must be finite")
    return list(value)


def _kind(item: Any) -> str | None:
    if isinstance(item, bool):
        return "bool"
    if isinstance(item, (int, float)):
        return "number"
    if isinstance(item, str):
        return "string"
    if isinstance(item, list) and item and all(_kind(number) == "number" for number in item):
        return "numbers"
    return None


def _value_key(value: Any) -> str:
    """A value as a comparable text (1 and 1.0, [1, 0] and [1.0, 0.0] the same)."""
    if isinstance(value, list):
        return "[" + ",".join(_value_key(item) for item in value) + "]"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return repr(float(value))
    return repr(value)


def _with_overrides(data: dict, values: dict, label: str) -> dict:
    """A deep copy of ``data`` with each dotted field set (sub-tables are created as needed);
    ``estimators.<name>.<field...>`` sets a field of the [[estimators]] entry named ``<name>``."""
    result = copy.deepcopy(data)
    for field, value in values.items():
        node = result
        parts = field.split(".")
        if parts[0] == ESTIMATOR_ENTRY_ROOT and isinstance(result.get(ESTIMATOR_ENTRY_ROOT), list):
            entry = next((item for item in result[ESTIMATOR_ENTRY_ROOT]
                          if isinstance(item, dict) and item.get("name") == parts[1]), None)
            if entry is None:
                raise ConfigError(f"{label}: axes.{field}: no estimator named {parts[1]!r} in the base campaign; "
                                  "allowed: estimators.<name of one of its [[estimators]]>.parameters.<key>")
            node, parts = entry, parts[2:]
        for depth, key in enumerate(parts[:-1]):
            child = node.setdefault(key, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{label}: axes.{field}: {'.'.join(parts[:depth + 1])} is a value, not a table, "
                                  "in the base campaign; allowed: a field inside a table")
            node = child
        node[parts[-1]] = copy.deepcopy(value)
    return result
