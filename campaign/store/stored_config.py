"""The campaign configuration a store was computed with, as a :class:`CampaignConfig` (``campaign export``
and the report's gallery simulate its cases again with it)."""
from __future__ import annotations

import json
from pathlib import Path

from campaign.configuration.campaign_file import CampaignConfig, campaign_config_from_data, load_campaign_config
from campaign.store.campaign_store import CampaignStore
from config_tables.errors import ConfigError


def stored_config(store: CampaignStore, manifest: dict) -> CampaignConfig:
    """The store's campaign: its campaign file when that still has the store's configuration hash, else
    rebuilt from the manifest's resolved tables (a sweep point's store, or a changed or moved file; the
    manifest's ``[scene]`` is the scene as the cases used it, sun distance included).

    The manifest's file names (``config_file`` and the resolved tables' paths) are as the submit saw them:
    relative ones are relative to its ``working_directory`` (the current directory for a store that does
    not record it), whatever directory this process runs in.
    """
    submit_directory = Path(manifest.get("working_directory", "."))
    config_file = submit_directory / manifest.get("config_file", "")
    if config_file.is_file():
        try:
            config = load_campaign_config(config_file, output_dir=store.root)
            if config.config_hash == manifest["config_hash"]:
                return config
        except ConfigError:
            pass
    tables = json.loads(json.dumps(manifest["config"]))
    # the resolved tables' relative paths are relative to the submit's directory, not to the campaign file's
    return campaign_config_from_data(tables, submit_directory / "manifest.json", source=f"{store.manifest_path}: config",
                                     output_dir=store.root)
