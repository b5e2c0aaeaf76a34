"""The inputs every worker would load alike and the driver has loaded to plan (camera, trajectory set) are shipped
as the cluster starts: a real embedded worker computes its cases with the driver's, and its cases keep the bits
they had when each worker loaded its own (the baseline comparison)."""
from __future__ import annotations

import pickle
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from campaign.case import shipped_inputs
from campaign.case.inputs import PROCESS_SHARED, SHIPPED_KINDS, SharedInputs, shippable_inputs
from campaign.configuration.campaign_file import load_campaign_config
from campaign.run.orchestrate import StorePoint, manifest_for, run_store_points
from campaign.run.planning import plan_campaign
from service_campaigns import campaign_file


def _shared_report() -> dict:
    """Run in a worker after its cases: which of its inputs came from the driver, and its trajectory sets."""
    from campaign.case.inputs import PROCESS_SHARED

    profiles = {key: value for key, value in PROCESS_SHARED.loaded.items() if key[0] == "profiles"}
    return {"shipped": sorted(key[0] for key in PROCESS_SHARED.shipped_keys), "profiles": profiles}


@pytest.mark.cluster
def test_a_worker_computes_with_the_inputs_the_driver_made(tmp_path):
    config = load_campaign_config(campaign_file(tmp_path, cases={"gcp": 1, "gdcp": 0, "gkep": 0}),
                                  output_dir=tmp_path / "out")
    point = StorePoint(config, manifest_for(config), plan_campaign(config)[1])
    reports: list[dict] = []

    @contextmanager
    def inspect(client) -> Iterator[None]:
        yield
        reports.extend(client.run(_shared_report).values())

    execution = config.execution.with_overrides(None, 1)
    run = run_store_points([point], execution, progress=False, on_note=lambda line: None, client_hook=inspect,
                           quiet=True)
    assert run.done == 1 and run.failed == 0
    [report] = reports
    assert report["shipped"] == ["camera", "profiles"]     # this campaign's only
    [(key, profiles)] = report["profiles"].items()
    # the same key and trajectories as this process (the driver) loaded
    assert pickle.dumps(profiles) == pickle.dumps(PROCESS_SHARED.loaded[key])


def test_shipped_inputs_stand_for_loading_and_never_replace_what_a_process_has(tmp_path):
    config = load_campaign_config(campaign_file(tmp_path), output_dir=tmp_path / "out")
    maker = SharedInputs()
    maker.get("camera", "another camera", lambda source: "not this campaign's")
    shipped_inputs.receive(shippable_inputs([config], maker))
    [payload] = shipped_inputs.take()
    assert shipped_inputs.take() == []                       # taken once
    entries = pickle.loads(payload)
    assert sorted(key[0] for key in entries) == ["camera", "profiles"]
    assert {key[0] for key in entries} <= set(SHIPPED_KINDS)
    receiver = SharedInputs()
    own_profiles = receiver.get("profiles", config.site.trajectory_path, lambda path: "loaded here")
    receiver.absorb(entries)
    # a loader never runs for a shipped key; what the process loaded itself stands
    assert receiver.get("camera", config.site.camera_path, lambda path: pytest.fail("loaded again")) is not None
    assert receiver.get("profiles", config.site.trajectory_path, lambda path: "again") == own_profiles
    assert {key[0] for key in receiver.shipped_keys} == {"camera"}
