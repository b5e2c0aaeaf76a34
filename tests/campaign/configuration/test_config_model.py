"""One frozen model per campaign file: derived values come from validation, overrides are validated copies."""
from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from campaign.configuration.campaign_file import CampaignConfig, load_campaign_config
from campaign.configuration.execution import ExecutionConfig
from campaign.configuration.sweep_file import load_sweep, point_store_dir

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"


def test_campaign_config_is_frozen_and_holds_the_validated_tables():
    config = load_campaign_config(GUSEV)
    with pytest.raises(ValidationError):
        config.output_dir = Path("elsewhere")
    assert config.site is config.tables.site and config.sensors is config.tables.sensors
    assert config.seed == config.tables.campaign.seed
    assert config.scene.sun_distance_au == config.site.heliocentric_distance_au   # the site's, not written in the file
    assert "sun_distance_au" not in config.tables.scene.model_fields_set
    assert config.estimator_names == ["dimes"]


def test_derived_values_cannot_be_passed_by_hand():
    config = load_campaign_config(GUSEV)
    forged = CampaignConfig.model_validate({"source": config.source, "tables": config.tables,
                                            "output_dir": Path("x"), "cases_scale": 1.0, "config_hash": "forged"})
    assert forged.config_hash == config.config_hash and forged.scene == config.scene


def test_command_line_overrides_make_validated_copies(tmp_path):
    config = load_campaign_config(GUSEV, output_dir=tmp_path / "out", cases_scale=0.1)
    assert config.output_dir == tmp_path / "out" and config.cases_per_class == {"gcp": 19, "gdcp": 11, "gkep": 8}
    assert config.config_hash == load_campaign_config(GUSEV).config_hash
    moved = config.with_output_dir(tmp_path / "moved")
    assert moved.output_dir == tmp_path / "moved" and config.output_dir == tmp_path / "out"
    assert moved.config_hash == config.config_hash and moved.cases_per_class == config.cases_per_class


def test_execution_overrides_are_validated():
    slurm = ExecutionConfig.model_validate({"cluster": "slurm", "slurm": {"cores": 8}})
    assert slurm.with_overrides(None, None) is slurm
    workers = slurm.with_overrides(None, 3)
    assert (workers.cluster, workers.workers, workers.slurm.cores, slurm.workers) == ("slurm", 3, 8, 0)
    scheduler = slurm.with_overrides("tcp://host:8786", None)
    assert (scheduler.cluster, scheduler.scheduler) == ("scheduler", "tcp://host:8786")
    with pytest.raises(ValidationError):
        ExecutionConfig().with_overrides(None, 5000)        # beyond the declared maximum


def test_sweep_points_are_validated_copies_in_their_stores(tmp_path):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nbase = "{GUSEV}"\ncases_scale = 0.01\n[axes]\n"sensors.attitude_random_sigma_deg" = [0.05, 0.5]\n')
    spec = load_sweep(sweep, output_dir=tmp_path / "out")
    for point in spec.points:
        assert isinstance(point.config, CampaignConfig)
        assert point.config.output_dir == point_store_dir(tmp_path / "out", point.config_hash)
    assert spec.points[0].config_hash != spec.points[1].config_hash
    assert spec.base.output_dir == tmp_path / "out"
