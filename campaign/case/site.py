"""What planning needs of a campaign, loaded once per process: the camera, the trajectory set and each class's
terrain (fitted to the trajectory set's footprints when its spec asks), and how a terrain holds the footprints.

:class:`SiteInputs` is all that ``campaign plan`` and the planning step of ``submit`` and ``sweep`` load
(:func:`campaign.run.planning.plan_campaign`); :class:`campaign.case.inputs.CampaignInputs` adds what a case
needs besides (calibration products, estimators). Both take their files through one :class:`SharedInputs`
per process (:data:`PROCESS_SHARED`), so what planning loaded is not loaded again for the cases.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from campaign.case.plan_row import PlanRow
from campaign.configuration.campaign_file import CampaignConfig
from campaign.plan.coverage import Coverage, coverage, fit_terrain, trajectory_boxes
from flight_interface.camera import Camera, load_camera
from simulator.scene.descent_profile import DescentProfile
from simulator.scene.terrain import Terrain
from sitedata.edl.trajectory_io import read_profiles
from sitedata.sites import load_class_terrain


class SharedInputs:
    """Inputs shared by every campaign (or sweep point) a process serves, loaded once per source: the
    sweep's points differ in scene/sensor/estimator parameters, not in camera, trajectories or terrain.

    Attributes
    ----------
    loaded : dict
        (kind, repr(source)[, file size in bytes, mtime in ns]) -> the loaded input.
    """

    def __init__(self) -> None:
        self.loaded: dict[tuple, Any] = {}

    def get(self, kind: str, source: Any, loader: Callable[[Any], Any]) -> Any:
        """``loader(source)``, loaded once per process per source (a path, keyed with its size and mtime so
        a changed file is read again, or a terrain spec)."""
        key: tuple = (kind, repr(source))
        path = Path(source) if isinstance(source, (str, Path)) else getattr(source, "path", None)
        if path is not None and Path(path).exists():
            stat = Path(path).stat()
            key += (stat.st_size, stat.st_mtime_ns)
        if key not in self.loaded:
            self.loaded[key] = loader(source)
        return self.loaded[key]


PROCESS_SHARED = SharedInputs()
"""The inputs this process has loaded (the only instance outside tests)."""


class SiteInputs:
    """Camera, trajectory set and class terrains of one campaign (through the process's :class:`SharedInputs`).

    Attributes
    ----------
    config : CampaignConfig
        The campaign.
    shared : SharedInputs
        Where the files are loaded once.
    camera : Camera
        The site's camera.
    profiles : list of DescentProfile
        The site's trajectory set.
    """

    def __init__(self, config: CampaignConfig, shared: SharedInputs = PROCESS_SHARED):
        self.config = config
        self.shared = shared
        self.camera: Camera = shared.get("camera", config.site.camera_path, load_camera)
        self.profiles: list[DescentProfile] = shared.get("profiles", config.site.trajectory_path, read_profiles)

    def terrain(self, class_name: str) -> Terrain:
        """The class's terrain, fitted to the trajectory set's footprints when its spec asks (``resample``)."""
        entry = next(entry for entry in self.config.site.classes if entry.name == class_name)
        terrain = self.shared.get("terrain", entry.terrain, load_class_terrain)
        if entry.terrain.resample == "none":
            return terrain
        source = (entry.terrain, id(terrain), str(self.config.site.camera_path), str(self.config.site.trajectory_path))
        return self.shared.get("fitted-terrain", source,
                               lambda _: fit_terrain(terrain, entry.terrain.resample, self.coverage(terrain)))

    def coverage(self, terrain: Terrain) -> Coverage:
        """How ``terrain`` holds this campaign's trajectory set (:func:`campaign.plan.coverage.coverage`)."""
        key = (str(self.config.site.camera_path), str(self.config.site.trajectory_path))
        boxes = self.shared.get("footprint-boxes", key, lambda _: trajectory_boxes(self.camera, self.profiles))
        return coverage(terrain, self.camera, self.profiles, boxes)

    def placed_profile(self, plan: PlanRow) -> DescentProfile:
        """The case's trajectory, turned by its heading and moved by its offset (m) on the terrain."""
        profile = self.profiles[plan.profile_index]
        return profile.placed(plan.heading_rad, np.array([plan.offset_east_m, plan.offset_north_m]),
                              name=f"{profile.name}@case{plan.case_id}")
