"""One planned case (a row of ``plan.parquet``) as a typed value."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class PlanRow:
    """One planned case (a row of ``plan.parquet``, :mod:`campaign.plan.placement`) as the case uses it.

    Attributes
    ----------
    case_id : int
        ``class_index * 1_000_000 + case_in_class``.
    class_name, terrain_name : str
        The case's class and the terrain it is placed on.
    case_in_class : int
        Index of the case within its class (0: the class's example images are saved).
    profile_index : int
        Index of the trajectory in the campaign's trajectory set.
    profile_name : str
        That trajectory's name.
    heading_rad : float
        Rotation of the trajectory about the vertical (rad).
    offset_east_m, offset_north_m : float
        Offset of the trajectory on the terrain (m).
    footprint_inside : bool
        Every image footprint lies inside the terrain (the planner's check).
    """

    case_id: int
    class_name: str
    terrain_name: str
    case_in_class: int
    profile_index: int
    profile_name: str
    heading_rad: float
    offset_east_m: float
    offset_north_m: float
    footprint_inside: bool

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> PlanRow:
        """The typed row of a plan record (a dict of ``plan.parquet`` columns; extra columns are ignored)."""
        return cls(case_id=int(record["case_id"]), class_name=str(record["class_name"]),
                   terrain_name=str(record["terrain_name"]), case_in_class=int(record["case_in_class"]),
                   profile_index=int(record["profile_index"]), profile_name=str(record["profile_name"]),
                   heading_rad=float(record["heading_rad"]), offset_east_m=float(record["offset_east_m"]),
                   offset_north_m=float(record["offset_north_m"]), footprint_inside=bool(record["footprint_inside"]))
