"""A case's inputs: its plan row (:class:`PlanRow`) and what the campaign gives every case, loaded once per
process.

:class:`SiteInputs` is what planning needs (the camera, the trajectory set and each class's terrain, fitted
to the trajectory set's footprints when its spec asks): all that ``campaign plan`` and the planning step of
``submit`` and ``sweep`` load (:func:`campaign.run.planning.plan_campaign`). :class:`CampaignInputs` adds
what a case needs besides (calibration products, estimators, the plausibility bound); :func:`campaign_inputs`
is the one way a process gets them (workers, ``campaign export``, the report's gallery, benchmarks). Both
take their files through one :class:`SharedInputs` per process (:data:`PROCESS_SHARED`), so what planning
loaded is not loaded again for the cases; campaigns are kept by configuration hash in :data:`PROCESS_INPUTS`.
Dask tasks carry only a small context and one plan row.

The flat-field calibration is drawn once per campaign from ``SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))``
(a stream no case uses) and cached per process, read-only at its source; each ``[[estimators]]`` entry is
built once per process.
"""
from __future__ import annotations

import pickle
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from campaign.case import shipped_inputs
from campaign.case.process_tuning import tune_once
from campaign.configuration.campaign_file import CampaignConfig
from campaign.plan.coverage import Coverage, coverage, fit_terrain, trajectory_boxes
from estimators.entries import EstimatorSpec
from estimators.plugins import build_estimator
from flight_interface.calibration import CalibrationProducts
from flight_interface.camera import Camera, load_camera
from simulator.calibration import simulate_flat_field, true_flat_field
from simulator.scene.descent_profile import DescentProfile
from simulator.scene.terrain import Terrain
from sitedata.edl.trajectory_io import read_profiles
from sitedata.sites import load_class_terrain

FLAT_FIELD_STREAM = 0xF1A7   # spawn key of the flat-field calibration's noise stream
#: Margin (m/s) above the trajectory set's fastest horizontal speed: a valid answer at or above the sum is
#: ``implausible`` (no estimator can be that far off on a real descent; the reference stays within ~30 m/s
#: of the truth by its 25 m/s bias search range).
PLAUSIBLE_SPEED_MARGIN_MPS = 100.0



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


class SharedInputs:
    """Inputs shared by every campaign (or sweep point) a process serves, loaded once per source: the
    sweep's points differ in scene/sensor/estimator parameters, not in camera, trajectories or terrain.

    Attributes
    ----------
    loaded : dict
        (kind, repr(source)[, file size in bytes, mtime in ns]) -> the loaded input.
    shipped_keys : set
        The keys of ``loaded`` whose input another process made (:meth:`absorb`).
    """

    def __init__(self) -> None:
        self.loaded: dict[tuple, Any] = {}
        self.shipped_keys: set[tuple] = set()       # the keys of entries another process made (absorb)

    @staticmethod
    def key(kind: str, source: Any) -> tuple:
        """The key of ``source`` (a path, with its size and mtime so a changed file is read again, or a spec)."""
        key: tuple = (kind, repr(source))
        path = Path(source) if isinstance(source, (str, Path)) else getattr(source, "path", None)
        if path is not None and Path(path).exists():
            stat = Path(path).stat()
            key += (stat.st_size, stat.st_mtime_ns)
        return key

    def get(self, kind: str, source: Any, loader: Callable[[Any], Any]) -> Any:
        """``loader(source)``, loaded once per process per source (:meth:`key`)."""
        key = self.key(kind, source)
        if key not in self.loaded:
            self.loaded[key] = loader(source)
        return self.loaded[key]

    def absorb(self, entries: Mapping[tuple, Any]) -> None:
        """Take ``entries`` (key -> input, as another process loaded them: :func:`shippable_inputs`) where
        nothing is loaded under their key yet; their arrays are made read-only, as the loaders here make the
        calibration products."""
        for key, value in entries.items():
            if key not in self.loaded:
                self.loaded[key] = read_only_array(value) if isinstance(value, np.ndarray) else value
                self.shipped_keys.add(key)


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
    terrains : dict of Terrain
        Class name -> the class's terrain, once :meth:`terrain` made it.
    """

    def __init__(self, config: CampaignConfig, shared: SharedInputs = PROCESS_SHARED):
        self.config = config
        self.shared = shared
        self.camera: Camera = shared.get("camera", config.site.camera_path, load_camera)
        self.profiles: list[DescentProfile] = shared.get("profiles", config.site.trajectory_path, read_profiles)
        self.terrains: dict[str, Terrain] = {}      # by class name, as :meth:`terrain` made them

    def terrain(self, class_name: str) -> Terrain:
        """The class's terrain, fitted to the trajectory set's footprints when its spec asks (``resample``)."""
        if class_name not in self.terrains:
            self.terrains[class_name] = self._class_terrain(class_name)
        return self.terrains[class_name]

    def _class_terrain(self, class_name: str) -> Terrain:
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


def read_only_array(array: np.ndarray) -> np.ndarray:
    """``array`` itself, made read-only (for arrays cached per process and handed to every estimator)."""
    array.setflags(write=False)
    return array


class CampaignInputs(SiteInputs):
    """Camera, trajectory set, terrain, calibration products and estimators of one campaign, loaded once per
    process (through the process's :class:`SharedInputs`).

    Attributes
    ----------
    built_estimators : list of (EstimatorSpec, estimator) or None
        The campaign's estimators once built in this process (:meth:`estimators`).
    calibration_products : CalibrationProducts or None
        The calibration products once made in this process (:meth:`calibration`).
    max_horizontal_speed_mps : float
        The plausibility bound of a valid answer (m/s): the fastest horizontal speed of any profile of the
        trajectory set, at any time, plus :data:`PLAUSIBLE_SPEED_MARGIN_MPS`.
    """

    def __init__(self, config: CampaignConfig, shared: SharedInputs = PROCESS_SHARED):
        super().__init__(config, shared)
        self.built_estimators: list[tuple[EstimatorSpec, Any]] | None = None   # built on first use
        self.calibration_products: CalibrationProducts | None = None         # made on first use
        fastest = max((float(np.hypot(p.velocity_mps[:, 0], p.velocity_mps[:, 1]).max()) for p in self.profiles),
                      default=0.0)
        self.max_horizontal_speed_mps = fastest + PLAUSIBLE_SPEED_MARGIN_MPS

    def calibration(self) -> CalibrationProducts:
        """The campaign's calibration products (``[estimator] flat_field``), made once per process."""
        if self.calibration_products is None:
            self.calibration_products = self._make_calibration()
        return self.calibration_products

    def _make_calibration(self) -> CalibrationProducts:
        calibration = self.config.calibration
        if calibration.flat_field == "none":
            return CalibrationProducts(None, "none")
        effects = self.config.scene.camera_effects.model_copy(update={"dark_current_scale": 1.0})   # the detector on the ground
        camera_path = Path(self.config.site.camera_path)
        stat = camera_path.stat()
        if calibration.flat_field == "truth":
            flat = self.shared.get("flat_truth", (str(camera_path), stat.st_size, stat.st_mtime_ns, effects),
                                   lambda _: read_only_array(true_flat_field(self.camera, effects)))
            return CalibrationProducts(flat, "truth")
        frames, seed = calibration.flat_field_frames, self.config.seed
        key = (str(camera_path), stat.st_size, stat.st_mtime_ns, effects, frames, seed)
        flat = self.shared.get("flat_calibrated", key, lambda _: read_only_array(simulate_flat_field(
            self.camera, frames, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))),
            effects)))
        return CalibrationProducts(flat, f"calibrated: {frames} frames")

    def estimators(self) -> list[tuple[EstimatorSpec, Any]]:
        """(spec, estimator object) of every configured estimator, built on first use."""
        if self.built_estimators is None:
            self.built_estimators = [(spec, build_estimator(spec)) for spec in self.config.estimators]
        return self.built_estimators


@dataclass
class ProcessInputs:
    """The campaigns' inputs a process keeps between cases.

    Attributes
    ----------
    campaigns : dict
        Configuration hash -> the campaign's :class:`CampaignInputs`.
    shared : SharedInputs
        Inputs shared by the campaigns (or sweep points) the process serves, by source.
    """

    campaigns: dict[str, CampaignInputs] = field(default_factory=dict)
    shared: SharedInputs = PROCESS_SHARED


PROCESS_INPUTS = ProcessInputs()
"""The inputs of this process (the only instance outside tests)."""


#: the kinds of :class:`SharedInputs` entries :func:`shippable_inputs` ships: what a worker would read for its first
#: case and the driver has read already to plan; terrains are left out (loaded in about 10 ms, 20 MB each)
SHIPPED_KINDS = ("camera", "profiles")


def shippable_inputs(configs: Sequence[CampaignConfig], shared: SharedInputs = PROCESS_SHARED) -> bytes:
    """The campaigns' inputs this process has loaded (planning did) that every worker would load alike, pickled
    (for :class:`campaign.run.worker_startup.ShippedInputs`; the worker's first :func:`campaign_inputs` takes them).

    Nothing is computed for the workers here: made in the driver while the cluster starts, the flat-field
    calibrations (0.7 s each) held the first task back by 0.6-1.2 s (the driver shares the cores with the starting
    workers), and Gusev + Meridiani took 47-50 s against 39 s without (2026-11-27, loaded 2-core machine).
    Every entry keeps the key a worker would look it up by (a file by its path, size and modification time: a
    worker that sees another file loads its own), so the worker computes with the same objects. About 10 MB
    for Gusev and Meridiani."""
    used = _UsedKeys(shared)
    for config in dict((config.config_hash, config) for config in configs).values():
        CampaignInputs(config, used)
    entries = {key: shared.loaded[key] for key in sorted(used.keys, key=repr) if key[0] in SHIPPED_KINDS}
    return pickle.dumps(entries, protocol=pickle.HIGHEST_PROTOCOL)


class _UsedKeys(SharedInputs):
    """``shared`` itself (the same entries), noting the keys asked for (only these campaigns' are shipped)."""

    def __init__(self, shared: SharedInputs):
        self.loaded = shared.loaded
        self.shipped_keys = shared.shipped_keys
        self.keys: set[tuple] = set()

    def get(self, kind: str, source: Any, loader: Callable[[Any], Any]) -> Any:
        self.keys.add(self.key(kind, source))
        return super().get(kind, source, loader)


def campaign_inputs(config: CampaignConfig, cache: ProcessInputs = PROCESS_INPUTS) -> CampaignInputs:
    """The campaign's inputs in this process (created on first use, in a process tuned for cases first, with
    the inputs a driver shipped: :mod:`campaign.case.shipped_inputs`)."""
    for payload in shipped_inputs.take():
        cache.shared.absorb(pickle.loads(payload))
    if config.config_hash not in cache.campaigns:
        tune_once()
        cache.campaigns[config.config_hash] = CampaignInputs(config, cache.shared)
    return cache.campaigns[config.config_hash]
