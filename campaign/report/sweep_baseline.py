"""A sweep against its baseline (``campaign sweep FILE --baseline DIR``), read before the sweep runs.

The baseline is a previous sweep's output directory (:func:`campaign.report.gate.read_side`). It must share
at least one point with this sweep (the same site and axis values; a sweep of several sites matches each
site's points); anything else is one line naming the file and what is allowed (exit 2), read before the
sweep runs, so a baseline that is the output directory itself is judged as it was: the case rows of the
matched baseline points are read here, before the run. After the run, :func:`campaign.report.gate.gate`
judges the sweep's output directory against it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from campaign.configuration.sweep_file import SweepSpec
from campaign.report.gate import GatePoint, GateSide, matched_points, point_rows, read_side
from campaign.store.errors import StoreError
from campaign.store.sweep_directory import ALLOWED


@dataclass(frozen=True)
class Baseline:
    """A previous sweep (its gate side) and the case rows of each of its points that match a point of this
    sweep (baseline point id -> rows, with an ``estimator`` column)."""

    side: GateSide
    rows: dict[str, pd.DataFrame]

    @property
    def directory(self) -> Path:
        return self.side.directory


def spec_side(spec: SweepSpec) -> GateSide:
    """This sweep's points as a gate side (their keys only: nothing has run yet)."""
    return GateSide(Path(spec.output_dir), "sweep", spec.axis_names,
                    [GatePoint(p.point_id, p.values, spec.base_of(p).site.name, Path(spec.output_dir), "", "", {},
                               spec.base.false_valid_mps, 0, 0, 0) for p in spec.points])


def read_baseline(directory: str | Path, spec: SweepSpec) -> Baseline:
    """The baseline for ``spec`` (StoreError, one line, when it is missing, corrupt or incompatible)."""
    side = read_side(directory, "baseline")
    if side.kind != "sweep":
        raise StoreError(f"{directory}: a campaign store, not a sweep output directory ({ALLOWED}; `campaign gate` "
                         "compares two campaign stores)")
    pairs, _ = matched_points(spec_side(spec), side, name="this sweep")
    matched = {theirs.point_id: theirs for _, theirs in pairs}
    return Baseline(side, {point_id: point_rows(side, point) for point_id, point in matched.items()})
