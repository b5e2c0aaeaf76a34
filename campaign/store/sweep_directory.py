"""A sweep output directory's description and state: ``OUT/sweep.json`` (the sweep as run: file, bases, sites,
mode, axes, tolerances, points with their values, site, configuration hash, planned cases, store, and the
previous sweep directory a point was reused from), written when a sweep ends or stops and read by
``campaign status OUT`` (:func:`sweep_status_lines`: per point, its store's planned, done, failed and missing
cases), by the commands that take a sweep directory (:func:`point_store`: ``--point``) and by the gate
(:mod:`campaign.report.gate`)."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

from campaign.store.campaign_store import CampaignStore
from campaign.store.case_files import atomic_write_bytes
from campaign.store.errors import StoreError

if TYPE_CHECKING:           # `campaign status` reads sweep.json without loading the configuration models
    from campaign.configuration.sweep_file import SweepSpec

ALLOWED = "allowed: the output directory of an earlier `campaign sweep` of the same sweep file"


def write_description(spec: SweepSpec, reused_from: dict[str, str] | None = None) -> None:
    """Write OUT/sweep.json (also when a sweep stops, so `campaign status OUT` knows all its points);
    ``reused_from``: point id -> the previous sweep directory its store was copied from (``--reuse``)."""
    Path(spec.output_dir).mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(Path(spec.output_dir) / "sweep.json",
                       json.dumps(sweep_description(spec, reused_from), indent=2).encode())


def sweep_description(spec: SweepSpec, reused_from: dict[str, str] | None = None) -> dict:
    """The content of OUT/sweep.json (module docstring). ``site``, ``seed``, ``cases_per_class`` and
    ``false_valid_mps`` are the first base's; every point records its own site and planned cases."""
    bases = spec.all_bases
    reused_from = reused_from or {}
    return {
        "sweep_file": str(spec.source), "base": str(spec.base_path), "bases": [str(base.source) for base in bases],
        "mode": spec.mode, "axes": spec.axes, "design": {"samples": spec.design_samples, "seed": spec.design_seed},
        "site": spec.base.site.name, "sites": [base.site.name for base in bases],
        "classes": {base.site.name: {entry.name: entry.ellipse_fraction for entry in base.site.classes}
                    for base in bases},
        "seed": spec.base.seed, "cases_per_class": spec.base.cases_per_class,
        "cases_scale": spec.base.cases_scale, "false_valid_mps": spec.base.false_valid_mps,
        "tolerances": spec.tolerances.model_dump(),
        "points": [{"point_id": p.point_id, "values": p.values, "site": p.config.site.name,
                    "config_hash": p.config_hash, "planned_cases": sum(p.config.cases_per_class.values()),
                    "store": str(Path("points") / p.config.output_dir.name),
                    **({"reused_from": reused_from[p.point_id]} if p.point_id in reused_from else {})}
                   for p in spec.points],
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def read_description(directory: str | Path) -> dict:
    """A sweep output directory's sweep.json, checked for the fields the baseline and status read."""
    path = Path(directory) / "sweep.json"
    if not path.is_file():
        raise StoreError(f"{directory}: no sweep.json: not a sweep output directory ({ALLOWED})")
    try:
        description = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise StoreError(f"{path}: cannot be read ({exc}); {ALLOWED}") from None
    except ValueError as exc:
        raise StoreError(f"{path}: not valid JSON ({exc}); {ALLOWED}") from None
    points = description.get("points") if isinstance(description, dict) else None
    if not isinstance(points, list) or not isinstance(description.get("axes"), dict) or not all(
            isinstance(p, dict) and isinstance(p.get("point_id"), str) and isinstance(p.get("values"), dict)
            and isinstance(p.get("store"), str) for p in points):
        raise StoreError(f"{path}: not a sweep description (needs axes and points with point_id, values and "
                         f"store); {ALLOWED}")
    return description


def sweep_status_lines(directory: str | Path) -> list[str]:
    """Per point of a sweep output directory: planned, done, failed and missing cases of its store, then the
    totals. The points are sweep.json's; without one (a first sweep still running) the point stores'
    under ``points/``, named by their store and axis values (from their manifests)."""
    directory = Path(directory)
    if (directory / "sweep.json").is_file():
        description = read_description(directory)
        planned_each = sum(int(count) for count in description.get("cases_per_class", {}).values())
        points = [(point_label(point["point_id"], point["values"]), directory / point["store"],
                   int(point.get("planned_cases", planned_each))) for point in description["points"]]
    else:
        points = []
        for manifest_path in sorted((directory / "points").glob("*/manifest.json")):
            values = (CampaignStore(manifest_path.parent).manifest() or {}).get("sweep_point") or {}
            points.append((point_label(f"points/{manifest_path.parent.name}", values), manifest_path.parent, 0))
    lines, totals = [], [0, 0, 0, 0]
    for label, store, planned_each in points:
        if not (store / "manifest.json").is_file():
            lines.append(f"{label}: no store yet ({store}): {planned_each} cases missing")
            totals[0] += planned_each
            totals[3] += planned_each
            continue
        try:
            status = CampaignStore(store).status()
        except StoreError as exc:
            lines.append(f"{label}: {exc}")
            continue
        lines.append(f"{label}: {status.planned} planned, {status.done} done, {status.failed} failed, "
                     f"{status.missing} missing" + (f" ({status.bad} bad case files)" if status.bad else ""))
        for index, count in enumerate((status.planned, status.done, status.failed, status.missing)):
            totals[index] += count
    lines.append(f"{directory}: sweep of {len(points)} points: {totals[0]} planned, {totals[1]} done, "
                 f"{totals[2]} failed, {totals[3]} missing")
    return lines


def point_label(name: str, values: dict) -> str:
    """A point's name and its axis values, as the status and regression lines show it."""
    return f"{name} ({', '.join(f'{k}={value_text(v)}' for k, v in values.items())})"


def value_text(value: object) -> str:
    """An axis value as people read it (a float in its shortest form; a list as ``[6, 0]``)."""
    if isinstance(value, list):
        return "[" + ", ".join(value_text(item) for item in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


def is_sweep_directory(directory: str | Path) -> bool:
    """A sweep output directory (sweep.json, or point stores of a first sweep still running), not a store."""
    directory = Path(directory)
    return (not (directory / "manifest.json").exists()
            and ((directory / "sweep.json").is_file() or (directory / "points").is_dir()))


def point_choices(directory: str | Path) -> list[tuple[str, dict, Path]]:
    """(point id, axis values, store) of every point of a sweep directory: sweep.json's, else the point stores
    under ``points/`` (named ``points/<store>``)."""
    directory = Path(directory)
    if (directory / "sweep.json").is_file():
        return [(point["point_id"], point["values"], directory / point["store"])
                for point in read_description(directory)["points"]]
    return [(f"points/{path.parent.name}", (CampaignStore(path.parent).manifest() or {}).get("sweep_point") or {},
             path.parent) for path in sorted((directory / "points").glob("*/manifest.json"))]


def point_store(directory: str | Path, point: str) -> Path:
    """The store of the point ``point`` (its id ``p003``, its store ``points/<hash>`` or the store's name) of
    a sweep directory; StoreError (one line, naming the points) when there is none."""
    choices = point_choices(directory)
    for point_id, _values, store in choices:
        if point in (point_id, store.name, f"points/{store.name}"):
            return store
    raise StoreError(f"{directory}: no point {point!r}; allowed: {points_hint(choices)}")


def points_hint(choices: list[tuple[str, dict, Path]], shown: int = 4) -> str:
    """A few of a sweep's points as ``--point`` values, e.g. ``p000 (x=1), p001 (x=2), ... (9 points)``."""
    listed = [point_label(point_id, values) for point_id, values, _ in choices[:shown]]
    more = f", ... ({len(choices)} points)" if len(choices) > shown else ""
    return ", ".join(listed) + more if listed else "no point has a store yet"
