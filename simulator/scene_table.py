"""The TOML ``[scene]`` table -> :class:`~simulator.scene_config.SceneConfig` (degrees only here).

Example::

    [scene]
    fidelity = "default"           # preset the other fields start from (simulator.fidelity)
    sun_distance_au = 1.524
    spectral_ratio = 0.906
    parachute_distance_m = 30.0
    heat_shield_cone_angle_deg = 140.0
    [scene.effects]
    shadows = true
    motion_blur = true
    [scene.camera_effects]
    dark_current_scale = 1.0
    [scene.off_nominal]            # see simulator.off_nominal for every key
    dust_particle_count = 0
    angular_rate_multiplier = 1.0
    [scene.atmosphere]             # simulator.scene.atmosphere; off while orbital_optical_depth = 0
    orbital_optical_depth = 0.5    # zenith dust optical depth of the column (0 .. 10)
    scale_height_m = 11100.0       # dust scale height (1000 .. 100000 m)
    single_scattering_albedo = 0.94
    forward_asymmetry = 0.70       # double Henyey-Greenstein: f HG(g1) + (1 - f) HG(g2)
    backward_asymmetry = -0.30
    forward_fraction = 0.90
    descent_path = true            # dust below the descent camera attenuates and adds path light
    diffuse_transmission = true    # adjacency light and skylight (single scattering)
"""
from __future__ import annotations

from dataclasses import fields

import numpy as np

from flight_interface.tomlfields import Table
from simulator.detector.camera_chain import CameraEffects
from simulator.off_nominal import off_nominal_config_from_table

from .fidelity import DEFAULT_PRESET, PRESETS, preset_config
from .scene_config import AtmosphereConfig, SceneConfig, SceneEffects


def scene_config_from_table(table: Table) -> SceneConfig:
    """Build a :class:`SceneConfig` from a TOML table (e.g. ``[scene]``); every field is optional.

    Numbers are range-checked with one-line errors naming file, field and allowed range; the heat
    shield cone angle is given in degrees (``heat_shield_cone_angle_deg``). Sub-tables ``effects`` and
    ``camera_effects`` hold the boolean switches (and ``camera_effects.dark_current_scale``);
    ``off_nominal`` the off-nominal effects (:mod:`simulator.off_nominal`), ``atmosphere`` the dust
(:func:`atmosphere_config_from_table`). ``fidelity`` names the
    preset of shortcuts the other fields start from (:mod:`simulator.fidelity`; default "default").
    """
    default = preset_config(table.string("fidelity", default=DEFAULT_PRESET, choices=PRESETS))
    switches = table.table("effects", required=False)
    effects = SceneEffects(**{f.name: switches.boolean(f.name, default=getattr(default.effects, f.name))
                              for f in fields(SceneEffects)})
    _reject_unknown(switches, {f.name for f in fields(SceneEffects)})
    cam_table = table.table("camera_effects", required=False)
    cam_kwargs = {}
    for f in fields(CameraEffects):
        current = getattr(default.camera_effects, f.name)
        if isinstance(current, bool):
            cam_kwargs[f.name] = cam_table.boolean(f.name, default=current)
        else:
            cam_kwargs[f.name] = cam_table.number(f.name, default=current, minimum=0.0, maximum=1e6)
    _reject_unknown(cam_table, {f.name for f in fields(CameraEffects)})

    def number(key, minimum, maximum, exclusive_minimum=False):
        return table.number(key, default=getattr(default, key), minimum=minimum, maximum=maximum,
                            exclusive_minimum=exclusive_minimum)

    def step(key):
        value = table.integer(key, default=getattr(default, key), minimum=1, maximum=256)
        if 1024 % value:
            raise table.fail(key, f"= {value} must divide the 1024-pixel frame; allowed: 1, 2, 4, ..., 256")
        return value

    config = SceneConfig(
        effects=effects, camera_effects=CameraEffects(**cam_kwargs),
        off_nominal=off_nominal_config_from_table(table.table("off_nominal", required=False)),
        atmosphere=atmosphere_config_from_table(table.table("atmosphere", required=False), default.atmosphere),
        sun_distance_au=number("sun_distance_au", 0.1, 100.0, exclusive_minimum=True),
        spectral_ratio=number("spectral_ratio", 0.0, 10.0, exclusive_minimum=True),
        lander_diameter_m=number("lander_diameter_m", 0.0, 20.0),
        backshell_diameter_m=number("backshell_diameter_m", 0.0, 20.0),
        backshell_distance_m=number("backshell_distance_m", 0.0, 500.0),
        parachute_diameter_m=number("parachute_diameter_m", 0.0, 100.0),
        parachute_distance_m=number("parachute_distance_m", 0.0, 500.0),
        shadow_diffuse_fraction=number("shadow_diffuse_fraction", 0.0, 1.0),
        heat_shield_diameter_m=number("heat_shield_diameter_m", 0.0, 50.0, exclusive_minimum=True),
        heat_shield_cone_angle_rad=float(np.radians(table.number(
            "heat_shield_cone_angle_deg", default=140.0, minimum=0.0, maximum=180.0,
            exclusive_minimum=True, exclusive_maximum=True))),
        heat_shield_reflectance=number("heat_shield_reflectance", 0.0, 1.0),
        ray_grid_step_px=step("ray_grid_step_px"),
        photometry_grid_step_px=step("photometry_grid_step_px"),
        max_substeps=table.integer("max_substeps", default=default.max_substeps, minimum=1, maximum=256),
        still_shift_terrain_px=number("still_shift_terrain_px", 0.0, 100.0),
        substeps_per_terrain_px=number("substeps_per_terrain_px", 0.1, 64.0),
        supersample=table.integer("supersample", default=default.supersample, minimum=1, maximum=8),
    )
    _reject_unknown(table, {f.name for f in fields(SceneConfig)} - {"heat_shield_cone_angle_rad"}
                    | {"heat_shield_cone_angle_deg", "fidelity"})
    return config


_ATMOSPHERE_RANGES = {   # field -> (minimum, maximum, exclusive minimum)
    "orbital_optical_depth": (0.0, 10.0, False),
    "scale_height_m": (1000.0, 100000.0, False),
    "single_scattering_albedo": (0.0, 1.0, False),
    "forward_asymmetry": (-0.95, 0.95, False),
    "backward_asymmetry": (-0.95, 0.95, False),
    "forward_fraction": (0.0, 1.0, False),
}


def atmosphere_config_from_table(table: Table, default: AtmosphereConfig = AtmosphereConfig()) -> AtmosphereConfig:
    """Build an :class:`AtmosphereConfig` from the ``[scene.atmosphere]`` table (every field optional;
    numbers range-checked, one-line errors naming file, field and allowed range)."""
    values = {key: table.number(key, default=getattr(default, key), minimum=low, maximum=high,
                                exclusive_minimum=exclusive)
              for key, (low, high, exclusive) in _ATMOSPHERE_RANGES.items()}
    values.update({key: table.boolean(key, default=getattr(default, key))
                   for key in ("descent_path", "diffuse_transmission")})
    _reject_unknown(table, {f.name for f in fields(AtmosphereConfig)})
    return AtmosphereConfig(**values)


def _reject_unknown(table: Table, allowed: set[str]) -> None:
    for key in table.data:
        if key not in allowed:
            raise table.fail(key, f"is not a known field; allowed: {', '.join(sorted(allowed))}")
