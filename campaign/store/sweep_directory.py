"""A sweep output directory's description and state: ``OUT/sweep.json`` (the sweep as run: file, base, mode,
axes, tolerances, points with their values, configuration hash and store), written when a sweep ends or
stops and read by ``campaign status OUT`` (:func:`sweep_status_lines`: per point, its store's planned, done,
failed and missing cases) and by the baseline check (:mod:`campaign.report.sweep_baseline`)."""
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


def write_description(spec: SweepSpec) -> None:
    """Write OUT/sweep.json (also when a sweep stops, so `campaign status OUT` knows all its points)."""
    Path(spec.output_dir).mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(Path(spec.output_dir) / "sweep.json", json.dumps(sweep_description(spec), indent=2).encode())


def sweep_description(spec: SweepSpec) -> dict:
    """The content of OUT/sweep.json (module docstring)."""
    return {
        "sweep_file": str(spec.source), "base": str(spec.base_path), "mode": spec.mode, "axes": spec.axes,
        "site": spec.base.site.name, "seed": spec.base.seed, "cases_per_class": spec.base.cases_per_class,
        "cases_scale": spec.base.cases_scale, "false_valid_mps": spec.base.false_valid_mps,
        "tolerances": spec.tolerances.model_dump(),
        "points": [{"point_id": p.point_id, "values": p.values, "config_hash": p.config_hash,
                    "store": str(Path("points") / p.config.output_dir.name)} for p in spec.points],
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
        points = [(point_label(point["point_id"], point["values"]), directory / point["store"])
                  for point in description["points"]]
    else:
        planned_each = 0
        points = []
        for manifest_path in sorted((directory / "points").glob("*/manifest.json")):
            values = (CampaignStore(manifest_path.parent).manifest() or {}).get("sweep_point") or {}
            points.append((point_label(f"points/{manifest_path.parent.name}", values), manifest_path.parent))
    lines, totals = [], [0, 0, 0, 0]
    for label, store in points:
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
    """An axis value as people read it (a float in its shortest form)."""
    return f"{value:g}" if isinstance(value, float) else str(value)
