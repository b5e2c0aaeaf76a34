"""JSON Schemas of every configuration file and table (``campaign schema [TABLE]``).

Each TOML table is declared once, as a pydantic model; its JSON Schema (draft 2020-12) is generated
from that declaration, so editors (e.g. taplo / "Even Better TOML" with a ``#:schema FILE`` line at the
top of a TOML file) check the same names, types, ranges and defaults as the loaders.
"""
from __future__ import annotations

import importlib
from typing import Any

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

#: Table name -> (module:model, what it is).
SCHEMA_TABLES = {
    "campaign_file": ("campaign.configuration.campaign_file:CampaignFile", "a campaign TOML file (sitedata/gusev.toml): [site] + the tables below"),
    "site": ("sitedata.sites:Site", "[site] of a site or campaign file"),
    "campaign": ("campaign.configuration.campaign_file:CampaignTable", "[campaign] of a campaign file"),
    "execution": ("campaign.configuration.execution:ExecutionConfig", "[execution] of a campaign file"),
    "sensors": ("simulator.sensors:SensorConfig", "[sensors] of a campaign file"),
    "estimator": ("campaign.configuration.estimators:EstimatorTable",
                  "[estimator] of a campaign file: calibration products and the reference estimator's parameters"),
    "scene": ("simulator.scene_config:SceneConfig", "[scene] of a campaign file"),
    "camera": ("flight_interface.camera_file:CameraFile", "a camera TOML file (sitedata/cameras/mer_a.toml)"),
    "sweep": ("campaign.configuration.sweep_file:SweepFile", "a sweep TOML file (sitedata/sweeps/nightly.toml)"),
    "trajectory_set": ("sitedata.edl.parameters:EdlParameters",
                       "a trajectory-set parameter file (sitedata/trajectories/edl_gusev.toml)"),
    "terrain_sidecar": ("file_formats.planetary.sidecar:Sidecar",
                        "a terrain image's side-car TOML (sitedata/examples/M0100115.sidecar.toml)"),
    "post_mapping": ("sitedata.edl.post_table:PostMapping", "a POST-table mapping TOML (sitedata/edl/post_table.py)"),
    "flight": ("campaign.realism.flight_file:FlightFile", "FLIGHT.toml of campaign compare-flight"),
}


def schema_model(name: str):
    """The pydantic model declaring table ``name`` (``KeyError`` for an unknown name)."""
    module, attribute = SCHEMA_TABLES[name][0].split(":")
    return getattr(importlib.import_module(module), attribute)


def table_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of one table or file kind (``KeyError`` for an unknown name)."""
    return {"$schema": JSON_SCHEMA_DIALECT, "$comment": f"moc2dimes {name}: {SCHEMA_TABLES[name][1]}",
            **schema_model(name).model_json_schema()}


def all_schemas() -> dict[str, dict[str, Any]]:
    """Every table's JSON Schema, by name."""
    return {name: table_schema(name) for name in SCHEMA_TABLES}
