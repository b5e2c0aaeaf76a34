"""One Monte Carlo case on a worker: simulate three descent images with sensor measurements, run the
reference estimator, and write the result row durably.

Big read-only inputs (camera, trajectory set, terrain strips) are loaded once per worker process and
kept in :data:`_WORKER_RESOURCES`, keyed by the campaign's configuration hash; tasks themselves only
carry the small :class:`CampaignContext` and one plan row.

Randomness: case ``k`` of a campaign with seed ``s`` draws everything from
``SeedSequence([s, k]).spawn(...)``: one stream per image (scene + camera noise), one for the sensors,
so a case is bit-for-bit reproducible whatever the worker count or order.
"""
from __future__ import annotations

import os
import socket
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simulator.descent_profile import DescentProfile

from .store import write_case_row

_WORKER_RESOURCES: dict[str, "Resources"] = {}
IMAGE_COUNT = 3


@dataclass(frozen=True)
class CampaignContext:
    """What every task needs besides its plan row (small and picklable)."""

    config: object          # campaign.config.CampaignConfig
    config_hash: str
    store_root: str

    @classmethod
    def from_config(cls, config, store_root: Path) -> "CampaignContext":
        return cls(config=config, config_hash=config.config_hash, store_root=str(store_root))


class Resources:
    """Camera, trajectory set and (lazily) terrain strips of one campaign, loaded once per process."""

    def __init__(self, config):
        from simulator.camera_config import load_camera
        from sitedata.trajectory_io import read_trajectory_set

        self.config = config
        self.camera = load_camera(config.site.camera_path)
        self.profiles: list[DescentProfile] = read_trajectory_set(config.site.trajectory_path)
        self._terrains: dict = {}

    def terrain(self, class_name: str):
        if class_name not in self._terrains:
            from sitedata.sites import load_class_terrain

            entry = next(entry for entry in self.config.site.classes if entry.name == class_name)
            self._terrains[class_name] = load_class_terrain(entry)
        return self._terrains[class_name]

    def placed_profile(self, row: dict) -> DescentProfile:
        profile = self.profiles[int(row["profile_index"])]
        return profile.placed(float(row["heading_rad"]), np.array([row["offset_east_m"], row["offset_north_m"]]),
                              name=f"{profile.name}@case{int(row['case_id'])}")


def load_resources(config) -> Resources:
    """The per-process resources of a campaign (created on first use)."""
    if config.config_hash not in _WORKER_RESOURCES:
        _WORKER_RESOURCES[config.config_hash] = Resources(config)
    return _WORKER_RESOURCES[config.config_hash]


def execute_case(context: CampaignContext, row: dict) -> str:
    """Run one case with retries and write its row (ok or failed) to the store; return the status."""
    config = context.config
    attempts = config.execution.retries + 1
    error = ""
    started = time.perf_counter()
    for attempt in range(1, attempts + 1):
        try:
            result = simulate_case(load_resources(config), row, context.store_root)
            status, attempts_used = "ok", attempt
            break
        except Exception as exc:  # recorded in the row; the campaign goes on
            error = f"{type(exc).__name__}: {exc} | {traceback.format_exc(limit=3).splitlines()[-2].strip()}"
            attempts_used = attempt
    else:
        status, result = "failed", failed_fields()
    record = {**plan_fields(row, config.seed), "status": status, "error": error if status == "failed" else "",
              **result, "attempts": attempts_used, "worker": f"{socket.gethostname()}:{os.getpid()}",
              "t_case_ms": 1e3 * (time.perf_counter() - started)}
    write_case_row(Path(context.store_root) / "cases", int(row["case_id"]), record)
    return status


def plan_fields(row: dict, seed: int) -> dict:
    return {
        "case_id": int(row["case_id"]), "class_name": str(row["class_name"]), "terrain_name": str(row["terrain_name"]),
        "profile_index": int(row["profile_index"]), "profile_name": str(row["profile_name"]),
        "heading_rad": float(row["heading_rad"]), "offset_east_m": float(row["offset_east_m"]),
        "offset_north_m": float(row["offset_north_m"]), "footprint_inside": bool(row["footprint_inside"]),
        "campaign_seed": int(seed),
    }


def failed_fields() -> dict:
    """The result columns of a case that produced no answer (nulls, invalid)."""
    return {"valid": False, "reason": "case_failed"}
