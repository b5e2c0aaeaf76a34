"""The configuration a store was computed with, read back from another directory than the submit's, after the
code (hence the configuration hash) changed: the manifest's relative file names are the submit's, relative to
its working directory, never to the campaign file's directory a second time."""
from __future__ import annotations

import os
from pathlib import Path

from campaign.configuration.campaign_file import load_campaign_config
from campaign.run.orchestrate import manifest_for
from campaign.store.campaign_store import CampaignStore
from campaign.store.stored_config import stored_config

REPO = Path(__file__).resolve().parents[3]


def test_a_store_submitted_with_relative_paths_is_read_back_from_elsewhere_after_a_code_change(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    config = load_campaign_config(Path("sitedata/gusev.toml"), output_dir=tmp_path / "store")
    manifest = manifest_for(config)
    assert manifest["config_file"] == "sitedata/gusev.toml"          # relative, as the user typed it
    assert not Path(manifest["config"]["site"]["camera"]).is_absolute()
    manifest["config_hash"] = "0" * len(manifest["config_hash"])    # the code changed since: the fallback path
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    rebuilt = stored_config(CampaignStore(tmp_path / "store"), manifest)
    assert Path(rebuilt.site.camera_path).resolve() == (REPO / "sitedata" / "cameras" / "mer_a.toml").resolve()
    assert rebuilt.site.name == config.site.name and rebuilt.seed == config.seed
    assert os.getcwd() == str(elsewhere)
